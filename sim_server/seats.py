"""A platoon's lockstep across seats: one :class:`~sim_server.platoon.PlatoonWorld`, one
client session per follower (a *seat*), and the two barriers that keep them in step.

- **Reset.** A seat's reset waits until every seat has asked for its next episode. The
  platoon's lead (trajectory or trace, seed, duration, set speed, initial speed) is seat
  0's; each seat's own reset gives its vehicle model and initial gap. The pre-roll is the
  longest any seat asked for; a seat that asked for a shorter one is answered when the
  platoon reaches its first frame (``-preroll``), so every seat's reset is answered
  with the frame it asked for. Before that frame it coasts, as every car does in a
  pre-roll. A reset while an episode runs abandons it: the other seats' steps are
  answered ``EPISODE_OVER``, and the platoon waits for every seat's reset.
- **Step.** Frame k advances when every seat that has reached its first frame sent
  its action for frame k. Repeats are answered from each seat's reply cache, so loss,
  duplication and reordering change nothing.
- **Nudges.** While a frame waits, each seat that has not acted gets its last observation
  again (:data:`NUDGE_FIRST`, doubling to :data:`NUDGE_MAX`): a reply lost on the way
  to one seat would otherwise hold every seat until that client's re-send timer fires.
- **Give-up.** A barrier waits at most ``join_timeout`` seconds for resets (from the first
  join or reset) and ``seat_timeout`` seconds for a frame's actions (from its first action).
  Then the platoon gives up: every seat's session ends, and each is told (``SEAT_LOST``)
  which seat it waited for and that seat's client address.

This module decides; the server (:mod:`sim_server.server`) receives and sends.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from sim_server.platoon import PlatoonWorld
from sim_server.world import WorldConfig, WorldState

__all__ = ["SeatReset", "PlatoonLockstep", "SEAT_TIMEOUT", "JOIN_TIMEOUT", "where"]

SEAT_TIMEOUT = 3.0  # [s] default wait for a seat's action, once another seat's has come
JOIN_TIMEOUT = 60.0  # [s] default wait for every seat's reset (clients that load a network take seconds)
# While a frame waits for a seat's action, the seat's last observation is sent again after
# NUDGE_FIRST, then at doubling intervals up to NUDGE_MAX: a lost reply costs the whole
# platoon a frame's wait, so the server does not leave its recovery to the client's timer alone.
NUDGE_FIRST = 0.02  # [s]
NUDGE_MAX = 0.5  # [s]


@dataclass(frozen=True)
class SeatReset:
    """One seat's parsed reset: ``episode`` is that seat's own counter."""

    episode: int
    scenario: str
    gap: float | None
    preroll: int
    lead: dict[str, Any]  # seed, trajectory, trace, duration, host_speed, set_speed: used from seat 0 only


class PlatoonLockstep:
    """The platoon's world and barriers. Seats are the server's sessions, indexed by seat.

    Each seat object carries ``asked`` (a :class:`SeatReset` or None), ``action`` (its
    action for the current frame or None), ``start`` (its first frame), ``addr`` and
    ``last_seen``; this class reads and sets those.
    """

    def __init__(self, followers: int, config: WorldConfig, salt: int, seat_timeout: float = SEAT_TIMEOUT,
                 join_timeout: float = JOIN_TIMEOUT):  # fmt: skip
        self.world = PlatoonWorld(followers, config, salt)
        self.seat_timeout = seat_timeout
        self.join_timeout = join_timeout
        self.frame: int | None = None  # the platoon's current frame; None: no episode running
        self.states: list[WorldState] = []
        self.waiting_since: float | None = None  # [s] monotonic: when the open barrier began
        self.nudge_at: float | None = None  # [s] monotonic: when the seats still awaited are sent their observation again
        self._nudge_every = NUDGE_FIRST
        self.abandoned = "no platoon episode is running"  # why a step finds none

    @property
    def running(self) -> bool:
        """An episode has started and is not over."""
        return self.frame is not None and not self.world.over

    def clear(self) -> None:
        """Forget the episode and every barrier (the platoon gave up, or every seat left)."""
        self.frame, self.states, self.waiting_since, self.nudge_at = None, [], None, None

    def joined(self, now: float) -> None:
        """A seat was taken: with no episode running, the reset barrier's clock starts."""
        if self.frame is None and self.waiting_since is None:
            self.waiting_since = now

    # -- the reset barrier ----------------------------------------------------

    def ask_reset(self, seat: Any, asked: SeatReset, now: float) -> None:
        """Seat ``seat`` asks for its next episode (the server gives up first if one is running)."""
        seat.asked = asked
        if self.waiting_since is None:
            self.waiting_since = now

    def reset_ready(self, seats: list[Any]) -> bool:
        return all(s is not None and s.asked is not None for s in seats)

    def reset(self, seats: list[Any]) -> list[WorldState]:
        """Start the platoon's episode from every seat's reset; raises as :meth:`PlatoonWorld.reset`."""
        head = seats[0].asked
        preroll = max(s.asked.preroll for s in seats)
        lead = head.lead
        try:
            self.states = self.world.reset(
                [s.asked.scenario for s in seats], lead["seed"], lead["trajectory"], trace=lead["trace"], duration=lead["duration"],
                gaps=[s.asked.gap for s in seats],
                host_speed=lead["host_speed"], set_speed=lead["set_speed"], preroll=preroll,
            )  # fmt: skip
        finally:
            for s in seats:
                s.start = -s.asked.preroll
        self.frame = -preroll
        self._opened(None)
        for s in seats:
            s.action = None
        return list(self.states)

    def _opened(self, now: float | None) -> None:
        """A barrier opened at ``now`` (None: none is open)."""
        self.waiting_since = now
        self.nudge_at = None if now is None else now + NUDGE_FIRST
        self._nudge_every = NUDGE_FIRST

    def nudges(self, seats: list[Any], now: float) -> list[Any]:
        """The seats whose observation is due again now (they have not acted on this frame)."""
        if self.nudge_at is None or now < self.nudge_at or not self.running:
            return []
        self._nudge_every = min(2 * self._nudge_every, NUDGE_MAX)
        self.nudge_at = now + self._nudge_every
        return [s for s in seats if s is not None and s.start <= self.frame and s.action is None]

    # -- the step barrier -----------------------------------------------------

    def ask_step(self, seat: Any, action: float, now: float) -> None:
        if seat.action is None and self.waiting_since is None:
            self._opened(now)
        seat.action = action

    def step_ready(self, seats: list[Any]) -> bool:
        return self.frame is not None and all(s is not None and (s.start > self.frame or s.action is not None) for s in seats)

    def step(self, seats: list[Any]) -> list[WorldState]:
        """Advance one frame with every seat's action (0 for a seat still before its first frame)."""
        forces = [0.0 if s.action is None else float(s.action) for s in seats]
        self.states = self.world.step(forces)
        assert self.frame is not None
        self.frame += 1
        self._opened(None)
        for s in seats:
            s.action = None
        return list(self.states)

    # -- giving up ------------------------------------------------------------

    def overdue(self, seats: list[Any], now: float) -> str | None:
        """Why the open barrier gives up now, naming the first seat it waits for; None if it may wait."""
        if self.waiting_since is None:
            return None
        if self.frame is None or self.world.over:
            if now - self.waiting_since <= self.join_timeout:
                return None
            for i, s in enumerate(seats):
                if s is None:
                    return f"no client took seat {i} within {self.join_timeout:g} s"
                if s.asked is None:
                    return f"seat {i} (client {where(s.addr)}) sent no reset within {self.join_timeout:g} s"
            return None
        if now - self.waiting_since <= self.seat_timeout:
            return None
        for i, s in enumerate(seats):
            if s is None:
                return f"seat {i} has no client"
            if s.start <= self.frame and s.action is None:
                return f"seat {i} (client {where(s.addr)}) sent no action for frame {self.frame} within {self.seat_timeout:g} s"
        return None

    def seat_obs(self, i: int) -> WorldState:
        """Seat ``i``'s state; once the platoon is over, a seat whose own episode is not over
        is truncated with reason "platoon" (another car ended it)."""
        st = self.states[i]
        if self.world.over and not (st.terminated or st.truncated):
            st = replace(st, truncated=True, reason="platoon")
        return st


def where(addr: Any) -> str:
    """A client's address as ``host:port``, for the messages that name a seat."""
    return f"{addr[0]}:{addr[1]}"
