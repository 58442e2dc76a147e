"""kill -9 at random moments of a training run never leaves an unresumable checkpoint."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import torch

from agent_client.rl.replay import ReplayMemory

ARGS = [
    "train", "--reward", "gap", "--steps", "300", "--learning-starts", "20", "--episode-seconds", "3",
    "--buffer-size", "1000", "--exploration-steps", "100", "--eval-every", "0", "--eval-trajectories", "test-1",
    "--eval-seconds", "0.5", "--checkpoint-every", "10", "--quiet", "--seed", "2",
]  # fmt: skip


def _check_pair(run):
    """latest.pt loads, and the replay file it names holds the same step."""
    ckpt = torch.load(run / "latest.pt", map_location="cpu", weights_only=False)
    step = ckpt["state"]["global_step"]
    (name,) = ckpt["replay"]
    replay = run / name
    assert ReplayMemory(1000, 8, 2).load(replay) == step
    return step


def _newest_step(run):
    """The highest step among the replay files on disk (-1 if none)."""
    steps = [int(p.stem.split("-")[1]) for p in run.glob("replay-*.npz") if p.stem.split("-")[1].isdigit()]
    return max(steps, default=-1)


def _run_until(cmd, run, target, delay):
    """Start training; SIGKILL it `delay` s after the replay on disk reaches `target`.

    Kills are paced by progress, not by wall-clock, so a fast machine cannot
    finish the run before the first kill. Returns True if it was killed.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if _newest_step(run) >= target:
                time.sleep(delay)  # lands anywhere in the next checkpoint's write
                break
            time.sleep(0.005)
        if proc.poll() is not None:
            return False
        proc.kill()  # SIGKILL: no clean-up runs
        return True
    finally:
        proc.wait()


def test_random_kill_9_then_resume(tmp_path):
    run = tmp_path / "run"
    rng = np.random.default_rng(7)
    deadline = time.monotonic() + 240  # bounded in time as well as in kills
    kills, steps_seen = 0, []
    targets = np.sort(rng.choice(np.arange(30, 280, 10), size=4, replace=False))
    while kills < 4 and time.monotonic() < deadline:
        # killed before its first checkpoint: start afresh over the half-made folder
        resume = ["--resume"] if (run / "latest.pt").exists() else ["--overwrite"]
        cmd = [sys.executable, "-m", "vacc", *ARGS, "--out", str(run), *resume]
        if not _run_until(cmd, run, int(targets[kills]), float(rng.uniform(0.0, 0.3))):
            break  # finished before the kill
        kills += 1
        if (run / "latest.pt").exists():
            steps_seen.append(_check_pair(run))
    assert kills >= 1 and steps_seen, (kills, steps_seen)
    print("killed", kills, "times; resumed from steps", steps_seen)
    final = subprocess.run([sys.executable, "-m", "vacc", *ARGS, "--out", str(run), "--resume"], capture_output=True, text=True, timeout=300)
    assert final.returncode == 0, final.stderr
    assert _check_pair(run) == 300
    assert steps_seen == sorted(steps_seen)  # every kill resumed from the last good checkpoint
    leftovers = [p.name for p in run.glob("replay-*.npz")]
    assert leftovers == ["replay-300.npz"]
