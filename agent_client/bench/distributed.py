"""Scaling figures of the multi-server trainer (:mod:`agent_client.rl.distributed`).

* environment steps/s into one learner against K = 1, 2, 4 actors (each with its own
  simulator server), learning off, so that the figure is the acting side's; ε = 0.05,
  so that actors run their forward pass as a trained policy does;
* the same K = 1 stream in-process (:func:`agent_client.rl.train.train`) as the reference;
* optionally with learning on (one batch-32 update per 8 steps), where the learner limits;
* the learner's cost per received transition (replay insert) and per update, which
  bound a 100-node run (see docs/benchmarks.md).

The K values are interleaved over the repetitions so that a change in the machine's
load hits every K alike; read the ratios.

    python -m agent_client.bench.distributed [--ks 1,2,4] [--steps 1500] [--reps 2] [--ray] [--learning]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from typing import Any

import numpy as np

from agent_client.bench.ddqn import update_cost
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config
from agent_client.rl.distributed import train_distributed
from agent_client.rl.replay import StreamReplay
from agent_client.rl.train import train

__all__ = ["acting_rate", "learner_costs", "run"]

MIN_DELIVERIES = 8  # per actor, for a window that opens after every actor's first


def _cfg(k: int, steps: int, learning: bool) -> Config:
    return Config(
        total_steps=steps, servers=k, start_e=0.05, end_e=0.05, learning_starts=(200 if learning else steps),
        train_every=8, batch_size=32, buffer_size=max(2 * steps, 1000), eval_trajectories=(), eval_every=0,
        checkpoint_every=10**9, episode_seconds=60.0, log_every=10**9,
    )  # fmt: skip


def _tree_cpu_s(root: int) -> float:
    """[s] user + system CPU time of every live descendant of ``root`` (Linux /proc)."""
    procs: dict[int, tuple[int, float]] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            procs[int(d)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / tick)
    found: set[int] = set()
    frontier = {root}
    while frontier:
        frontier = {pid for pid, (ppid, _) in procs.items() if ppid in frontier} - found
        found |= frontier
    return sum(procs[p][1] for p in found)


def acting_rate(k: int, steps: int, learning: bool = False, use_ray: bool = False, actor_cpus: float = 1.0) -> dict[str, Any]:
    """Env steps/s reaching one learner from ``k`` actors, over the whole run and over a
    window that opens once every actor has delivered (start-up excluded) and closes at
    90 % of the run (shut-down excluded).

    Also the CPU seconds per env step of every process of the run together (learner,
    actors, servers; with Ray, its daemons too, as :func:`run` starts Ray here) over that
    window, read from /proc. Actors deliver ``actor_batch`` transitions at a time, so a
    run of a few deliveries per actor has no window: its window figures are left out
    (``window`` says why), rather than counting steps taken before the window opened.
    """
    marks: list[tuple[int, float, float]] = []  # (step, wall, cpu)
    delivered: set[int] = set()

    def on_batch(step: int, i: int, batch: dict[str, Any]) -> None:
        delivered.add(i)
        if (not marks and len(delivered) == k) or (len(marks) == 1 and step >= 0.9 * steps):
            marks.append((step, time.perf_counter(), _tree_cpu_s(os.getpid()) + time.process_time()))

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        s = train_distributed(_cfg(k, steps, learning), tmp, progress=False, use_ray=use_ray, actor_cpus=actor_cpus, on_batch=on_batch)
        wall = time.perf_counter() - t0
    row = {
        "k": k, "steps": s["steps"], "env_steps_per_s": s["env_steps_per_s"], "wall_s": wall, "run_steps_per_s": s["steps"] / wall,
        "transitions_by_actor": s["transitions_by_actor"], "load": os.getloadavg()[0],
    }  # fmt: skip
    per_actor = steps / (k * Config.actor_batch)
    if len(marks) == 2 and per_actor >= MIN_DELIVERIES:  # Ray: its daemons and workers are children of this process too (ray.init here)
        (s0, t0, c0), (s1, t1, c1) = marks
        row["window_steps_per_s"] = (s1 - s0) / (t1 - t0)
        row["cpu_ms_per_step"] = 1e3 * (c1 - c0) / (s1 - s0)
        row["cores_used"] = (c1 - c0) / (t1 - t0)
    else:
        row["window"] = f"none: {per_actor:.1f} deliveries per actor, at least {MIN_DELIVERIES} needed (--steps {MIN_DELIVERIES * k * Config.actor_batch} or more)"
    return row


def single_stream_rate(steps: int, learning: bool = False) -> dict[str, Any]:
    """Env steps/s of :func:`agent_client.rl.train.train` (one in-process stream, no IPC)."""
    with tempfile.TemporaryDirectory() as tmp:
        s = train(_cfg(1, steps, learning), tmp, progress=False)
    return {"k": 1, "steps": s["steps"], "env_steps_per_s": s["steps"] / s["wall_s"], "wall_s": s["wall_s"], "load": os.getloadavg()[0]}


def learner_costs(k: int = 4, capacity: int = 8_000, updates: int = 20) -> dict[str, float]:
    """CPU seconds (not wall: the machine is shared) the learner spends per received
    transition (replay insert), per batch-32 5-step sample, and per batch-32 update on
    one CPU thread. Medians over repetitions; the replay is filled once first, so
    that page faults of fresh memory are not counted."""
    cfg = Config(servers=k, buffer_size=capacity)
    replay = StreamReplay(cfg.buffer_size, k, cfg.frame_stack, cfg.stack_stride)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (50, FRAME_H, FRAME_W), dtype=np.uint8)

    def fill(n_batches: int) -> float:
        t0 = time.process_time()
        for n_batch in range(n_batches):
            i = n_batch % k
            replay.start(i, frames[0], 25.0)
            for j in range(1, 50):
                replay.add(i, 3, 0.1, False, False, frames[j], 25.0)
        return (time.process_time() - t0) / (49 * n_batches)

    fill(capacity // 49 + k)  # touch every page once
    insert = float(np.median([fill(20) for _ in range(5)]))
    samples = []
    for _ in range(updates):
        t0 = time.process_time()
        replay.sample(32, rng, 5, 0.99)
        samples.append(time.process_time() - t0)
    update = update_cost(updates, memory=replay, torch_threads=1)["median_s"]
    return {"insert_cpu_s_per_transition": insert, "sample_cpu_s": float(np.median(samples)), "update_cpu_s": update}


def run(ks: tuple[int, ...] = (1, 2, 4), steps: int = 1500, reps: int = 2, learning: bool = False, use_ray: bool = False) -> dict[str, Any]:
    """All figures; each K measured ``reps`` times, interleaved."""
    rows: list[dict[str, Any]] = []
    ray_ctx = None
    if use_ray:
        import ray

        ray.init(num_cpus=max(ks), include_dashboard=False, log_to_driver=False)  # logical CPUs: one per actor
        ray_ctx = ray
    try:
        for rep in range(reps):
            if not use_ray:
                rows.append({"rep": rep, "mode": "single-stream", **single_stream_rate(steps, learning)})
            for k in ks:
                rows.append({"rep": rep, "mode": "ray" if use_ray else "local", **acting_rate(k, steps, learning, use_ray)})
                print(json.dumps(rows[-1]), flush=True)
    finally:
        if ray_ctx is not None:
            ray_ctx.shutdown()
    summary = {}
    for mode in sorted({r["mode"] for r in rows}):
        for k in sorted({r["k"] for r in rows if r["mode"] == mode}):
            same = [r for r in rows if r["mode"] == mode and r["k"] == k]
            if mode == "single-stream" or all("window_steps_per_s" in r for r in same):
                v = [r.get("window_steps_per_s", r["env_steps_per_s"]) for r in same]
                summary[f"{mode}/K={k}"] = {"median": float(np.median(v)), "all": v}
            else:  # too short a run: from the first batch on, steps taken before it would count
                summary[f"{mode}/K={k}"] = {"median": None, "window": next(r["window"] for r in same if "window" in r)}
    return {"rows": rows, "summary": summary, "learner": learner_costs(), "learning": learning, "cpus": os.cpu_count()}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ks", default="1,2,4")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--ray", action="store_true")
    ap.add_argument("--learning", action="store_true")
    a = ap.parse_args()
    print(json.dumps(run(tuple(int(k) for k in a.ks.split(",")), a.steps, a.reps, a.learning, a.ray), indent=2))
