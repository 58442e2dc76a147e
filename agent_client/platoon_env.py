"""A PettingZoo ``ParallelEnv`` over a platoon server: one agent per seat.

    from agent_client.platoon_env import PlatoonParallelEnv
    env = PlatoonParallelEnv(followers=3, scenarios=("ice", "ev", "ice"), trajectory="test-1")
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)
    env.close()

Agent ``seat_i`` drives follower i (``seat_0`` behind the lead). Each agent is a
:class:`~agent_client.env.VisionACCEnv` on its own seat: the same camera observation,
actions, rewards and ``info`` as the single-car env, with its own car ahead as its
lead. The platoon server steps every seat together (:mod:`sim_server.seats`), so an
episode ends for every agent at once: a collision or a lost lead anywhere ends it,
the other agents' episodes truncated. Requires ``pip install 'vacc[pettingzoo]'``.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from agent_client.env import RESET_OPTIONS, VisionACCEnv
from agent_client.launcher import local_server
from protocol.constants import MAX_FOLLOWERS

__all__ = ["PlatoonParallelEnv"]


class PlatoonParallelEnv(ParallelEnv):
    """A platoon of ``followers`` agents (module docstring).

    Args:
        followers: seats, 1..16.
        server: (host, port) of a platoon server with that many seats
            (``vacc serve --followers N``), or None to spawn one, reaped on :meth:`close`.
        scenarios: each seat's vehicle, "ice" or "ev"; default all "ice".
        trajectory: the lead's, as :class:`VisionACCEnv`'s.
        server_args: more arguments of a spawned server (``--seat-timeout 5``, ...).
        env_kwargs: every seat's :class:`VisionACCEnv` keywords (``reward``,
            ``action``, ``episode_seconds``, ``zoom``, ``preroll``, ``key_file``, ...).
    """

    metadata = {"name": "vacc_platoon_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        followers: int = 3,
        server: tuple[str, int] | None = None,
        *,
        scenarios: Sequence[str] | None = None,
        trajectory: str = "random",
        server_args: tuple[str, ...] = (),
        **env_kwargs: Any,
    ):
        if not 1 <= followers <= MAX_FOLLOWERS:
            raise ValueError(f"a platoon has 1..{MAX_FOLLOWERS} followers, got {followers}")
        scenarios = tuple(scenarios) if scenarios is not None else ("ice",) * followers
        if len(scenarios) != followers:
            raise ValueError(f"{followers} followers need {followers} scenarios, got {len(scenarios)}")
        self.possible_agents = [f"seat_{i}" for i in range(followers)]
        self.agents: list[str] = []
        self._stack = contextlib.ExitStack()
        try:
            if server is None:
                key_file = env_kwargs.get("key_file")
                server = self._stack.enter_context(local_server("--followers", str(followers), *server_args, key_file=key_file))
            # each seat's handshake before the next, so seat i is follower i
            self._envs = {
                agent: self._stack.enter_context(_closing(VisionACCEnv(server, scenario=scenarios[i], trajectory=trajectory, seat=i, **env_kwargs)))
                for i, agent in enumerate(self.possible_agents)
            }  # fmt: skip
            self._pool = self._stack.enter_context(ThreadPoolExecutor(max_workers=followers, thread_name_prefix="vacc-seat"))
        except BaseException:
            self._stack.close()
            raise
        self._rng = np.random.default_rng()

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._envs[agent].observation_space  # the same object each time, as PettingZoo asks

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._envs[agent].action_space

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start a platoon episode; ``options`` as :meth:`VisionACCEnv.reset`'s (the lead's
        ``seed`` and ``trajectory``, and every follower's ``host_speed``, ``gap``, ``set_speed``);
        others are ignored with a warning."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        unknown = sorted(set(options) - RESET_OPTIONS)
        if unknown:  # PettingZoo's API test passes an option no env knows: said, not fatal
            warnings.warn(f"reset options {unknown} ignored; known: {sorted(RESET_OPTIONS)}", stacklevel=2)
            options = {k: v for k, v in options.items() if k in RESET_OPTIONS}
        options.setdefault("seed", int(self._rng.integers(2**31)))  # one episode seed for every seat: seat 0's is the lead's
        for i, env in enumerate(self._envs.values()):
            env.action_space.seed(None if seed is None else seed + i)
        done = self._all(self.possible_agents, lambda env, agent: env.reset(options=options))
        self.agents = list(self.possible_agents)
        return {a: d[0] for a, d in done.items()}, {a: d[1] for a, d in done.items()}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], ...]:
        """Every live agent's action at once; the usual five dicts. An agent whose episode
        ended is gone from :attr:`agents` after this step.

        Raises:
            ValueError: actions for other agents than the live ones.
        """
        if set(actions) != set(self.agents):
            raise ValueError(f"actions for {sorted(actions)}, but the live agents are {self.agents}")
        done = self._all(self.agents, lambda env, agent: env.step(actions[agent]))
        out: tuple[dict[str, Any], ...] = tuple({a: d[k] for a, d in done.items()} for k in range(5))
        terminations, truncations = out[2], out[3]
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return out

    def _all(self, agents: list[str], call: Any) -> dict[str, Any]:
        """``call(env, agent)`` for every agent's env at once (a platoon server answers a
        seat only when every seat has asked), in agent order."""
        futures = {a: self._pool.submit(call, self._envs[a], a) for a in agents}
        return {a: f.result() for a, f in futures.items()}

    def close(self) -> None:
        self._stack.close()


@contextlib.contextmanager
def _closing(env: VisionACCEnv) -> Any:
    try:
        yield env
    finally:
        env.close()
