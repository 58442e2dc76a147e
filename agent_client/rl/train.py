"""Double DQN (or, for the continuous action, DrQ-v2) from pixels, one acting stream: the
loop that feeds the :class:`Learner`.

Read top to bottom, as CleanRL's ``dqn_atari.py``: seed and build (the learner),
then act ε-greedily, store, and take a gradient step every ``train_every`` steps;
evaluate and checkpoint on their step grids. ``vacc train`` fills in the
:class:`Config` and calls :func:`train`.

The network sees 8 stacked preprocessed camera frames and the 8 matching host speeds,
nothing else: the gap feeds only the reward. Training talks to a real simulator
server process over UDP through :class:`agent_client.env.VisionACCEnv`.

Run folder ``runs/<name>/``: ``config.json``; ``scalars.csv`` (``step,name,value,wall_s``;
TensorBoard events too if installed); ``latest.pt`` + ``replay-<step>.npz``, written at
episode ends (a Ctrl-C waits for the episode's end) and at the step budget's end, which keeps
the episode it cut (:func:`_redrive`), so a resumed run continues exactly; ``best.pt``, the
policy with the best evaluation so far (< 5 MB).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent_client.actions import is_continuous, make_action_type
from agent_client.errors import ResumeError
from agent_client.launcher import Road
from agent_client.rl.actor_critic import explore, noise_std, noisy, student_target
from agent_client.rl.config import Config
from agent_client.rl.learner import STOP, Learner, PolicyTeacher
from agent_client.rl.losses.brake_margin import lead_stop_distance
from agent_client.rl.network import Decision, linear_schedule
from agent_client.rl.replay import ReplayMemory
from agent_client.rl.scalars import Progress

__all__ = ["train", "LoopState", "STOP"]


@dataclass
class LoopState:
    """What a resumed run needs of the loop besides the learner and the replay memory."""

    global_step: int = 0
    episodes: int = 0
    recent_returns: list[float] = field(default_factory=list)
    eval_pending: bool = False  # stopped where an evaluation was due: the resumed run does it first
    # The episode the step budget cut (None: the run ended at an episode's end): its reset options,
    # the decisions taken, its return and length so far, and the acting policy's state. A run
    # resumed with a larger budget re-drives it and finishes it, as a straight run would have.
    cut: dict[str, Any] | None = None


@dataclass
class _Schedule:
    """The evaluation and checkpoint grids (on the eval_every grid, so that a resumed
    run evaluates where it would have)."""

    next_eval: float
    next_checkpoint: int
    last_eval_step: int = -1

    @classmethod
    def at(cls, step: int, cfg: Config) -> _Schedule:
        next_eval = (step // cfg.eval_every + 1) * cfg.eval_every if cfg.eval_every > 0 else math.inf
        return cls(next_eval, step + cfg.checkpoint_every)


def train(
    cfg: Config,
    run_dir: str | Path,
    *,
    resume: bool = False,
    progress: bool = True,
    server_args: tuple[str, ...] = (),
    on_eval: Callable[[int, list[dict[str, Any]]], None] | None = None,
) -> dict[str, Any]:
    """Train a DDQN policy against a spawned simulator server; write the run folder.

    Args:
        cfg: the settings (with ``resume``, those of the run being resumed must match,
            but for :data:`~agent_client.rl.config.RESUMABLE_CHANGES`).
        run_dir: ``runs/<name>``.
        resume: continue from ``run_dir/latest.pt`` and the replay file it names.
        progress: show the progress line on stderr.
        server_args: extra ``python -m sim_server`` arguments for the spawned servers.
        on_eval: called with (step, results) after each evaluation.

    Returns:
        Summary: steps, episodes, best score, last evaluation, wall time [s], whether
        :data:`STOP` ended it.

    Raises:
        InputFileError: ``resume`` with a missing or bad checkpoint or replay file.
        CheckpointWriteError: a checkpoint could not be written (the last good one stays).
    """
    from agent_client.env import VisionACCEnv  # the env spawns servers; import late
    from agent_client.errors import InputFileError

    if cfg.servers != 1:
        raise ValueError(f"train() runs one stream; servers={cfg.servers} needs agent_client.rl.distributed.train_distributed")
    memory = ReplayMemory(cfg.buffer_size, cfg.frame_stack, cfg.stack_stride, n_controls=make_action_type(cfg.action).n_controls, gaps=cfg.stores_gaps,
                          continuous=is_continuous(cfg.action), state_size=cfg.hidden if cfg.recurrent != "none" else 0,
                          lead_stops=cfg.stores_lead_stops)  # fmt: skip

    def load_replay(learner: Learner) -> None:
        step = int(learner.saved.get("global_step", 0))
        replay_path = learner.run_dir / learner.replay_names[0]
        if memory.load(replay_path) != step:
            raise InputFileError(f"{replay_path}: saved at a step other than latest.pt's {step}")

    learner = Learner(cfg, run_dir, resume=resume, trainer="single", server_args=server_args, on_eval=on_eval, load_replay=load_replay)
    state = LoopState(**{k: v for k, v in learner.saved.items() if k in LoopState.__dataclass_fields__})
    env = None
    try:
        env = VisionACCEnv(
            scenario=cfg.scenario, trajectory=cfg.train_trajectories[0], reward=cfg.reward, frame_stack=cfg.frame_stack,
            stack_stride=cfg.stack_stride, episode_seconds=cfg.episode_seconds, zoom=cfg.zoom,
            server_args=(*learner.server_args, *Road(cfg.train_traffic, (cfg.train_sun_elevation[0], cfg.train_sun_elevation[1])).server_args()),  # evaluations keep the defaults
            set_speed=cfg.set_speed, action=cfg.action, eco_weights=cfg.eco_weights, crash_reward=cfg.crash_reward, preroll=cfg.preroll,
        )  # fmt: skip
        wall_s = _loop(cfg, learner, memory, env, state, progress)
    finally:
        learner.close()
        if env is not None:
            env.close()
    return {
        "steps": state.global_step,
        "episodes": state.episodes,
        "updates": learner.updates,
        "best_score": learner.best_score,
        "last_eval": learner.last_eval,
        "wall_s": wall_s,
        "schedule": cfg.schedule,
        "stopped": STOP.is_set() and state.global_step < cfg.total_steps,  # a stop at the last step finished the run
        "replay_bytes_per_transition": memory.nbytes / memory.capacity,
    }


def _loop(cfg: Config, learner: Learner, memory: ReplayMemory, env: Any, state: LoopState, progress: bool) -> float:
    """Act, store, learn, evaluate and checkpoint until ``cfg.total_steps``; returns the wall time [s]."""
    rng, log = learner.acting_rng, learner.log
    bar = Progress(cfg.total_steps, enabled=progress, initial=state.global_step, label="noise" if is_continuous(cfg.action) else "eps")
    recent = deque(state.recent_returns, maxlen=20)
    grid = _Schedule.at(state.global_step, cfg)
    if state.cut is not None and state.cut["eval_due"]:
        grid.next_eval = state.global_step  # due before the cut: a straight run evaluates at the cut episode's end
    if state.eval_pending:  # where the uninterrupted run evaluated, with the same weights
        learner.evaluate(state.global_step)
        grid.last_eval_step, state.eval_pending = state.global_step, False
    t_start, steps_at_start = time.perf_counter(), state.global_step

    def sps() -> float:
        return (state.global_step - steps_at_start) / max(time.perf_counter() - t_start, 1e-9)

    try:
        while state.global_step < cfg.total_steps:
            policy = learner.acting_policy
            if state.cut is not None:  # the budget cut this episode: take it up where it stopped
                obs, info = _redrive(cfg, learner, env, memory, state.cut)
                options, taken = state.cut["options"], list(state.cut["taken"])
                episode_return, episode_len = float(state.cut["return"]), int(state.cut["length"])
                state.cut = None
            else:
                options = {"seed": int(rng.integers(2**31))}
                if len(cfg.train_trajectories) > 1:  # a mix: one drawn per episode (a single one draws nothing)
                    options["trajectory"] = cfg.train_trajectories[int(rng.integers(len(cfg.train_trajectories)))]
                obs, info = env.reset(options=options)
                if learner.teacher is not None:
                    learner.teacher.reset()  # a lagged teacher's view starts over with the episode
                policy.reset()
                for frame in info.get("preroll", ()):
                    memory.warm(frame)
                memory.start(obs, info["gap"], policy.state(), lead_stop_distance(info["v_lead"], info["a_lead"]))  # privileged: kept apart from obs
                if state.episodes == 0:  # what the network sees, once
                    log.frames("charts/first_observation", obs["frames"], state.global_step)
                taken, episode_return, episode_len = [], 0.0, 0
            done = False
            while not done and state.global_step < cfg.total_steps:  # a stop waits for the episode's end
                exploring = _exploration(cfg, state.global_step)  # ε, or the actor-critic's noise std
                decision, stored = _choose(cfg, learner, env, obs, info, exploring, state.global_step)
                obs, reward, terminated, truncated, info = decision.step(env)
                taken.append(list(decision))
                memory.add(stored, reward, terminated, truncated, obs, info["gap"], policy.state(),  # a recurrent state: the one before obs
                           lead_stop_distance(info["v_lead"], info["a_lead"]))  # fmt: skip
                episode_return += reward
                episode_len += 1
                done = terminated or truncated
                state.global_step += 1
                step = state.global_step
                if step > cfg.learning_starts and step % cfg.train_every == 0:
                    learner.train_step(memory, step)
                if step % cfg.target_sync_every == 0:
                    learner.sync_target()
                bar.update(step, exploring, float(np.mean(recent)) if recent else float("nan"))
            if not done:  # cut by the step budget: kept, so that a larger budget finishes it
                state.cut = {"options": options, "taken": taken, "return": episode_return, "length": episode_len, "policy": policy.episode_state(),
                             "eval_due": bool(cfg.eval_trajectories) and state.global_step >= grid.next_eval}  # fmt: skip
            if done:  # a whole episode (not one cut by the step budget)
                state.episodes += 1
                recent.append(episode_return)
                for name, value in (("episodic_return", episode_return), ("episodic_length", episode_len),
                                    ("mean_reward", episode_return / max(episode_len, 1)), ("SPS", sps()),
                                    ("noise_std" if learner.continuous else "epsilon", exploring)):  # fmt: skip
                    log.add(f"charts/{name}", value, state.global_step)
            state.recent_returns = list(recent)
            if STOP.is_set() and state.global_step < cfg.total_steps:
                # Asked to stop: a checkpoint at an episode's end, as every one, so the resumed run
                # continues exactly (one cut mid-episode would start a new episode in its place).
                state.eval_pending = bool(cfg.eval_trajectories) and state.global_step >= grid.next_eval
                learner.checkpoint(asdict(state), memory)
                break
            _evaluate_and_checkpoint(cfg, learner, memory, state, grid)
        learner.wait()
        bar.update(state.global_step, _exploration(cfg, state.global_step), float(np.mean(recent)) if recent else float("nan"), force=True)
    finally:
        bar.close()
    return time.perf_counter() - t_start


def _redrive(cfg: Config, learner: Learner, env: Any, memory: ReplayMemory, cut: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Bring a fresh server to where the step budget cut an episode: reset it with the episode's
    options and replay the decisions taken, the teacher watching as it did (its lag is state);
    the acting policy takes up its saved state. Nothing is stored or learned, nothing drawn.

    Raises:
        ResumeError: the re-driven episode does not end on the frame the replay memory
            holds (the simulator is no longer deterministic for these actions).
    """
    obs, info = env.reset(options=cut["options"])
    if learner.teacher is not None:
        learner.teacher.reset()
    for action, target, continuous in cut["taken"]:
        if isinstance(learner.teacher, PolicyTeacher):
            learner.teacher.decide(obs, env.actions, cfg.teacher_brake)
        elif learner.teacher is not None:
            learner.teacher(info)
        obs, _, _, _, info = Decision(int(action), target, continuous).step(env)
    learner.acting_policy.set_episode_state(cut["policy"])
    if not np.array_equal(obs["frames"][-1], memory.frames[(memory.total - 1) % memory.capacity]):
        raise ResumeError(f"{learner.run_dir}: the episode cut at step {learner.saved.get('global_step')} re-drove to another camera frame than the replay memory holds")
    return obs, info


def _exploration(cfg: Config, step: int) -> float:
    """What explores at env step ``step``: the actor-critic's noise std, else the DQN's ε."""
    return noise_std(cfg, step) if is_continuous(cfg.action) else linear_schedule(cfg.start_e, cfg.end_e, cfg.exploration_steps, step)


def _choose(cfg: Config, learner: Learner, env: Any, obs: dict[str, Any], info: dict[str, Any], exploring: float, step: int) -> tuple[Decision, int | float]:
    """The decision to take and the action to store; ``exploring`` is :func:`_exploration` at ``step``.

    Actor-critic (a continuous action): the actor's target plus the scheduled Gaussian
    noise (:func:`agent_client.rl.actor_critic.explore`), stored as taken; with ``bc_steps``,
    the student's target until learning starts, so that the clone learns its decision on the
    states it drives into and the critic's first data are its own.
    Double DQN: ε-greedy, stored as taken. With a teacher (DAgger): the teacher's label is
    stored whoever drives; the teacher drives a share β of the steps, falling from 1 to 0
    over ``teacher_steps``, and the ε-greedy student the rest, so that it learns the
    teacher's answer in the states its own mistakes lead to.
    """
    rng = learner.acting_rng
    if learner.continuous:
        if cfg.bc_steps > 0 and step < cfg.learning_starts:
            assert learner.student is not None  # loaded with the learner
            if learner.q.recurrent:
                learner.acting_policy.target(obs)  # its state steps on every observation, whoever drives
            return noisy(student_target(*learner.student, obs), exploring, rng)
        return explore(learner.acting_policy, obs, exploring, rng)
    # a recurrent student's state steps on every observation, whoever drives (it draws nothing)
    own = learner.act(obs) if learner.q.recurrent else None
    if isinstance(learner.teacher, PolicyTeacher):  # a network on the same observation: distillation
        own, label = learner.teacher.decide(obs, env.actions, cfg.teacher_brake)
        if rng.random() < linear_schedule(1.0, 0.0, cfg.teacher_steps, step):
            return own, label
    elif learner.teacher is not None:
        label = env.actions.imitate(learner.teacher(info), cfg.teacher_brake)  # privileged: reads the gap, never the network
        if rng.random() < linear_schedule(1.0, 0.0, cfg.teacher_steps, step):
            return Decision(label), label
    decision = Decision(int(rng.integers(env.action_space.n))) if rng.random() < exploring else (own if own is not None else learner.act(obs))
    return decision, (label if learner.teacher is not None else decision.action)


def _evaluate_and_checkpoint(cfg: Config, learner: Learner, memory: ReplayMemory, state: LoopState, grid: _Schedule) -> None:
    """At an episode end: evaluate and checkpoint when their grids say so, and at the end."""
    finished = state.global_step >= cfg.total_steps
    if cfg.eval_trajectories and (state.global_step >= grid.next_eval or (finished and grid.last_eval_step != state.global_step)):
        learner.evaluate(state.global_step)
        grid.last_eval_step = state.global_step
        while grid.next_eval <= state.global_step:
            grid.next_eval += cfg.eval_every
    if state.global_step >= grid.next_checkpoint or finished:
        learner.checkpoint(asdict(state), memory)
        grid.next_checkpoint = state.global_step + cfg.checkpoint_every
