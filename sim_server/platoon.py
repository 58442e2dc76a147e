"""A platoon world: a lead and up to :data:`MAX_FOLLOWERS` followers in one lane.

Each follower is the host of a :class:`~sim_server.world.World` of its own, so each has its
own vehicle model (``ice`` or ``ev``), its own front camera (:meth:`World.scene`) and its
own adjacent traffic. Follower 0's lead drives the episode's trajectory, as in a
single-car world; follower i's lead *is* follower i - 1: at every physics step it drives
at the speed that car drove at the same step, so each gap is the bumper-to-bumper distance
to the car directly ahead. The platoon steps in lockstep, one force per follower per
frame, nearest the lead first, and is deterministic: the same seed and forces give the
same states.

The scenery of each follower's camera (its traffic and sun) is drawn from its own seed;
only the cars of the platoon are shared between the followers' views.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from protocol.constants import MAX_FOLLOWERS
from protocol.scenarios import TRACE
from sim_server.errors import InitialConditionError
from sim_server.world import SEED_MASK, World, WorldConfig, WorldState

__all__ = ["MAX_FOLLOWERS", "PlatoonWorld", "follower_seed"]


def follower_seed(seed: int, follower: int) -> int:
    """Follower ``follower``'s episode seed (its scenery): the episode seed for follower 0,
    which so drives exactly as the host of a single-car world, a derived one behind it."""
    if follower == 0:
        return seed
    return int(np.random.SeedSequence([seed & SEED_MASK, follower]).generate_state(2, np.uint64)[0]) & SEED_MASK


class PlatoonWorld:
    """One episode of a platoon (module docstring).

    Args:
        followers: how many followers, 1..:data:`MAX_FOLLOWERS`.
        config: timing and traffic settings, the same for every follower's world.
        salt: the server's ``--seed``, mixed into every episode seed.
    """

    def __init__(self, followers: int, config: WorldConfig | None = None, salt: int = 0):
        if not 1 <= followers <= MAX_FOLLOWERS:
            raise InitialConditionError(f"a platoon has 1..{MAX_FOLLOWERS} followers, not {followers}")
        self.worlds = [World(config, salt) for _ in range(followers)]
        self.states: list[WorldState] = []

    @property
    def followers(self) -> int:
        return len(self.worlds)

    def reset(
        self,
        scenarios: Sequence[str],
        seed: int,
        trajectory: str,
        *,
        trace: tuple[np.ndarray, np.ndarray] | None = None,
        duration: float | None = None,
        gaps: Sequence[float | None] | None = None,
        host_speed: float | None = None,
        set_speed: float | None = None,
        preroll: int = 0,
    ) -> list[WorldState]:
        """Start an episode; returns each follower's first state, nearest the lead first.

        Args:
            scenarios: each follower's vehicle model, "ice" or "ev"; follower 0's also picks
                the lead's trajectory, as in a single-car world.
            seed, trajectory, trace, duration, set_speed, preroll: as :meth:`World.reset`.
            gaps: each follower's initial gap [m] to the car ahead, or None for its default:
                follower 0's is drawn as in a single-car world, the others' is follower 0's.
            host_speed: every follower's initial speed [m/s]; default drawn for follower 0,
                and the others start at follower 0's.

        Raises:
            ScenarioError, TrajectoryError, InitialConditionError: as :meth:`World.reset`,
                or counts that do not match the followers.
        """
        n = self.followers
        if len(scenarios) != n or (gaps is not None and len(gaps) != n):
            raise InitialConditionError(f"a platoon of {n} followers needs {n} scenarios and {n} gaps (if any)")
        first = self.worlds[0].reset(scenarios[0], seed, trajectory, trace=trace, duration=duration, host_speed=host_speed,
                                     gap=None if gaps is None else gaps[0], set_speed=set_speed, preroll=preroll)  # fmt: skip
        self.states = [first]
        lead0 = self.worlds[0]
        span = (len(lead0.v_lead_profile) - 1) * lead0.config.physics_dt  # [s] the lead's profile
        v0 = first.v_host
        for i, world in enumerate(self.worlds[1:], start=1):
            # the car ahead's own speeds replace this placeholder step by step (World.step)
            still = (np.array([0.0, span]), np.array([v0, v0]))
            gap = gaps[i] if gaps is not None and gaps[i] is not None else first.gap
            self.states.append(world.reset(scenarios[i], follower_seed(seed, i), TRACE, trace=still, duration=duration, host_speed=v0,
                                           gap=gap, set_speed=set_speed, preroll=preroll))  # fmt: skip
        return list(self.states)

    @property
    def over(self) -> bool:
        """Whether the episode has ended: a follower's collision or lost lead, or the end."""
        return any(s.terminated or s.truncated for s in self.states)

    def step(self, forces: Sequence[float]) -> list[WorldState]:
        """Apply one force per follower (nearest the lead first) for one control period.

        Raises:
            ValueError: a force not in [-1, 1], or not one per follower.
            RuntimeError: the episode is over or not started.
        """
        if len(forces) != self.followers:
            raise ValueError(f"a platoon of {self.followers} followers needs {self.followers} forces, got {len(forces)}")
        if not self.states or self.over:
            raise RuntimeError("step on a platoon episode that is over or not started")
        ahead: list[float] | None = None
        states = []
        for world, u in zip(self.worlds, forces, strict=True):
            states.append(world.step(u, lead_speeds=ahead))
            ahead = world.host_speeds  # empty in a pre-roll step
        self.states = states
        return list(states)
