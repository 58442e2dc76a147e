"""What the camera needs to know about the world at one instant.

The world (``sim_server.world``) fills a :class:`SceneState` after every control
step; the renderer (``sim_server.render``) turns it into pixels. Keeping this a
plain frozen snapshot means the renderer never touches pymunk and the same state
always renders the same bytes.

Coordinates: ``dx`` is measured along the road from the host's front bumper to the
other car's rear bumper [m], positive ahead. Lanes are counted from the host's lane:
0 is the host's (middle) lane, -1 the lane to its left (faster traffic), +1 the lane
to its right (slower traffic). The oncoming carriageway is lanes -4..-2 (beyond the
median), where ``dx`` is still along the host's direction of travel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

LANE_WIDTH = 3.7  # [m] US freeway lane
CAR_LENGTH = 4.6  # [m]
CAR_WIDTH = 1.8  # [m]
CAR_HEIGHT = 1.45  # [m]


@dataclass(frozen=True)
class CarView:
    """One other car as the camera sees it."""

    dx: float  # [m] host front bumper -> this car's rear bumper, along the road
    lane: int  # 0 host lane, -1 left, +1 right, -4..-2 oncoming
    braking: bool = False  # brake lights on
    color: tuple[int, int, int] = (170, 30, 30)  # RGB body colour
    length: float = CAR_LENGTH  # [m]
    width: float = CAR_WIDTH  # [m]
    height: float = CAR_HEIGHT  # [m]
    lateral: float = 0.0  # [m] offset from the lane centre, positive to the right


@dataclass(frozen=True)
class SceneState:
    """A snapshot of everything visible from the host's camera."""

    host_s: float  # [m] host odometer: moves lane dashes and roadside objects past
    cars: tuple[CarView, ...] = ()  # lead car first (lane 0), then traffic
    light_azimuth: float = 0.6  # [rad] sun direction, 0 = straight ahead, + to the right
    light_elevation: float = 0.8  # [rad] sun height above the horizon
    scenery_seed: int = 0  # places trees and buildings; fixed for an episode
    extras: dict[str, float] = field(default_factory=dict)  # reserved, not rendered

    @property
    def lead(self) -> CarView | None:
        """The car ahead in the host's lane, if any."""
        for car in self.cars:
            if car.lane == 0 and car.dx >= 0:
                return car
        return None
