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


def test_random_kill_9_then_resume(tmp_path):
    run = tmp_path / "run"
    rng = np.random.default_rng(7)
    deadline = time.monotonic() + 240  # bounded in time as well as in kills
    kills, steps_seen = 0, []
    while kills < 4 and time.monotonic() < deadline:
        # killed before its first checkpoint: start afresh over the half-made folder
        resume = ["--resume"] if (run / "latest.pt").exists() else ["--overwrite"]
        proc = subprocess.Popen([sys.executable, "-m", "vacc", *ARGS, "--out", str(run), *resume], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            proc.wait(timeout=float(rng.uniform(4.0, 9.0)))
        except subprocess.TimeoutExpired:
            proc.kill()  # SIGKILL: no clean-up runs
            proc.wait()
            kills += 1
        else:
            break  # finished before the kill
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
