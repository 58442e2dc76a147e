"""Many simulator servers, one learner, without Ray: `vacc train --servers K` (issue #10)."""

from __future__ import annotations

import csv
import os
import shlex
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from proctools import (
    assert_no_servers_left,
    descendants,
    procs,
    servers_of,
    vacc_job,
    wait_gone,
    wait_until_both_actors_deliver,
)

from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config, single_stream_only
from agent_client.rl.distributed import RAY_INSTALL_HINT, StreamActor, train_distributed
from agent_client.rl.replay import ReplayMemory, StreamReplay
from agent_client.rl.train import train
from vacc.cli import main

SMALL = Config(
    total_steps=300, learning_starts=100, train_every=8, batch_size=8, buffer_size=1000, exploration_steps=200,
    target_sync_every=80, episode_seconds=3.0, checkpoint_every=10**6, eval_every=0, eval_trajectories=(),
    log_every=50, servers=2, actor_batch=20, weight_sync_every=5,
)  # fmt: skip

CLI_ARGS = [
    "train", "--reward", "gap", "--steps", "300", "--learning-starts", "100", "--train-every", "8",
    "--batch-size", "8", "--buffer-size", "1000", "--exploration-steps", "200", "--episode-seconds", "3",
    "--eval-every", "0", "--eval-trajectories", "test-1", "--eval-seconds", "0.5", "--log-every", "50",
    "--actor-batch", "20", "--weight-sync-every", "5", "--quiet", "--seed", "4",
]  # fmt: skip


def _assert_no_orphans(actor_pids) -> None:
    assert wait_gone(list(actor_pids)) == [], "actor processes left behind"
    assert_no_servers_left(actor_pids)


def _batch(rng, starts, n_frames) -> dict:
    """A synthetic actor batch: ``starts`` marks episode starts among ``n_frames`` records."""
    start = np.zeros(n_frames, np.bool_)
    start[list(starts)] = True
    return {
        "frames": rng.integers(0, 256, (n_frames, FRAME_H, FRAME_W), dtype=np.uint8),
        "speeds": rng.uniform(20, 30, n_frames).astype(np.float32),
        "start": start,
        "actions": rng.integers(0, 21, n_frames).astype(np.uint8),
        "rewards": rng.uniform(-1, 1, n_frames).astype(np.float32),
        "terminated": np.zeros(n_frames, np.bool_),
        "truncated": np.zeros(n_frames, np.bool_),
    }


def test_stream_replay_samples_every_stream_and_keeps_the_bytes_per_transition():
    cfg = Config(buffer_size=3001, servers=3, frame_stack=8, stack_stride=2)
    replay = StreamReplay(cfg.buffer_size, cfg.servers, cfg.frame_stack, cfg.stack_stride)
    assert [m.capacity for m in replay.streams] == [1001, 1000, 1000] and replay.capacity == 3001
    assert replay.nbytes / replay.capacity <= 1.1 * FRAME_H * FRAME_W
    rng = np.random.default_rng(0)
    for i, n in enumerate((600, 300, 0)):  # stream 2 has nothing yet: never sampled
        if n:
            b = _batch(rng, [0, n // 2], n)
            for j in range(n):
                if b["start"][j]:
                    replay.start(i, b["frames"][j], float(b["speeds"][j]))
                else:
                    replay.add(i, int(b["actions"][j]), float(b["rewards"][j]), False, False, b["frames"][j], float(b["speeds"][j]))
    counts = np.zeros(3)
    for _ in range(50):
        s = replay.sample(32, rng, n_step=3, gamma=0.9)
        assert s.frames.shape == (32, 8, FRAME_H, FRAME_W) and s.next_frames.shape == (32, 8, FRAME_H, FRAME_W)
        assert s.returns.shape == (32,) and s.actions.dtype == torch.int64
    # proportional to the streams' sizes (600 : 300 : 0 slots)
    rng = np.random.default_rng(1)
    sizes = np.array([len(m) if m.transitions else 0 for m in replay.streams], float)
    for _ in range(200):
        counts += rng.multinomial(32, sizes / sizes.sum())
    assert counts[2] == 0 and counts[0] / counts[1] == pytest.approx(2.0, rel=0.1)


def test_shared_weights_hold_no_lock_an_actor_could_die_with():
    """The local actors read weights through a seqlock: a torn read is retried, and a
    writer that never finishes (a learner killed mid-write) leaves the reader its old weights."""
    import multiprocessing as mp

    from agent_client.rl.distributed import _Shared

    shared = _Shared(mp.get_context("spawn"), 5)
    assert shared.read() is not None and shared.read()[1] == -1
    shared.write(np.arange(5, dtype=np.float32), 7)
    flat, version = shared.read()
    assert version == 7 and flat.tolist() == [0, 1, 2, 3, 4]
    shared.seq.value += 1  # a write that never ends
    t0 = time.monotonic()
    assert shared.read() is None and time.monotonic() - t0 < 5


def test_actor_episodes_are_a_function_of_seed_and_index():
    """The same (run seed, actor) plays the same episodes; another actor plays others;
    a restarted actor continues its sequence at the episode it is told."""
    cfg = Config(episode_seconds=1.0, seed=11, frame_stack=8, stack_stride=2)
    batches = []
    for index, base in ((0, 0), (0, 0), (1, 0), (0, 1)):
        actor = StreamActor(cfg, index, episode_base=base)
        try:
            batches.append(actor.collect(25, epsilon=1.0))  # random actions, from the episode's generator
        finally:
            actor.close()
            actor.close()  # safe twice
    a, b, other, later = batches
    for key in ("frames", "speeds", "start", "actions", "rewards", "terminated", "truncated", "episode"):
        np.testing.assert_array_equal(a[key], b[key])
    assert a["steps"] == 25 and len(a["frames"]) == 25 + a["start"].sum()
    assert list(np.unique(a["episode"])) == [0, 1, 2]  # 10-step episodes
    assert not np.array_equal(a["actions"], other["actions"])
    # the actor restarted at episode 1 replays actor 0's episode 1
    first_of_1 = np.flatnonzero(a["episode"] == 1)
    np.testing.assert_array_equal(later["frames"][:5], a["frames"][first_of_1[:5]])
    np.testing.assert_array_equal(later["actions"][:5], a["actions"][first_of_1[:5]])


def test_servers_2_trains_without_ray_and_ray_flag_says_how_to_install(tmp_path, monkeypatch):
    """`vacc train --servers 2` with `import ray` failing: both actors deliver; `--ray` explains."""
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    out = tmp_path / "run"
    t0 = time.monotonic()
    result = CliRunner().invoke(main, [*CLI_ARGS, "--servers", "2", "--out", str(out)])
    assert result.exit_code == 0, result.output
    print(f"--servers 2, 300 steps: {time.monotonic() - t0:.1f} s")
    assert "trained 300 steps" in result.output and "2 actors (local)" in result.output
    for name in ("config.json", "scalars.csv", "latest.pt", "best.pt", "summary.json", "replay-300-0.npz", "replay-300-1.npz"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader(open(out / "scalars.csv")))
    last = {r["name"]: float(r["value"]) for r in rows}
    assert last["charts/transitions/actor-0"] > 0 and last["charts/transitions/actor-1"] > 0
    assert last["charts/transitions/actor-0"] + last["charts/transitions/actor-1"] == 300
    assert last["charts/actor_restarts"] == 0 and last["charts/updates"] == 300 // 8 - 100 // 8
    for name in ("charts/episodic_return", "charts/SPS", "losses/td_loss", "charts/policy_lag_updates", "eval/gap_rmse_m"):
        assert name in last, name
    ckpt = torch.load(out / "latest.pt", weights_only=True)
    assert ckpt["state"]["global_step"] == 300 and ckpt["config"]["servers"] == 2
    assert ckpt["optimizer"]["state"][0]["step"] == 300 // 8 - 100 // 8
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["actor_pids"]) == 2
    _assert_no_orphans(summary["actor_pids"])

    result = CliRunner().invoke(main, [*CLI_ARGS, "--servers", "2", "--ray", "--out", str(tmp_path / "ray")])
    assert result.exit_code == 1
    assert RAY_INSTALL_HINT in result.output and "pip install 'vacc[ray]'" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "ray").exists()


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--preroll"], "--preroll needs the single-stream trainer"),
        (["--action", "ramp", "--teacher", "acc-55"], "--teacher acc-55 and --action ramp need the single-stream trainer"),
        (["--train-trajectories", "random,closing"], "--train-trajectories random,closing needs the single-stream trainer"),
        (["--train-traffic", "8"], "--train-traffic 8 needs the single-stream trainer"),
        (["--train-sun-elevation", "0.35,0.6"], "--train-sun-elevation needs the single-stream trainer"),
    ],
)
def test_ray_with_one_server_refuses_what_only_the_single_stream_trainer_does(tmp_path, options, words):
    # Config refuses these with servers > 1 only; --ray --servers 1 also runs the K-stream trainer.
    result = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--ray", *options, "--out", str(tmp_path / "r")])
    assert result.exit_code == 2 and words in result.output, result.output
    with pytest.raises(ValueError, match="starts its episodes cold"):
        train_distributed(Config(preroll=True), tmp_path / "d", use_ray=True)
    assert not (tmp_path / "r").exists() and not (tmp_path / "d").exists()
    assert single_stream_only(Config()) is None
    # --servers K says the same, naming every option, at the first one's flag
    result = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--servers", "2", "--preroll", "--aux-gap", "1", "--out", str(tmp_path / "k")])
    assert result.exit_code == 2 and "--aux-gap" in result.output and "--aux-gap 1 and --preroll need the single-stream trainer" in " ".join(result.output.split())


def test_a_killed_local_actor_is_restarted_and_training_goes_on(tmp_path):
    killed: list[int] = []
    back: list[int] = []

    def kill_once(step, i, batch):
        if i == 0 and step >= 150 and not killed:
            killed.append(batch["pid"])
            os.kill(batch["pid"], signal.SIGKILL)  # no clean-up runs in the actor
        elif i == 0 and killed and batch["pid"] != killed[0]:
            back.append(step)
        elif i == 1 and killed and not back:
            time.sleep(0.3)  # slow the learner so that the run lasts until actor 0 is back

    cfg = Config(**{**SMALL.__dict__, "total_steps": 1200})
    t0 = time.monotonic()
    summary = train_distributed(cfg, tmp_path / "run", progress=False, on_batch=kill_once)
    print(f"kill test: {time.monotonic() - t0:.1f} s, {summary['transitions_by_actor']}, restarts {summary['restarts_by_actor']}")
    assert killed and back and summary["steps"] == 1200
    assert summary["restarts_by_actor"] == [1, 0]
    assert len(summary["actor_pids"]) == 3 and killed[0] in summary["actor_pids"]
    rows = list(csv.DictReader(open(tmp_path / "run" / "scalars.csv")))
    restarts = [float(r["value"]) for r in rows if r["name"] == "charts/actor_restarts"]
    assert restarts[-1] == 1
    # the restarted actor delivered: its count grew after the restart was logged
    step_of_restart = min(int(r["step"]) for r in rows if r["name"] == "charts/actor_restarts" and float(r["value"]) == 1)
    a0 = [(int(r["step"]), float(r["value"])) for r in rows if r["name"] == "charts/transitions/actor-0"]
    before = max((v for s, v in a0 if s <= step_of_restart), default=0.0)
    assert a0[-1][1] > before
    _assert_no_orphans(summary["actor_pids"])


def test_resume_of_a_two_server_run(tmp_path):
    run = tmp_path / "run"
    first = train_distributed(Config(**{**SMALL.__dict__, "total_steps": 200}), run, progress=False)
    assert first["steps"] == 200
    resumed = train_distributed(SMALL, run, resume=True, progress=False)
    assert resumed["steps"] == 300 and resumed["updates"] == 300 // 8 - 100 // 8
    ckpt = torch.load(run / "latest.pt", weights_only=True)
    assert ckpt["optimizer"]["state"][0]["step"] == resumed["updates"]
    assert sum(ckpt["state"]["transitions_by_actor"]) == 300
    assert sorted(p.name for p in run.glob("replay-*.npz")) == ["replay-300-0.npz", "replay-300-1.npz"]
    for i in range(2):
        assert ReplayMemory(500, 8, 2).load(run / f"replay-300-{i}.npz") == 300
    _assert_no_orphans(first["actor_pids"] + resumed["actor_pids"])
    # the wrong trainer for the checkpoint is refused, by name
    with pytest.raises(InputFileError, match="written by the K-stream trainer; resume it with --servers/--ray"):
        train(Config(**{**SMALL.__dict__, "servers": 1}), run, resume=True, progress=False)
    single = tmp_path / "single"
    train(Config(**{**SMALL.__dict__, "servers": 1, "total_steps": 20, "learning_starts": 10}), single, progress=False)
    with pytest.raises(InputFileError, match="written by the single-stream trainer; resume it without --servers/--ray"):
        train_distributed(SMALL, single, resume=True, progress=False)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL], ids=["SIGTERM", "SIGINT", "SIGKILL"])
def test_learner_signals_leave_no_process_behind(tmp_path, sig):
    """SIGTERM, Ctrl-C (SIGINT) or kill -9 of `vacc train --servers 2`: actors and servers all go.
    SIGTERM, as a batch system's pre-emption, stops with a checkpoint like a first Ctrl-C."""
    out = tmp_path / "run"
    args = [*CLI_ARGS, "--servers", "2", "--steps", "100000", "--log-every", "20", "--out", str(out)]
    with vacc_job(args, stderr_path=tmp_path / "stderr.txt") as proc:
        wait_until_both_actors_deliver(out)
        tree = descendants(proc.pid)
        assert len(servers_of(tree)) == 2, tree
        os.kill(proc.pid, sig)
        proc.wait(timeout=60)
    stderr = (tmp_path / "stderr.txt").read_text(errors="replace")
    assert wait_gone(tree, timeout=20) == [], (tree, stderr[-2000:])
    if sig != signal.SIGKILL:
        assert "Traceback" not in stderr, stderr[-2000:]
    if sig == signal.SIGTERM:
        assert proc.returncode == 143 and "SIGTERM: stopping at the next point it can resume from, with a checkpoint" in stderr, stderr[-2000:]
        assert (out / "latest.pt").is_file()


def _in_own_group(args, stderr_path):
    """`vacc ARGS` in a session of its own: a process group, as a job started from a terminal."""
    return vacc_job(args, own_group=True, stdout=subprocess.PIPE, stderr_path=stderr_path)


def test_first_ctrl_c_of_a_two_server_run_saves_a_checkpoint_that_resumes(tmp_path):
    """Ctrl-C to the whole process group, as a terminal sends it: the learner checkpoints,
    prints the command that resumes, and stops its actors and their servers in order."""
    out = tmp_path / "run"
    args = [*CLI_ARGS, "--servers", "2", "--steps", "100000", "--checkpoint-every", "100000", "--log-every", "20", "--out", str(out)]
    with _in_own_group(args, tmp_path / "stderr.txt") as proc:
        wait_until_both_actors_deliver(out)
        tree = descendants(proc.pid)
        assert len(servers_of(tree)) == 2, tree
        os.killpg(proc.pid, signal.SIGINT)
        stdout, _ = proc.communicate(timeout=120)
    stderr = (tmp_path / "stderr.txt").read_text(errors="replace")
    assert proc.returncode == 130, stderr[-2000:]
    assert "Ctrl-C again to abort" in stderr and "Traceback" not in stderr and "died" not in stderr, stderr[-2000:]
    assert wait_gone(tree, timeout=20) == [], (tree, stderr[-2000:])
    assert not list(out.glob("*.tmp"))
    ckpt = torch.load(out / "latest.pt", weights_only=True)
    step = ckpt["state"]["global_step"]
    assert ckpt["trainer"] == "streams" and 0 < step < 100000 and sorted(ckpt["replay"]) == [f"replay-{step}-0.npz", f"replay-{step}-1.npz"]
    # the printed command resumes it: --servers 2 comes back from config.json
    (command,) = [line.split("continue with: ", 1)[1] for line in stdout.splitlines() if "continue with: " in line]
    resumed = subprocess.run([sys.executable, "-m", "vacc", *shlex.split(command)[1:], "--steps", str(step + 40), "--quiet"],
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "2 actors (local)" in resumed.stdout
    assert torch.load(out / "latest.pt", weights_only=True)["state"]["global_step"] == step + 40


def test_ctrl_c_while_the_actors_start_kills_none_of_them(tmp_path):
    """Before an actor has made its own process group it is still in the terminal's job;
    it starts with SIGINT ignored, so the Ctrl-C stops the run instead of killing it."""
    out = tmp_path / "run"
    seen: set[int] = set()  # every process of the run: actors, their servers
    with _in_own_group([*CLI_ARGS, "--servers", "2", "--steps", "100000", "--out", str(out)], tmp_path / "stderr.txt") as proc:
        deadline = time.monotonic() + 120
        # both actors exist: they import for seconds yet, still in this process group. (Not
        # earlier: a Ctrl-C in the milliseconds the learner spends in Process.start, where it
        # ignores SIGINT so that the actor inherits that, can still be lost; docs/scale-out.md.)
        while len([p for p in descendants(proc.pid) if "spawn_main" in procs().get(p, (0, ""))[1]]) < 2:
            assert proc.poll() is None and time.monotonic() < deadline, "the actors did not start"
            time.sleep(0.01)
        time.sleep(0.2)  # the learner is past Process.start; the actors are still importing
        os.killpg(proc.pid, signal.SIGINT)
        while proc.poll() is None and time.monotonic() < deadline + 60:
            seen |= descendants(proc.pid)
            time.sleep(0.1)
        stdout, _ = proc.communicate(timeout=60)
    stderr = (tmp_path / "stderr.txt").read_text(errors="replace")
    assert proc.returncode == 130, stderr[-2000:]
    assert "died" not in stderr and "KeyboardInterrupt" not in stderr and "Traceback" not in stderr, stderr[-2000:]
    assert "--resume" in stdout and (out / "latest.pt").exists()
    assert wait_gone(seen, timeout=20) == [], seen
    assert_no_servers_left(seen)
