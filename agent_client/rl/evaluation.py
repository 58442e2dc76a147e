"""Greedy evaluation episodes over UDP, and the score that picks ``best.pt``."""

from __future__ import annotations

import queue
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np

from protocol.constants import DESIRED_GAP, MIN_GAP
from protocol.scenarios import LEAD_SCENARIOS, RANDOM, TEST_TRAJECTORIES

__all__ = ["eval_episode", "evaluate", "score", "EVAL_NAMES_HELP"]

EVAL_NAMES_HELP = f"{', '.join(TEST_TRAJECTORIES)}, random:SEED, or a lead scenario[:SEED] ({', '.join(LEAD_SCENARIOS)})"


class _Log(Protocol):
    def add(self, name: str, value: float, step: int) -> None: ...


def eval_episode(name: str) -> tuple[str, int]:
    """An evaluation trajectory's name to (server trajectory, episode seed).

    "test-N" is a test trajectory from seed 0's start, as ``vacc drive`` drives it.
    "random:S" is the random trajectory (and start, traffic, light) of episode seed S,
    the one ``vacc drive --trajectory random --seed S`` drives: a selection set held out
    from the test set. Training episodes draw their seeds from the run's RNG over
    [0, 2^31), so a small S is, in practice, never a training episode. A lead scenario
    "NAME" or "NAME:S" (``docs/scenarios.md``) is that scenario with seed S (default 0).

    Raises:
        ValueError: any other name.
    """
    if name in TEST_TRAJECTORIES:
        return name, 0
    kind, sep, seed = name.partition(":")
    if kind == RANDOM and seed.isdigit():
        return RANDOM, int(seed)
    if kind in LEAD_SCENARIOS and (not sep or seed.isdigit()):
        return kind, int(seed) if sep else 0
    raise ValueError(f"evaluation trajectory {name!r} is not one of {EVAL_NAMES_HELP} (e.g. random:101)")


def evaluate(policy: Any, envs: Any, trajectories: tuple[str, ...]) -> list[dict[str, Any]]:
    """Greedy episodes; gap RMSE against 55 m and collisions.

    With several envs (each with its own server), the episodes run on as many threads:
    the servers render in parallel, and each episode is a function of its trajectory
    alone, so the results are the same as one after the other.

    Args:
        policy: the network and its decision rule (:class:`~agent_client.rl.network.Policy`).
        envs: a :class:`VisionACCEnv` of the scenario, or a list of them.
        trajectories: names for :func:`eval_episode`, e.g. ("test-1", ..., "test-4")
            or ("random:101", "random:102").

    Returns:
        One dict per trajectory, in their order: trajectory (its name), gap_rmse_m,
        collision, steps, reason.
    """
    pool = list(envs) if isinstance(envs, (list, tuple)) else [envs]
    if len(pool) == 1:
        return [_episode(policy, pool[0], t) for t in trajectories]
    free: queue.Queue[Any] = queue.Queue()
    for env in pool:
        free.put(env)

    def run(trajectory: str) -> dict[str, Any]:
        env = free.get()
        try:
            return _episode(policy, env, trajectory)
        finally:
            free.put(env)

    with ThreadPoolExecutor(len(pool), thread_name_prefix="vacc-eval") as ex:
        return list(ex.map(run, trajectories))


def _episode(policy: Any, env: Any, trajectory: str) -> dict[str, Any]:
    """One greedy episode of ``trajectory`` in ``env``."""
    policy = policy.fresh()  # its own decision state: episodes may run on several threads
    server_trajectory, seed = eval_episode(trajectory)
    obs, info = env.reset(options={"seed": seed, "trajectory": server_trajectory})
    gaps, collision, steps = [info["gap"]], bool(info["collision"]), 0
    done = False
    while not done:
        obs, _, terminated, truncated, info = policy(obs).step(env)
        gaps.append(info["gap"])
        collision = collision or bool(info["collision"])
        steps += 1
        done = terminated or truncated
    g = np.asarray(gaps)
    return {
        "trajectory": trajectory,
        "gap_rmse_m": float(np.sqrt(np.mean((g - DESIRED_GAP) ** 2))),
        "collision": collision,
        "min_gap_m": float(g.min()),
        "steps": steps,
        "reason": info["reason"],
    }


def score(log: _Log, results: list[dict[str, Any]], step: int) -> float:
    """Write an evaluation's ``eval/`` scalars; return its score (lower is better).

    Score: fewest failures (a collision, a gap under the safety suite's 2 m, or losing
    the lead past 300 m), then the worst trajectory's RMSE (the target is per
    trajectory). The 55 m RMSE counts only on the paper's trajectories (test-N,
    random:S) when there are any: behind a stopped car 55 m is no target, only safety.
    """
    following = [r for r in results if eval_episode(r["trajectory"])[0] not in LEAD_SCENARIOS] or results
    rmse = [r["gap_rmse_m"] for r in following]
    for r in results:
        log.add(f"eval/gap_rmse_m/{r['trajectory']}", r["gap_rmse_m"], step)
    log.add("eval/gap_rmse_m", max(rmse), step)
    log.add("eval/gap_rmse_mean_m", float(np.mean(rmse)), step)
    log.add("eval/collisions", sum(r["collision"] for r in results), step)
    failures = sum(r["collision"] or r.get("min_gap_m", MIN_GAP) < MIN_GAP or r["reason"] not in ("end", "") for r in results)
    log.add("eval/failures", failures, step)
    return 1e6 * failures + max(rmse)
