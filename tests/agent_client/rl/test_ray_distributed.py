"""`vacc train --ray --servers K`: simulator servers and their actors as Ray actors (issue #10).

Ray is in the `dev` extra, so these run in `make test`; they are skipped only where
Ray cannot be imported.
"""

from __future__ import annotations

import csv
import os
import shlex
import signal
import subprocess
import time

import pytest
import torch
from proctools import (
    assert_no_servers_left,
    descendants,
    procs,
    vacc_job,
    wait_gone,
    wait_until_both_actors_deliver,
)

from agent_client.rl.config import Config
from agent_client.rl.distributed import train_distributed

ray = pytest.importorskip("ray")

SMALL = Config(
    total_steps=300, learning_starts=100, train_every=8, batch_size=8, buffer_size=1000, exploration_steps=200,
    target_sync_every=80, episode_seconds=3.0, checkpoint_every=10**6, eval_every=0, eval_trajectories=(),
    log_every=50, servers=2, actor_batch=20, weight_sync_every=5, seed=6,
)  # fmt: skip


def test_sigterm_to_a_ray_run_leaves_no_process_behind(tmp_path):
    """Runs first, before this module starts its own Ray: `vacc train --ray` starts one."""
    out = tmp_path / "run"
    args = [
        "train", "--reward", "gap", "--steps", "100000", "--learning-starts", "100", "--batch-size", "8",
        "--buffer-size", "1000", "--episode-seconds", "3", "--eval-every", "0", "--log-every", "20",
        "--quiet", "--servers", "2", "--ray", "--out", str(out),
    ]  # fmt: skip
    with vacc_job(args, stderr_path=tmp_path / "stderr.txt") as proc:
        wait_until_both_actors_deliver(out)
        tree = descendants(proc.pid)
        servers = [p for p in tree if "sim_server" in procs().get(p, (0, ""))[1]]
        assert len(servers) == 2, (tree, (tmp_path / "stderr.txt").read_text()[-2000:])
        proc.terminate()
        proc.wait(timeout=60)
    stderr = (tmp_path / "stderr.txt").read_text(errors="replace")
    assert wait_gone(tree, timeout=20) == [], stderr[-2000:]  # Ray's own processes, its workers and the servers
    assert "Traceback" not in stderr and "SIGTERM received" not in stderr, stderr[-2000:]
    # ray.init takes SIGTERM for itself; the trainer takes it back, so a kill checkpoints
    assert proc.returncode == 143 and "SIGTERM: stopping at the next point it can resume from" in stderr, stderr[-2000:]
    assert (out / "latest.pt").is_file()


def test_first_ctrl_c_of_a_ray_run_saves_a_checkpoint(tmp_path):
    """Ctrl-C to the whole process group, as a terminal sends it (also before this module's
    Ray): the learner checkpoints and prints a resume command that keeps --ray."""
    out = tmp_path / "run"
    args = [
        "train", "--reward", "gap", "--steps", "100000", "--learning-starts", "100", "--batch-size", "8",
        "--buffer-size", "1000", "--episode-seconds", "3", "--eval-every", "0", "--log-every", "20",
        "--checkpoint-every", "100000", "--quiet", "--servers", "2", "--ray", "--out", str(out),
    ]  # fmt: skip
    with vacc_job(args, own_group=True, stdout=subprocess.PIPE, stderr_path=tmp_path / "stderr.txt") as proc:
        wait_until_both_actors_deliver(out)
        tree = descendants(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        stdout, _ = proc.communicate(timeout=120)
    stderr = (tmp_path / "stderr.txt").read_text(errors="replace")
    assert proc.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr and "call failed" not in stderr, stderr[-2000:]
    assert wait_gone(tree, timeout=20) == [], stderr[-2000:]
    ckpt = torch.load(out / "latest.pt", weights_only=True)
    assert ckpt["trainer"] == "streams" and ckpt["state"]["global_step"] > 0 and not list(out.glob("*.tmp"))
    (command,) = [line.split("continue with: ", 1)[1] for line in stdout.splitlines() if "continue with: " in line]
    assert shlex.split(command)[-2:] == ["--resume", "--ray"], command


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance of 2 CPUs, as the issue asks; shut down after the module."""
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200 * 2**20, log_to_driver=False, _node_ip_address="127.0.0.1")
    try:
        yield ray
    finally:
        ray.shutdown()


def test_ray_two_servers_train_and_both_actors_deliver(local_ray, tmp_path):
    t0 = time.monotonic()
    summary = train_distributed(SMALL, tmp_path / "run", progress=False, use_ray=True)
    print(f"ray, 2 servers, 300 steps: {time.monotonic() - t0:.1f} s, {summary['transitions_by_actor']}")
    assert summary["backend"] == "ray" and summary["steps"] == 300
    assert all(n > 0 for n in summary["transitions_by_actor"]) and sum(summary["transitions_by_actor"]) == 300
    assert summary["restarts_by_actor"] == [0, 0] and len(summary["actor_pids"]) == 2
    assert summary["updates"] == 300 // 8 - 100 // 8
    assert os.getpid() not in summary["actor_pids"]  # the actors ran in Ray's workers
    names = {r["name"] for r in csv.DictReader(open(tmp_path / "run" / "scalars.csv"))}
    assert {"charts/transitions/actor-0", "charts/transitions/actor-1", "charts/actor_restarts", "losses/td_loss"} <= names
    assert (tmp_path / "run" / "latest.pt").is_file()
    assert ray.is_initialized()  # a Ray instance it did not start is left running
    assert_no_servers_left(summary["actor_pids"])


def test_ray_killed_actor_is_restarted_and_training_goes_on(local_ray, tmp_path):
    killed: list[int] = []
    back: list[int] = []

    def kill_once(step, i, batch):
        if i == 1 and step >= 150 and not killed:
            killed.append(batch["pid"])
            os.kill(batch["pid"], signal.SIGKILL)  # the actor's worker process, as a crash would
        elif i == 1 and killed and batch["pid"] != killed[0]:
            back.append(step)
        elif i == 0 and killed and not back:
            time.sleep(0.3)  # slow the learner so that the run lasts until Ray has brought actor 1 back

    cfg = Config(**{**SMALL.__dict__, "total_steps": 1200})
    t0 = time.monotonic()
    summary = train_distributed(cfg, tmp_path / "run", progress=False, use_ray=True, on_batch=kill_once)
    print(f"ray kill test: {time.monotonic() - t0:.1f} s, {summary['transitions_by_actor']}, restarts {summary['restarts_by_actor']}")
    assert killed and back and summary["steps"] == 1200
    assert summary["restarts_by_actor"] == [0, 1]
    assert len(summary["actor_pids"]) == 3 and killed[0] in summary["actor_pids"]
    rows = list(csv.DictReader(open(tmp_path / "run" / "scalars.csv")))
    assert max(float(r["value"]) for r in rows if r["name"] == "charts/actor_restarts") == 1
    assert_no_servers_left(summary["actor_pids"])


def test_ray_refuses_more_actors_than_the_local_instance_has_cpus(local_ray, tmp_path):
    from agent_client.errors import ClientError

    with pytest.raises(ClientError, match="4 actors x 1 CPU need 4 CPUs; the Ray cluster has 2"):
        train_distributed(Config(**{**SMALL.__dict__, "servers": 4}), tmp_path / "run", progress=False, use_ray=True)
    assert ray.is_initialized()
