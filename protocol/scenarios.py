"""The one registry of scenario and trajectory names, shared by the server and its clients.

A reset names two things: the **scenario**, the host vehicle and its paper setting
(``"ice"`` or ``"ev"``), and the **trajectory**, what the lead car does:

* ``test-1``..``test-4``: the paper's fixed 4-minute test trajectories;
* ``random``: a new paper-style trajectory drawn from the episode seed (training);
* a **lead scenario** (:data:`LEAD_SCENARIOS`): a named, seeded, parameterised case
  beyond the paper's test set (a stopped car, a braking lead, stop-and-go, ...).
  The seed draws every parameter uniformly within the ranges given here, so the
  same seed gives the same episode. Lead scenarios leave Table 2's lead bands: they
  drive the same way for both vehicles;
* ``trace``: a lead speed trace sent with the reset (a user's CSV).

This module holds names, descriptions and parameter ranges only; the server builds
the speed profiles from them (``sim_server/scenarios.py``). It imports neither
side. ``docs/scenarios.md`` describes each case and the standard test it resembles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from protocol.codec import MAX_ARRAY_LEN
from protocol.constants import A_MIN, SUN_ELEVATION_LIMITS

__all__ = [
    "check_sun_elevation",
    "parse_sun_elevation",
    "SCENARIOS",
    "TEST_TRAJECTORIES",
    "TEST_DURATION",
    "RANDOM_DURATION",
    "RANDOM",
    "TRACE",
    "Param",
    "LeadScenario",
    "LEAD_SCENARIOS",
    "TRAJECTORIES",
    "DEFAULT_SET_SPEED",
    "SET_SPEED_RANGE",
    "GAP_LIMIT",
    "TRACE_SPEED_MAX",
    "TRACE_ACCEL_LIMIT",
    "TRACE_MAX_SAMPLES",
    "TRACE_MAX_SPAN",
    "check_trace_size",
    "BRAKE_LIMIT",
    "REACTION_TIME",
    "STOP_MARGIN",
    "stopping_gap",
    "check_trajectory",
    "check_initial",
    "MAX_PREROLL",
    "PREROLL_MIN_GAP",
]

SCENARIOS = ("ice", "ev")  # host vehicle and paper setting (Table 2)
TEST_TRAJECTORIES = ("test-1", "test-2", "test-3", "test-4")
RANDOM = "random"
TEST_DURATION = 240.0  # [s] the paper's 4-minute test trajectories
RANDOM_DURATION = 240.0  # [s] training episodes are as long as the tests
TRACE = "trace"  # wire name of a trace sent with the reset

# Cruise set speed: the driver's input, enforced by the host's speed limiter.
DEFAULT_SET_SPEED = 33.5  # [m/s] 120.6 km/h, above the ICE leads' 33 m/s maximum
# [m/s] what may be set: a driver sets 1..50 m/s (3.6..180 km/h); up to 80 m/s is
# accepted so that runs from before the limiter can be repeated exactly (it never binds).
SET_SPEED_RANGE = (1.0, 80.0)
GAP_LIMIT = 300.0  # [m] an episode terminates beyond this gap (paper Sec. 3)
# The pre-roll: the camera's frames before the controller engages, the host coasting
# at its initial speed and the lead at its own, as a camera that was on before the
# driver engaged the ACC would have seen them (frames -preroll..-1 of an episode).
MAX_PREROLL = 100  # [control steps] 10 s
# [m] a lead faster than the host is drawn no closer than this in the pre-roll (it
# would otherwise have been behind the host a few seconds earlier: it had cut in)
PREROLL_MIN_GAP = 5.0

# Physical sanity limits of a user's lead trace; it is driven as given inside them.
TRACE_SPEED_MAX = 70.0  # [m/s] 252 km/h
# A trace's size: as many samples as one wire array holds, over at most 4 h (the server
# resamples it at the physics rate: 720,000 steps at most).
TRACE_MAX_SAMPLES = MAX_ARRAY_LEN
TRACE_MAX_SPAN = 14_400.0  # [s]
TRACE_ACCEL_LIMIT = 9.81  # [m/s^2] 1 g either way: beyond tyre grip of a road car

# What "stopping is physically possible" means for the scenarios below.
BRAKE_LIMIT = -A_MIN  # [m/s^2] the host's full-brake deceleration (u = -1)
REACTION_TIME = 0.1  # [s] one control period before the first brake command acts
STOP_MARGIN = 2.0  # [m] gap left at standstill (the safety suite's minimum gap)


def check_trace_size(samples: int, span: float) -> None:
    """A lead trace's sample count and time span [s] against :data:`TRACE_MAX_SAMPLES` and
    :data:`TRACE_MAX_SPAN`.

    Raises:
        ValueError: one line naming the limit broken.
    """
    if samples > TRACE_MAX_SAMPLES:
        raise ValueError(f"a trace holds at most {TRACE_MAX_SAMPLES} samples; this one has {samples}")
    if not span <= TRACE_MAX_SPAN:
        raise ValueError(f"a trace spans at most {TRACE_MAX_SPAN:g} s (4 h); this one spans {span:g} s")


def stopping_gap(closing_speed: float) -> float:
    """Gap [m] the host needs to shed ``closing_speed`` [m/s] at its braking limit.

    One control period of reaction at the closing speed, then full braking, with
    :data:`STOP_MARGIN` left over.
    """
    return closing_speed * REACTION_TIME + closing_speed**2 / (2.0 * BRAKE_LIMIT) + STOP_MARGIN


@dataclass(frozen=True)
class Param:
    """One parameter of a lead scenario, drawn uniformly from ``[low, high]``."""

    name: str
    low: float
    high: float
    unit: str
    meaning: str


@dataclass(frozen=True)
class LeadScenario:
    """A named lead scenario: what the lead does, and the host's start."""

    name: str
    summary: str
    resembles: str  # the standard test it is shaped after
    duration: float  # [s] episode length
    params: tuple[Param, ...]

    def param(self, name: str) -> Param:
        """The parameter called ``name``.

        Raises:
            KeyError: if there is none.
        """
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(f"lead scenario {self.name!r} has no parameter {name!r}")


# The seed draws the parameters in the order listed (the server relies on it).
LEAD_SCENARIOS: dict[str, LeadScenario] = {
    s.name: s
    for s in (
        LeadScenario(
            "stopped",
            "A car stands still ahead from the start; the host approaches it.",
            "Euro NCAP CCRs (car-to-car rear, stationary target); ISO 15622 stopping on a stationary target",
            40.0,
            (
                Param("v_host", 8.0, 16.0, "m/s", "host's initial speed"),
                Param("gap", 25.0, 40.0, "m", "initial gap, at least stopping_gap(v_host) (drawn above it)"),
            ),
        ),
        LeadScenario(
            "brake-stop",
            "Host and lead cruise at one speed; the lead brakes to a standstill and stays there.",
            "Euro NCAP CCRb (braking target, 2-6 m/s^2), braking to a stop; ISO 15622 FSRA stopping",
            60.0,
            (
                Param("v_cruise", 14.0, 30.0, "m/s", "initial speed of lead and host"),
                Param("gap", 20.0, 55.0, "m", "initial gap"),
                Param("t_brake", 3.0, 10.0, "s", "time the lead cruises before braking"),
                Param("decel", 2.0, 6.0, "m/s^2", "lead's deceleration"),
            ),
        ),
        LeadScenario(
            "brake-hard",
            "Host and lead cruise at one speed; the lead brakes hard to a lower speed and holds it.",
            "Euro NCAP CCRb (braking target) ending at a lower speed rather than a stop",
            60.0,
            (
                Param("v_cruise", 20.0, 30.0, "m/s", "initial speed of lead and host"),
                Param("gap", 20.0, 55.0, "m", "initial gap"),
                Param("t_brake", 3.0, 10.0, "s", "time the lead cruises before braking"),
                Param("decel", 4.0, 6.0, "m/s^2", "lead's deceleration"),
                Param("speed_drop", 8.0, 15.0, "m/s", "how much speed the lead sheds"),
            ),
        ),
        LeadScenario(
            "slow-lead",
            "The lead drives much slower than the host at a constant speed.",
            "Euro NCAP CCRm (car-to-car rear, moving target at 20 km/h)",
            60.0,
            (
                Param("v_lead", 4.0, 12.0, "m/s", "lead's constant speed"),
                Param("v_host", 20.0, 30.0, "m/s", "host's initial speed"),
                Param("gap", 60.0, 120.0, "m", "initial gap, at least stopping_gap(v_host - v_lead)"),
            ),
        ),
        LeadScenario(
            "cut-in",
            "A slower car cuts in close ahead: from frame 0 it drives in the host's lane, inside the camera's near field.",
            "Euro NCAP Assisted Driving cut-in, and ISO 15622 target changes (the lateral move itself is not simulated)",
            40.0,
            (
                Param("v_host", 8.0, 30.0, "m/s", "host's initial speed"),
                Param("speed_deficit", 2.0, 8.0, "m/s", "how much slower the lead drives (constant)"),
                Param("gap", 8.0, 25.0, "m", "initial gap, at least stopping_gap(speed_deficit) (drawn above it)"),
            ),
        ),
        LeadScenario(
            "closing",
            "A slower car ahead, the host closing on it from a gap just above its stopping distance at full braking: only braking at once, and hard, stops in time.",
            "Euro NCAP CCRm (moving target) met late, as after a missed target; the camera's near field (docs/scenarios.md)",
            40.0,
            (
                Param("v_lead", 2.0, 15.0, "m/s", "lead's constant speed"),
                Param("closing_speed", 3.0, 14.0, "m/s", "host's initial speed minus the lead's"),
                Param("margin", 1.15, 1.6, "", "initial gap as a multiple of stopping_gap(closing_speed)"),
            ),
        ),
        LeadScenario(
            "catch-up",
            "The lead drives much faster than the host at the start; the gap opens before the host catches up.",
            "ISO 15622 target approach from behind (free driving into following)",
            90.0,
            (
                Param("v_lead", 24.0, 30.0, "m/s", "lead's constant speed (below the default set speed)"),
                Param("speed_deficit", 6.0, 18.0, "m/s", "how much slower the host starts"),
                Param("gap", 30.0, 50.0, "m", "initial gap"),
            ),
        ),
        LeadScenario(
            "stop-and-go",
            "Queue traffic: the lead repeatedly cruises, brakes to a stop, stands, and pulls away.",
            "ISO 15622 full-speed-range ACC (FSRA) stop-and-go; ISO 22179 traffic jam following",
            120.0,
            (
                Param("v_go", 6.0, 14.0, "m/s", "cruise speed of each go phase (the first is the start speed of both cars)"),
                Param("t_cruise", 2.0, 8.0, "s", "cruise time of each go phase"),
                Param("decel", 1.5, 3.5, "m/s^2", "deceleration of each stop"),
                Param("t_stand", 2.0, 8.0, "s", "standing time of each stop"),
                Param("accel", 1.0, 2.0, "m/s^2", "acceleration of each pull-away"),
                Param("gap", 15.0, 30.0, "m", "initial gap"),
            ),
        ),
        LeadScenario(
            "constant",
            "The lead holds one speed for the whole episode.",
            "Steady-state following (ISO 15622 time-gap keeping); the eco bound's constant lead",
            120.0,
            (
                Param("v_lead", 10.0, 31.0, "m/s", "lead's constant speed (below the default set speed)"),
                Param("speed_offset", -3.0, 3.0, "m/s", "host's initial speed minus the lead's"),
                Param("gap", 30.0, 60.0, "m", "initial gap"),
            ),
        ),
        LeadScenario(
            "distant-stop",
            "The lead, far ahead while the host cruises at the set speed, brakes to a standstill and stays there.",
            "Euro NCAP CCRb (braking target, up to 4 m/s^2) met from far behind; ISO 15622 approach to a stopping target beyond the camera's range",
            60.0,
            (
                Param("v_cruise", 24.0, 30.0, "m/s", "lead's initial speed (below the default set speed: the host closes)"),
                Param("gap", 100.0, 200.0, "m", "initial gap"),
                Param("t_brake", 2.0, 10.0, "s", "time the lead cruises before braking"),
                Param("decel", 2.0, 4.0, "m/s^2", "lead's deceleration"),
            ),
        ),
    )
}

TRAJECTORIES = (*TEST_TRAJECTORIES, RANDOM, *LEAD_SCENARIOS)  # every named trajectory


def check_trajectory(name: str) -> str:
    """Return ``name`` if it is a named trajectory.

    Raises:
        ValueError: one line listing the names.
    """
    if name not in TRAJECTORIES:
        raise ValueError(f"unknown trajectory {name!r}; expected one of {', '.join(TRAJECTORIES)} (or a CSV trace)")
    return name


def check_sun_elevation(bounds: tuple[float, ...]) -> str | None:
    """What is wrong with a range [rad] to draw the sun's height from, or None: two numbers,
    low <= high, within :data:`~protocol.constants.SUN_ELEVATION_LIMITS`."""
    lo_limit, hi_limit = SUN_ELEVATION_LIMITS
    if len(bounds) != 2 or not all(math.isfinite(b) for b in bounds):
        return f"must be two numbers LOW,HIGH [rad], got {','.join(map(str, bounds))}"
    if not lo_limit <= bounds[0] <= bounds[1] <= hi_limit:
        return f"must have {lo_limit:g} <= LOW <= HIGH <= {hi_limit:g} rad, got {bounds[0]:g},{bounds[1]:g}"
    return None


def parse_sun_elevation(text: str) -> tuple[float, float]:
    """"LOW,HIGH" [rad] as a checked range for the sun's height.

    Raises:
        ValueError: one line: not two numbers, or outside :func:`check_sun_elevation`'s bounds.
    """
    try:
        bounds = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{text!r} is not LOW,HIGH in radians") from None
    if (why := check_sun_elevation(bounds)) is not None:
        raise ValueError(why)
    return bounds[0], bounds[1]


def check_initial(*, host_speed: float | None, gap: float | None, set_speed: float | None, preroll: int = 0) -> None:
    """Check a reset's optional initial host speed [m/s], gap [m] and set speed [m/s], and its pre-roll [steps].

    Raises:
        ValueError: one line naming the value and its allowed range.
    """
    v_set = DEFAULT_SET_SPEED if set_speed is None else set_speed
    lo, hi = SET_SPEED_RANGE
    if not (math.isfinite(v_set) and lo <= v_set <= hi):
        raise ValueError(f"set speed {v_set!r} m/s is outside {lo:g}..{hi:g} m/s")
    if host_speed is not None and not (math.isfinite(host_speed) and 0.0 <= host_speed <= v_set):
        raise ValueError(f"host speed {host_speed!r} m/s is outside 0..{v_set:g} m/s (the set speed)")
    if gap is not None and not (math.isfinite(gap) and 0.0 < gap < GAP_LIMIT):
        raise ValueError(f"gap {gap!r} m is outside (0, {GAP_LIMIT:g}) m")
    if not 0 <= preroll <= MAX_PREROLL:
        raise ValueError(f"preroll {preroll!r} is outside 0..{MAX_PREROLL} control steps")
