"""The simulated world: host, lead and adjacent-lane traffic as pymunk bodies.

Axes: x along the road in the direction of travel [m], y across it, positive to the
host's right [m]. The host drives in the middle lane (y = 0). Bodies are boxes of a
car's footprint; pymunk detects the host's collisions with any other car.

The host is a dynamic body whose velocity the longitudinal model sets every physics
step; the lead and traffic are kinematic bodies that follow their speed profiles.

The host has a speed limiter at the cruise set speed (default 33.5 m/s): whatever
the controller commands, the host never drives faster. It lives here, in the
vehicle, rather than in each controller, as in a production ACC, where the set
speed caps the commanded acceleration below the controller. So every controller,
a learned one included, is held to it, and the guarantee needs no trust in the
policy. The set speed is in every observation: it is the driver's input.
Collision response is switched off: a collision ends the episode, so only its
detection matters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pymunk

from protocol.constants import (
    PHYSICS_DT,
    SUBSTEPS,
    SUN_ELEVATION,
    TRAFFIC_PER_LANE,
    TRAFFIC_PER_LANE_RANGE,
)
from protocol.scenarios import (
    DEFAULT_SET_SPEED,
    GAP_LIMIT,
    LEAD_SCENARIOS,
    PREROLL_MIN_GAP,
    SCENARIOS,
    TRACE,
    check_initial,
    check_sun_elevation,
)
from sim_server import scenarios as lead_scenarios
from sim_server import trajectory as traj
from sim_server.errors import InitialConditionError, ScenarioError
from sim_server.scene import CAR_LENGTH, CAR_WIDTH, LANE_WIDTH, CarView, SceneState
from sim_server.vehicle import accel_of_force, advance_speed

__all__ = ["WorldConfig", "WorldState", "World", "GAP_LIMIT"]

SALT_MASK = 0xFFFFFFFF  # only the salt's low 32 bits are mixed into an episode seed
SEED_MASK = 0xFFFFFFFFFFFFFFFF  # and the episode seed's low 64 bits
HOST, LEAD, TRAFFIC = 1, 2, 3  # pymunk collision types
BRAKE_LIGHT_ACCEL = -0.3  # [m/s^2] lead brake lights come on below this
TRAFFIC_AHEAD = 250.0  # [m] traffic is kept within this window around the host
TRAFFIC_BEHIND = 100.0  # [m]
TRAFFIC_COLORS = ((40, 70, 150), (200, 200, 205), (30, 30, 35), (120, 125, 130), (150, 120, 60), (60, 110, 70))


@dataclass(frozen=True)
class WorldConfig:
    """Timing and traffic settings of a world."""

    physics_dt: float = PHYSICS_DT  # [s] paper Sec. 4
    substeps: int = SUBSTEPS  # physics steps per control step: 0.1 s control period (10 Hz)
    traffic_per_lane: int = TRAFFIC_PER_LANE  # cars in each adjacent lane; twice as many oncoming
    randomize_light: bool = True  # draw the sun per episode for random trajectories and lead scenarios
    sun_elevation: tuple[float, float] = SUN_ELEVATION  # [rad] the range of that draw's height

    def __post_init__(self) -> None:
        lo, hi = TRAFFIC_PER_LANE_RANGE
        if not lo <= self.traffic_per_lane <= hi:
            raise ValueError(f"traffic_per_lane must be in [{lo}, {hi}], got {self.traffic_per_lane}")
        if (why := check_sun_elevation(self.sun_elevation)) is not None:
            raise ValueError(f"sun_elevation {why}")

    @property
    def control_period(self) -> float:
        """Simulated time per control step [s]."""
        return self.physics_dt * self.substeps


@dataclass(frozen=True)
class WorldState:
    """The world after a control step, in SI units."""

    frame: int
    t: float  # [s]
    v_host: float  # [m/s]
    v_lead: float  # [m/s]
    gap: float  # [m] host front bumper to lead rear bumper
    accel: float  # [m/s^2] host, over the last control period
    a_lead: float  # [m/s^2] lead, over the last control period
    force: float  # u applied over the last control period
    collision: bool
    terminated: bool
    truncated: bool
    reason: str  # "", "collision", "gap" or "end"
    set_speed: float  # [m/s] the cruise set speed the host's limiter holds


def _car(space: pymunk.Space, kind: int, x: float, y: float, body_type: int) -> pymunk.Body:
    if body_type == pymunk.Body.DYNAMIC:
        body = pymunk.Body(1500.0, float("inf"))  # [kg]; no rotation
    else:
        body = pymunk.Body(body_type=body_type)
    body.position = (x, y)
    shape = pymunk.Poly.create_box(body, (CAR_LENGTH, CAR_WIDTH))
    shape.collision_type = kind
    space.add(body, shape)
    return body


class World:
    """One episode's world. Deterministic: same seed and actions, same states.

    Args:
        config: timing and traffic settings.
        salt: mixed into every episode seed (the server's ``--seed``); kept as
            mixed, its low 32 bits (the ``welcome``'s ``seed_salt``).
    """

    def __init__(self, config: WorldConfig | None = None, salt: int = 0):
        self.config = config or WorldConfig()
        self.salt = salt & SALT_MASK
        self.state: WorldState | None = None
        self.host_speeds: list[float] = []  # [m/s] the host's at each physics step of the last step()

    def reset(
        self,
        scenario: str,
        seed: int,
        trajectory: str,
        *,
        trace: tuple[np.ndarray, np.ndarray] | None = None,
        duration: float | None = None,
        host_speed: float | None = None,
        gap: float | None = None,
        set_speed: float | None = None,
        preroll: int = 0,
    ) -> WorldState:
        """Start an episode; returns frame 0, or frame ``-preroll``.

        Args:
            scenario: "ice" or "ev".
            seed: episode seed (mixed with the salt).
            trajectory: a name of :data:`protocol.scenarios.TRAJECTORIES` or "trace".
            trace: (times [s], speeds [m/s]) for "trace".
            duration: truncate the episode after this many seconds.
            host_speed: host's initial speed [m/s]; default drawn (Table 2 or the
                lead scenario), for a trace the lead's first speed. Never above
                the set speed: a drawn speed above it starts at the set speed.
            gap: initial gap [m]; default drawn.
            set_speed: cruise set speed [m/s]; default 33.5.
            preroll: control steps before the start (frames -preroll..-1) in which
                the camera already runs: the host coasts at its initial speed
                whatever the action, the lead drives at its initial speed (a faster
                one no closer than PREROLL_MIN_GAP), traffic at its own. Frame 0 is
                then the state a reset without pre-roll starts in, bit for bit.

        Raises:
            ScenarioError, TrajectoryError: unknown names or a bad trace.
            InitialConditionError: host speed, gap or set speed out of range.
        """
        cfg = self.config
        if scenario not in SCENARIOS:
            raise ScenarioError(f"unknown scenario {scenario!r}; expected one of {list(SCENARIOS)}")
        try:
            check_initial(host_speed=host_speed, gap=gap, set_speed=set_speed, preroll=preroll)
        except ValueError as exc:
            raise InitialConditionError(str(exc)) from None
        v_set = DEFAULT_SET_SPEED if set_speed is None else float(set_speed)
        rng = np.random.default_rng([self.salt, seed & SEED_MASK])
        self.v_lead_profile, v_host, gap0 = self._draw_lead(scenario, trajectory, rng, trace)
        v_host = min(v_host if host_speed is None else float(host_speed), v_set)
        gap0 = gap0 if gap is None else float(gap)
        self.set_speed = v_set
        self.last_frame = self._last_frame(duration)
        self.scenario, self.seed = scenario, seed
        self.light = self._draw_light(trajectory, rng)
        self._place_cars(rng, v_host, gap0)
        self._rng = rng
        self._collided = False
        self.odometer = 0.0  # [m] host distance travelled
        self.step_index = 0  # physics steps since the start (frame 0)
        self.preroll_left = preroll
        if preroll:
            self._start_preroll(preroll)
        self.state = self._state(-preroll, 0.0, 0.0, 0.0, -(preroll * cfg.substeps) * cfg.physics_dt)
        return self.state

    def _draw_lead(
        self, scenario: str, trajectory: str, rng: np.random.Generator, trace: tuple[np.ndarray, np.ndarray] | None,
    ) -> tuple[np.ndarray, float, float]:
        """The lead's speed profile [m/s] per physics step, and the drawn initial host
        speed [m/s] and gap [m], before any reset option overrides them."""
        if trajectory in LEAD_SCENARIOS:
            episode = lead_scenarios.build(trajectory, rng, self.config.physics_dt)
            return episode.v_lead, episode.v_host, episode.gap
        # Draw order kept as it always was: the paper's runs stay bit-identical.
        profile = traj.build(scenario, trajectory, rng, self.config.physics_dt, trace=trace)
        lim = traj.LIMITS[scenario]
        v_host = float(rng.uniform(*lim.v0_host))
        gap0 = float(rng.uniform(*lim.gap0))
        if trajectory == TRACE:
            v_host = float(profile[0])  # a trace starting at 0 starts the host standing
        return profile, v_host, gap0

    def _last_frame(self, duration: float | None) -> int:
        """The frame that truncates the episode: the lead profile's end, or ``duration`` [s] if sooner."""
        cfg = self.config
        steps = len(self.v_lead_profile) - 1
        if duration is not None and duration < steps * cfg.physics_dt:  # longer: the whole trajectory (1e308 too)
            steps = int(round(duration / cfg.physics_dt))
        return steps // cfg.substeps

    def _draw_light(self, trajectory: str, rng: np.random.Generator) -> tuple[float, float]:
        """The sun's (azimuth, elevation) [rad]: drawn for random leads and lead scenarios, else fixed."""
        cfg = self.config
        if cfg.randomize_light and (trajectory == "random" or trajectory in LEAD_SCENARIOS):
            return (float(rng.uniform(-1.2, 1.2)), float(rng.uniform(*cfg.sun_elevation)))
        return (0.6, 0.8)

    def _place_cars(self, rng: np.random.Generator, v_host: float, gap0: float) -> None:
        """A new physics space: the host at x = 0 at ``v_host`` [m/s], the lead ``gap0`` [m]
        ahead at the profile's first speed, and the adjacent lanes' traffic."""
        self.space = space = pymunk.Space()
        space.on_collision(HOST, LEAD, begin=self._on_collision)
        space.on_collision(HOST, TRAFFIC, begin=self._on_collision)
        self.host = _car(space, HOST, 0.0, 0.0, pymunk.Body.DYNAMIC)
        self.host.velocity = (v_host, 0.0)
        self.lead = _car(space, LEAD, gap0 + CAR_LENGTH, 0.0, pymunk.Body.KINEMATIC)
        self.lead.velocity = (float(self.v_lead_profile[0]), 0.0)
        self._spawn_traffic(rng, float(np.mean(self.v_lead_profile)))

    def _start_preroll(self, preroll: int) -> None:
        # Every body moved back along its own speed; frame 0 puts back what is saved here.
        span = preroll * self.config.control_period  # [s]
        v_host, v_lead = self.host.velocity.x, self.lead.velocity.x
        gap0 = self.lead.position.x - self.host.position.x - CAR_LENGTH
        v_lead = min(v_lead, v_host + max(gap0 - PREROLL_MIN_GAP, 0.0) / span)
        self._start_positions = [(b, b.position) for b in (self.host, self.lead, *(t[0] for t in self.traffic))]
        for body, (x, y) in self._start_positions:
            v = v_lead if body is self.lead else body.velocity.x
            body.position = (x - v * span, y)
        self.lead.velocity = (v_lead, 0.0)
        self._reindex()
        self.odometer = -v_host * span

    def _end_preroll(self) -> None:
        for body, position in self._start_positions:
            body.position = position
        self.lead.velocity = (float(self.v_lead_profile[0]), 0.0)
        self._reindex()
        self.odometer = 0.0

    def _reindex(self) -> None:
        for body, _ in self._start_positions:
            self.space.reindex_shapes_for_body(body)

    def _spawn_traffic(self, rng: np.random.Generator, v_mean: float) -> None:
        # Faster traffic on the left, slower on the right (paper Sec. 3); oncoming
        # traffic beyond the median only for the camera, outside the physics.
        self.traffic: list[tuple[pymunk.Body, int, tuple[int, int, int]]] = []
        for lane, dv in ((-1, (2.0, 6.0)), (1, (-6.0, -2.0))):
            for _ in range(self.config.traffic_per_lane):
                x = float(rng.uniform(-TRAFFIC_BEHIND, TRAFFIC_AHEAD))
                body = _car(self.space, TRAFFIC, x, lane * LANE_WIDTH, pymunk.Body.KINEMATIC)
                body.velocity = (max(0.0, v_mean + float(rng.uniform(*dv))), 0.0)
                color = TRAFFIC_COLORS[int(rng.integers(len(TRAFFIC_COLORS)))]
                self.traffic.append((body, lane, color))
        self.oncoming = [
            (float(rng.uniform(-TRAFFIC_BEHIND, TRAFFIC_AHEAD)), -int(rng.integers(2, 5)),
             float(rng.uniform(22.0, 33.0)), TRAFFIC_COLORS[int(rng.integers(len(TRAFFIC_COLORS)))])
            for _ in range(self.config.traffic_per_lane * 2)
        ]  # fmt: skip

    def _on_collision(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object) -> None:
        self._collided = True
        arbiter.process_collision = False

    def _recycle_traffic(self) -> None:
        # Cars that fall out of the window re-enter at its other end, so the host
        # always has neighbours; the respawn is drawn from the episode's generator.
        hx = self.host.position.x
        for body, _lane, _color in self.traffic:
            dx = body.position.x - hx
            if dx < -TRAFFIC_BEHIND or dx > TRAFFIC_AHEAD:
                ahead = dx < -TRAFFIC_BEHIND
                offset = float(self._rng.uniform(0.8, 1.0)) * (TRAFFIC_AHEAD if ahead else -TRAFFIC_BEHIND)
                body.position = (hx + offset, body.position.y)
                self.space.reindex_shapes_for_body(body)

    def step(self, u: float, lead_speeds: Sequence[float] | None = None) -> WorldState:
        """Apply force ``u`` for one control period.

        ``lead_speeds`` (a platoon, :mod:`sim_server.platoon`): the lead's speed [m/s] at each
        physics step of the period, in place of its profile's; fewer than the period's steps
        hold the last one. :attr:`host_speeds` then holds the host's, for the car behind.

        Raises:
            ValueError: if ``u`` is not a finite number in [-1, 1].
            RuntimeError: if the episode is already over or not started.
        """
        state = self.state
        if state is None or state.terminated or state.truncated:
            raise RuntimeError("step on an episode that is over or not started")
        a_cmd = accel_of_force(u)
        self.host_speeds = []  # none in a pre-roll step: the car behind coasts too
        if self.preroll_left:
            return self._preroll_step()
        cfg = self.config
        dt = cfg.physics_dt
        v0_host, v0_lead = state.v_host, state.v_lead
        host, lead = self.host, self.lead
        profile = self.v_lead_profile
        if lead_speeds is not None and len(lead_speeds):
            ahead = [*lead_speeds, *[lead_speeds[-1]] * cfg.substeps][: cfg.substeps]
            profile[self.step_index + 1 : self.step_index + 1 + cfg.substeps] = ahead[: len(profile) - self.step_index - 1]
        steps = 0
        for _ in range(cfg.substeps):
            self.step_index += 1
            steps += 1
            v = advance_speed(host.velocity.x, a_cmd, dt, self.set_speed)
            host.velocity = (v, 0.0)
            self.host_speeds.append(v)
            lead.velocity = (float(profile[self.step_index]), 0.0)
            self.space.step(dt)
            self.odometer += v * dt
            if self._collided:
                break
        self._recycle_traffic()
        elapsed = steps * dt
        v_host, v_lead = host.velocity.x, lead.velocity.x
        self.state = self._state(
            state.frame + 1,
            (v_host - v0_host) / elapsed,
            (v_lead - v0_lead) / elapsed,
            u,
            self.step_index * dt,
        )
        return self.state

    def _preroll_step(self) -> WorldState:
        # Before the start: everything at constant speed, the action ignored, the
        # lead's profile not begun, no traffic respawned (that would draw from the
        # episode's generator); nothing here can end the episode.
        cfg = self.config
        for _ in range(cfg.substeps):
            self.odometer += self.host.velocity.x * cfg.physics_dt
            self.space.step(cfg.physics_dt)
        self.preroll_left -= 1
        if not self.preroll_left:
            self._end_preroll()
        assert self.state is not None
        self.state = self._state(self.state.frame + 1, 0.0, 0.0, 0.0, -(self.preroll_left * cfg.substeps) * cfg.physics_dt)
        return self.state

    def _state(self, frame: int, accel: float, a_lead: float, force: float, t: float) -> WorldState:
        gap = self.lead.position.x - self.host.position.x - CAR_LENGTH
        collision = self._collided or gap <= 0.0
        reason = "collision" if collision else "gap" if gap > GAP_LIMIT and frame >= 0 else ""
        truncated = not reason and frame >= self.last_frame
        return WorldState(
            frame=frame,
            t=t,
            v_host=float(self.host.velocity.x),
            v_lead=float(self.lead.velocity.x),
            gap=float(gap),
            accel=float(accel),
            a_lead=float(a_lead),
            force=float(force),
            collision=collision,
            terminated=bool(reason),
            truncated=truncated,
            reason=reason or ("end" if truncated else ""),
            set_speed=self.set_speed,
        )

    def scene(self) -> SceneState:
        """What the camera sees now."""
        assert self.state is not None
        hx = self.host.position.x + CAR_LENGTH / 2  # host front bumper
        lead = CarView(
            dx=self.state.gap,
            lane=0,
            braking=self.state.a_lead < BRAKE_LIGHT_ACCEL,
            color=(170, 30, 30),
        )
        cars = [lead]
        for body, lane, color in self.traffic:
            cars.append(CarView(dx=body.position.x - CAR_LENGTH / 2 - hx, lane=lane, color=color))
        t = self.state.t
        for x0, lane, v, color in self.oncoming:
            x = x0 - v * t
            # Oncoming cars wrap around the host's window as it drives on.
            dx = (x - hx + TRAFFIC_BEHIND) % (TRAFFIC_AHEAD + TRAFFIC_BEHIND) - TRAFFIC_BEHIND
            cars.append(CarView(dx=dx, lane=lane, color=color))
        return SceneState(
            host_s=self.odometer,
            cars=tuple(cars),
            light_azimuth=self.light[0],
            light_elevation=self.light[1],
            scenery_seed=int(self.seed) & 0x7FFFFFFF,
        )
