"""Drive one episode with any controller over a session, writing the run log."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_client.runlog import RunLog
from agent_client.session import Session
from protocol.constants import DESIRED_GAP

__all__ = ["DriveSummary", "drive_episode", "DESIRED_GAP", "StopEpisode", "COLD_START_HELP"]

COLD_START_HELP = (
    "Engage a DDQN policy at the first frame, its stack that one frame repeated, instead of after "
    "the seconds of camera pre-roll its stack spans (the host coasting meanwhile; frame 0 is the same either way)."
)



class StopEpisode(Exception):
    """Raised by a controller to end the episode early and cleanly (a human closed the window)."""


@dataclass(frozen=True)
class DriveSummary:
    """What one driven episode came to."""

    steps: int
    sim_time: float  # [s]
    wall_time: float  # [s]
    collision: bool
    reason: str
    gap_rmse: float  # [m] against DESIRED_GAP
    gap_min: float  # [m]
    resends: int

    @property
    def steps_per_second(self) -> float:
        return self.steps / self.wall_time if self.wall_time > 0 else math.inf

    def lines(self) -> list[str]:
        return [
            f"steps            {self.steps}",
            f"simulated time   {self.sim_time:.1f} s",
            f"end              {self.reason or 'stopped'}",
            f"collision        {'yes' if self.collision else 'no'}",
            f"gap RMSE (55 m)  {self.gap_rmse:.3f} m",
            f"minimum gap      {self.gap_min:.2f} m",
            f"wall time        {self.wall_time:.2f} s ({self.steps_per_second:.0f} steps/s)",
            f"re-sent requests {self.resends}",
        ]


def drive_episode(
    session: Session,
    controller: Callable[[dict[str, Any]], float],
    *,
    scenario: str,
    seed: int,
    trajectory: str,
    trace: tuple[np.ndarray, np.ndarray] | None = None,
    duration: float | None = None,
    log: str | Path | None = None,
    on_step: Callable[[dict[str, Any]], None] | None = None,
    host_speed: float | None = None,
    gap: float | None = None,
    set_speed: float | None = None,
    preroll: int | None = None,
) -> DriveSummary:
    """Reset, then step ``controller`` until the episode ends.

    A controller that reads a history (a ``history_steps`` attribute: the DDQN's frame
    stack) gets that many frames of pre-roll before it engages, as a camera that was on
    before the driver engaged the ACC (at most :data:`protocol.scenarios.MAX_PREROLL`); it
    sees them through its ``warm(obs)`` and the host coasts at its initial speed meanwhile.
    ``preroll`` overrides that (0: a cold start, where the first frame stands for the
    whole stack). Frame 0 is the same state either way; the log and the summary start there.

    The log is written row by row, so an interrupted run keeps what it drove. A
    controller may raise :class:`StopEpisode` to end the episode early; the summary's
    ``reason`` is then "". ``host_speed`` [m/s], ``gap`` [m] and ``set_speed`` [m/s]
    go to the reset (None: the server's draw or default).

    Raises:
        SessionError, FatalSessionError: from the session.
    """
    start = time.perf_counter()
    resends0 = session.resends
    gaps: list[float] = []
    collision = False
    if preroll is None:
        preroll = getattr(controller, "history_steps", 0)
    with RunLog(log, getattr(controller, "log_columns", ())) as runlog:
        obs = session.reset(
            scenario=scenario, seed=seed, trajectory=trajectory, trace=trace, duration=duration,
            host_speed=host_speed, gap=gap, set_speed=set_speed, preroll=preroll,
        )  # fmt: skip
        if hasattr(controller, "reset"):
            controller.reset()
        while obs["frame"] < 0:  # the pre-roll: the server ignores the action
            if hasattr(controller, "warm"):
                controller.warm(obs)
            obs = session.step(0.0)
        while True:
            done = obs["terminated"] or obs["truncated"]
            if done:  # no decision: the row without the controller's columns
                runlog.write(obs)
            gaps.append(obs["gap"])
            collision = collision or obs["collision"]
            if on_step is not None:
                on_step(obs)
            if done:
                break
            values: tuple[float, ...] = ()  # the controller's own columns for this row, once it decided
            try:
                action = controller(obs)
                values = getattr(controller, "log_values", ())
            except StopEpisode:
                break  # the log keeps the rows so far; the summary's end reads "stopped"
            finally:
                runlog.write(obs, values)
            obs = session.step(action)
    g = np.array(gaps)
    return DriveSummary(
        steps=len(gaps) - 1,
        sim_time=obs["t"],
        wall_time=time.perf_counter() - start,
        collision=collision,
        reason=obs["reason"],
        gap_rmse=float(np.sqrt(np.mean((g - DESIRED_GAP) ** 2))),
        gap_min=float(g.min()),
        resends=session.resends - resends0,
    )
