"""`vacc train`: fill in :class:`agent_client.ddqn.Config` from flags and train."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import click

from agent_client.ddqn import Config, eval_episode
from agent_client.ddqn import train as run_training
from agent_client.errors import ClientError

_D = Config()  # defaults shown in --help


def _terminate(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def _seconds(ctx: click.Context, param: click.Parameter, value: float | None) -> float | None:
    return None if value is None or value <= 0 else value


@click.command("train")
@click.option("--reward", required=True, type=click.Choice(["gap", "force"]), help="Table 1 reward: gap term, or gap + force terms.")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(["ice", "ev"]))
@click.option("--steps", required=True, type=click.IntRange(min=1), help="Environment steps (0.1 s each) to train for, in total.")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Run folder, e.g. runs/ice-gap.")
@click.option("--resume", is_flag=True, help="Continue the run in --out from latest.pt and the replay file it names.")
@click.option("--seed", default=_D.seed, show_default=True, type=int)
@click.option("--eval-every", default=_D.eval_every, show_default=True, type=click.IntRange(min=0), help="Steps between evaluations on --eval-trajectories (0: only at the end).")
@click.option("--eval-seconds", default=None, type=float, callback=_seconds, help="Evaluation episode length [s] (default: whole trajectories).")
@click.option("--eval-trajectories", default=",".join(_D.eval_trajectories), show_default=True, help="Comma-separated evaluation trajectories; they pick best.pt: test-1..test-4, or random:SEED for a selection set held out from the tests.")
@click.option("--episode-seconds", default=_D.episode_seconds, show_default=True, type=float, callback=_seconds, help="Training episode length [s] (0: the whole 240 s trajectory).")
@click.option("--buffer-size", default=_D.buffer_size, show_default=True, type=click.IntRange(min=100))
@click.option("--learning-starts", default=_D.learning_starts, show_default=True, type=click.IntRange(min=0))
@click.option("--exploration-steps", default=_D.exploration_steps, show_default=True, type=click.IntRange(min=1))
@click.option("--start-e", default=_D.start_e, show_default=True, type=click.FloatRange(0.0, 1.0))
@click.option("--end-e", default=_D.end_e, show_default=True, type=click.FloatRange(0.0, 1.0))
@click.option("--learning-rate", default=_D.learning_rate, show_default=True, type=click.FloatRange(min=0.0, min_open=True))
@click.option("--batch-size", default=_D.batch_size, show_default=True, type=click.IntRange(min=1))
@click.option("--train-every", default=_D.train_every, show_default=True, type=click.IntRange(min=1), help="Environment steps per gradient step.")
@click.option("--target-sync-every", default=_D.target_sync_every, show_default=True, type=click.IntRange(min=1))
@click.option("--gamma", default=_D.gamma, show_default=True, type=click.FloatRange(0.0, 1.0, max_open=True))
@click.option("--n-step", default=_D.n_step, show_default=True, type=click.IntRange(min=1), help="Rewards summed before bootstrapping (n-step return).")
@click.option("--stack-stride", default=_D.stack_stride, show_default=True, type=click.IntRange(min=1), help="Control steps between stacked frames.")
@click.option("--zoom", default=_D.zoom, show_default=True, type=click.Choice(["1", "2"]), help="1: the paper's halved camera; 2: the same window at full resolution.")
@click.option("--checkpoint-every", default=_D.checkpoint_every, show_default=True, type=click.IntRange(min=1))
@click.option("--log-every", default=_D.log_every, show_default=True, type=click.IntRange(min=1), help="Steps between loss/Q-value scalars.")
@click.option("--init-from", default=None, type=click.Path(dir_okay=False, exists=True), help="Start from this policy checkpoint's weights (fine-tuning).")
@click.option("--threads", default=_D.torch_threads, show_default=True, type=click.IntRange(min=1), help="torch CPU threads.")
@click.option("--no-cuda", is_flag=True, help="Stay on the CPU even if CUDA is available.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@click.option("--servers", default=_D.servers, show_default=True, type=click.IntRange(min=1), help="Simulator servers, each with its own acting process, feeding one learner (docs/scale-out.md).")
@click.option("--ray", "use_ray", is_flag=True, help="Run the servers and their actors as Ray actors (pip install 'vacc[ray]').")
@click.option("--ray-address", default=None, help="With --ray: 'auto' or HOST:PORT of a running cluster (default: a local Ray instance).")
@click.option("--actor-cpus", default=1.0, show_default=True, type=click.FloatRange(min=0.0, min_open=True), help="With --ray: CPUs reserved per actor (its server included).")
@click.option("--max-restarts", default=3, show_default=True, type=click.IntRange(min=0), help="With --servers > 1 or --ray: restarts of a dead actor before it is given up.")
@click.option("--weight-sync-every", default=_D.weight_sync_every, show_default=True, type=click.IntRange(min=1), help="With --servers > 1 or --ray: gradient steps between weight broadcasts to the actors (M).")
@click.option("--actor-batch", default=_D.actor_batch, show_default=True, type=click.IntRange(min=1), help="With --servers > 1 or --ray: transitions per delivery from an actor.")
def train(
    reward: str,
    scenario: str,
    steps: int,
    out: str,
    resume: bool,
    seed: int,
    eval_every: int,
    eval_seconds: float | None,
    eval_trajectories: str,
    episode_seconds: float | None,
    buffer_size: int,
    learning_starts: int,
    exploration_steps: int,
    start_e: float,
    end_e: float,
    learning_rate: float,
    batch_size: int,
    train_every: int,
    target_sync_every: int,
    gamma: float,
    n_step: int,
    stack_stride: int,
    zoom: str,
    checkpoint_every: int,
    log_every: int,
    init_from: str | None,
    threads: int,
    no_cuda: bool,
    quiet: bool,
    servers: int,
    use_ray: bool,
    ray_address: str | None,
    actor_cpus: float,
    max_restarts: int,
    weight_sync_every: int,
    actor_batch: int,
) -> None:
    """Train a Double-DQN policy from camera frames against spawned simulator servers.

    Writes OUT/config.json, OUT/scalars.csv, OUT/latest.pt (+ replay-STEP.npz) and
    OUT/best.pt (the policy with the best test evaluation; drive it with
    `vacc drive --controller ddqn --checkpoint OUT/best.pt`).

    --servers K runs K simulator servers, each with its own acting process, feeding
    one learner; --ray runs them as Ray actors on a Ray cluster instead.
    """
    trajectories = tuple(t.strip() for t in eval_trajectories.split(",") if t.strip())
    if not trajectories:
        raise click.BadParameter("give at least one trajectory", param_hint="--eval-trajectories")
    for name in trajectories:
        try:
            eval_episode(name)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--eval-trajectories") from None
    cfg = Config(
        reward=reward, scenario=scenario, total_steps=steps, seed=seed, eval_every=eval_every,
        eval_seconds=eval_seconds, eval_trajectories=trajectories, episode_seconds=episode_seconds,
        buffer_size=buffer_size, learning_starts=learning_starts, exploration_steps=exploration_steps,
        start_e=start_e, end_e=end_e, learning_rate=learning_rate, batch_size=batch_size, train_every=train_every,
        target_sync_every=target_sync_every, gamma=gamma, n_step=n_step, stack_stride=stack_stride, zoom=int(zoom),
        checkpoint_every=checkpoint_every, log_every=log_every, init_from=init_from, torch_threads=threads, cuda=not no_cuda,
        servers=servers, weight_sync_every=weight_sync_every, actor_batch=actor_batch,
    )  # fmt: skip
    if ray_address is not None and not use_ray:
        raise click.UsageError("--ray-address needs --ray")
    distributed = use_ray or servers > 1
    if resume and not (Path(out) / "latest.pt").exists():
        raise click.UsageError(f"--resume: {Path(out) / 'latest.pt'} does not exist")
    # A plain `kill` or Ctrl-C reaps the spawned servers and actors (the finally blocks
    # run); both leave through SystemExit, one shutdown path.
    signal.signal(signal.SIGTERM, _terminate)
    signal.signal(signal.SIGINT, _terminate)
    try:
        if distributed:
            from agent_client.distributed import import_ray, train_distributed

            if use_ray:
                import_ray()  # before any work: say how to install it
            summary = train_distributed(
                cfg, out, resume=resume, progress=not quiet, use_ray=use_ray, ray_address=ray_address,
                actor_cpus=actor_cpus, max_restarts=max_restarts,
            )  # fmt: skip
        else:
            summary = run_training(cfg, out, resume=resume, progress=not quiet)
    except ClientError as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"trained {summary['steps']} steps, {summary['episodes']} episodes in {summary['wall_s']:.0f} s -> {out}")
    if distributed:
        click.echo(
            f"  {summary['servers']} actors ({summary['backend']}): transitions {summary['transitions_by_actor']}, "
            f"restarts {summary['restarts_by_actor']}, {summary['env_steps_per_s']:.0f} env steps/s"
        )
    for r in summary["last_eval"]:
        click.echo(f"  {r['trajectory']}: gap RMSE {r['gap_rmse_m']:.3f} m, collision {'yes' if r['collision'] else 'no'}")
    (Path(out) / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
