"""Learner figures on a CUDA device beside the same work on the CPU, for the lent GPU machine.

* one Double-DQN gradient step (:meth:`Learner.update`, 5-step returns) at batch 32 (the
  configured batch), 256 and 1024, wall time with the device synchronised, against one
  and all CPU threads;
* sampling that batch from the frame-deduplicated replay (numpy, on the CPU either way),
  which bounds a GPU learner's update rate (docs/benchmarks.md, the 100-node sketch);
* the network's batch-1 forward (the decision's network part) on the device and on one
  CPU thread.

The machine is a lent one, so these are absolute times of that machine; `vacc bench` keeps
the ratio figures on the CPU.

    python -m agent_client.bench.gpu [--repeats 50] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from agent_client.bench.ddqn import _filled_memory
from agent_client.rl.config import Config
from agent_client.rl.network import QNetwork

__all__ = ["forward_latency", "run", "update_wall"]

BATCHES = (32, 256, 1024)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _median_wall(fn: Callable[[], Any], device: torch.device, repeats: int, warmup: int = 5) -> dict[str, float]:
    """Median and p90 [s] of ``fn``'s wall time, the device synchronised around each call."""
    times = []
    for i in range(repeats + warmup):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    return {"median_s": float(np.median(times)), "p90_s": float(np.percentile(times, 90))}


def update_wall(device: str, threads: int, batches: tuple[int, ...] = BATCHES, repeats: int = 50) -> list[dict[str, Any]]:
    """Per batch size: wall time of sampling a batch (CPU) and of one gradient step on it."""
    from agent_client.rl.learner import Learner

    rng = np.random.default_rng(0)
    memory = _filled_memory(5_000, rng)
    dev = torch.device(device)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        learner = Learner(Config(cuda=dev.type == "cuda", n_step=5, torch_threads=threads), tmp)
        try:
            for batch in batches:
                b = memory.sample(batch, rng, 5, 0.99)

                def draw(n: int = batch) -> Any:
                    return memory.sample(n, rng, 5, 0.99)

                def step_on(b: Any = b) -> Any:
                    return learner.update(b)

                sample = _median_wall(draw, torch.device("cpu"), max(10, repeats // 2), warmup=2)
                step = _median_wall(step_on, dev, repeats)
                rows.append({"device": device, "threads": threads, "batch": batch, "sample_s": sample["median_s"],
                             "update_s": step["median_s"], "update_p90_s": step["p90_s"],
                             "samples_per_s": batch / (step["median_s"] + sample["median_s"])})  # fmt: skip
                print(json.dumps(rows[-1]), flush=True)
        finally:
            learner.close()
    return rows


def forward_latency(device: str, threads: int, repeats: int = 300) -> dict[str, Any]:
    """Batch-1 forward of the paper's network (8 frames, 21 actions) without autograd."""
    torch.set_num_threads(threads)
    dev = torch.device(device)
    net = QNetwork(8, 21).to(dev).eval()
    rng = np.random.default_rng(0)
    frames = torch.from_numpy(rng.integers(0, 256, (1, 8, 105, 150), dtype=np.uint8)).to(dev)
    speeds = torch.full((1, 8), 25.0, device=dev)
    with torch.inference_mode():
        t = _median_wall(lambda: net(frames, speeds), dev, repeats, warmup=20)
    return {"device": device, "threads": threads, **t}


def run(repeats: int = 50) -> dict[str, Any]:
    """Every figure, on the CUDA device when there is one and on the CPU beside it."""
    cpus = os.cpu_count() or 1
    devices = [("cpu", 1), ("cpu", cpus)] + ([("cuda", 1)] if torch.cuda.is_available() else [])
    out: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M"), "cpu": platform.processor() or platform.machine(), "cpus": cpus,
        "torch": torch.__version__, "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "update": [], "forward": [],
    }  # fmt: skip
    for device, threads in devices:
        out["update"] += update_wall(device, threads, repeats=repeats)
        out["forward"].append(forward_latency(device, threads))
        torch.set_num_threads(cpus)
        print(json.dumps(out["forward"][-1]), flush=True)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=50, help="timed gradient steps per batch size")
    ap.add_argument("--json", default=None, help="also write the figures here")
    a = ap.parse_args()
    result = run(a.repeats)
    text = json.dumps(result, indent=2)
    print(text)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text + "\n")
