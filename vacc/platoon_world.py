"""Camera platoons in-process: any controller in any seat of a
:class:`~sim_server.platoon.PlatoonWorld`, learned (camera) followers included.

Each follower's controller gets the observation a session would give it (its own speed,
the gap to the car directly ahead, that car's speed, and, for a policy, its own camera
frame at the size and format it asks for, :func:`agent_client.controllers.camera`). A
policy's frame stack is filled in a pre-roll before frame 0, as ``vacc drive`` does. The
run comes back as the kinematic platoon's :class:`~vacc.platoon_sim.PlatoonRun`, so the
string-stability figures read both the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from agent_client.controllers import camera
from sim_server.platoon import PlatoonWorld
from sim_server.scene import CAR_LENGTH
from sim_server.world import WorldConfig, WorldState
from vacc.platoon_sim import PlatoonRun

__all__ = ["drive_platoon"]


class _Camera:
    """One follower's camera at the size and in the format its controller asks for."""

    def __init__(self, controller: Any):
        self.format, self.size = camera(controller)
        self.renderer: Any = None

    def frame(self, world: Any) -> tuple[bytes | None, tuple[int, int, int] | None]:
        if self.format == "none":
            return None, None
        from sim_server.render import CameraConfig, Renderer, in_format

        if self.renderer is None:
            self.renderer = Renderer(CameraConfig(width=self.size[0], height=self.size[1]))
        image = in_format(self.renderer.render(world.scene()), self.format)
        return image.tobytes(), (image.shape[0], image.shape[1], image.shape[2] if image.ndim == 3 else 1)


def _observation(st: WorldState, image: bytes | None, shape: tuple[int, int, int] | None) -> dict[str, Any]:
    return {"frame": st.frame, "t": st.t, "v_host": st.v_host, "v_lead": st.v_lead, "gap": st.gap, "accel": st.accel, "a_lead": st.a_lead,
            "force": st.force, "set_speed": st.set_speed, "image": image, "image_shape": shape}  # fmt: skip


def drive_platoon(
    controllers: Sequence[Any],
    scenarios: Sequence[str],
    lead: tuple[np.ndarray, np.ndarray],
    gaps: Sequence[float],
    *,
    host_speed: float,
    seed: int = 0,
    config: WorldConfig | None = None,
) -> PlatoonRun:
    """Drive ``controllers`` (nearest the lead first) behind a lead on the trace ``lead``
    (times [s], speeds [m/s]) from the gaps ``gaps`` [m] and a common speed ``host_speed``.

    Returns:
        The run from frame 0 to the trace's end or the first collision or lost lead.
    """
    for c in controllers:
        if hasattr(c, "reset"):
            c.reset()
    preroll = max((getattr(c, "history_steps", 0) for c in controllers), default=0)
    world = PlatoonWorld(len(controllers), config)
    states = world.reset(list(scenarios), seed, "trace", trace=lead, gaps=list(gaps), host_speed=host_speed, preroll=preroll)
    cams = [_Camera(c) for c in controllers]
    frames: list[list[WorldState]] = []
    while True:
        if states[0].frame >= 0:
            frames.append(states)
        if world.over:
            break
        forces = []
        for c, cam, w, st in zip(controllers, cams, world.worlds, states, strict=True):
            obs = _observation(st, *cam.frame(w))
            if st.frame < 0:  # the pre-roll: a policy fills its stack, the car coasts
                if hasattr(c, "warm"):
                    c.warm(obs)
                forces.append(0.0)
            else:
                forces.append(float(c(obs)))
        states = world.step(forces)
    return _run(frames)


def _run(frames: list[list[WorldState]]) -> PlatoonRun:
    """The frames as a :class:`PlatoonRun` (positions from the gaps, the lead at 0 at the start)."""
    n = len(frames[0])
    gaps = np.array([[f[i].gap for f in frames] for i in range(n)])
    v = np.array([[f[0].v_lead for f in frames], *([f[i].v_host for f in frames] for i in range(n))])
    t = np.array([f[0].t for f in frames])
    lead_x = np.concatenate([[0.0], np.cumsum(0.5 * (v[0, 1:] + v[0, :-1]) * np.diff(t))])  # the lead's only for plots
    x = np.vstack([lead_x, lead_x - np.cumsum(gaps + CAR_LENGTH, axis=0)])
    force = np.array([[f[i].force for f in frames] for i in range(n)])
    hit = [i + 1 for i in range(n) if frames[-1][i].collision]
    return PlatoonRun(t, v, x, gaps, force, hit[0] if hit else None)
