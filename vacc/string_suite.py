"""``vacc evaluate --suite string``: what a follower does to the speed waves of the car
ahead, on leads that are not the nine OpenACC files (so a model is selected here and
judged there).

Two parts, each for every law in ``--methods`` and every ``--model`` (from its camera):

* **Gains**: one follower behind a lead whose speed is a sine of
  :data:`SINE_AMPLITUDE` around each of :data:`SINE_SPEEDS` at each of
  :data:`SINE_FREQS`; the gain is the amplitude of the follower's speed at that frequency
  over the lead's (least squares after :data:`SETTLE_S`). A platoon of identical followers
  is string-stable where every gain is at most 1; a gain g at a frequency grows a wave by
  g^n over n cars. For the ACC law the linear theory (:func:`~agent_client.controllers.acc.speed_transfer`)
  is printed beside it.
* **Platoons**: :data:`FOLLOWERS` followers behind held-out leads like OpenACC's (a driver
  cruising, then changing speed within :data:`LEAD_SPEEDS`; seeds :data:`LEAD_SEEDS`,
  :data:`LEAD_SECONDS` each) and behind a lead at a constant :data:`STILL_SPEED`: the
  lead-to-last amplification of speed deviation (RMS and peak, after the first fifth), the
  last car's own deviation (what counts behind the constant lead), the closest gap, collisions.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from agent_client.controllers.acc import AccController, speed_transfer
from agent_client.progress import progress_bar
from agent_client.rl.teachers import REGISTRY, teacher_law
from energy.string_stability import amplification, safety
from vacc.openacc_suite import STILL_LEAD_MPS
from vacc.platoon_world import drive_platoon

__all__ = ["SINE_SPEEDS", "SINE_FREQS", "SINE_AMPLITUDE", "LEAD_SEEDS", "FOLLOWERS", "LAWS", "GainRow", "PlatoonRow",
           "sine_gain", "gain_rows", "platoon_rows", "held_out_lead", "still_lead", "law_maker", "model_maker", "run_string", "string_tables"]  # fmt: skip

SINE_SPEEDS = (8.0, 20.0)  # [m/s] the OpenACC leads' slowest (8.1) and a highway speed
SINE_FREQS = (0.02, 0.05, 0.1, 0.2, 0.3)  # [Hz] the OpenACC leads' speed changes lie below 0.1 Hz
SINE_AMPLITUDE = 0.5  # [m/s] small enough that no limit of the ACC law engages
LAG_FREQ = 0.1  # [Hz] where the table gives the follower's lag (how late it answers the lead)
SETTLE_S = 30.0  # [s] left out of each sine fit: the follower settles to its spacing
SINE_PERIODS = 5
LEAD_SEEDS = (7001, 7002, 7003)  # held-out leads: seeds no training draws from this generator
LEAD_SECONDS = 180.0
LEAD_SPEEDS = (4.0, 12.0)  # [m/s] the OpenACC leads drive 4.3-11.2 m/s
STILL_SPEED = 8.1  # [m/s] OpenACC's constant-speed lead (mixed_dynamic_part5)
FOLLOWERS = 10
LEAD_DT = 0.1  # [s] the held-out leads' sample period
LAWS = tuple(name for name, t in REGISTRY.items() if t.gap is not None)  # --methods: the ACC and each teacher law


class GainRow(NamedTuple):
    driver: str
    speed: float  # [m/s] the sine's mean
    freq: float  # [Hz]
    gain: float  # [-] follower's speed amplitude over the lead's at freq
    lag_s: float  # [s] how late the follower's speed wave follows the lead's
    theory: float  # [-] the linearised ACC law's |H|; NaN for anything else
    min_gap_m: float
    collided: bool


class PlatoonRow(NamedTuple):
    driver: str
    lead: str  # "seed N" or "still" (the constant lead)
    cars: int  # the lead included
    speed_rms: float  # [-] lead-to-last, after the first fifth
    speed_peak: float
    lead_dev_rms: float  # [m/s]
    last_dev_rms: float  # [m/s]
    min_gap_m: float
    collided: bool


Maker = Callable[[], Any]


def _sine_component(t: np.ndarray, y: np.ndarray, f: float) -> complex:
    """The f [Hz] component of y by least squares (sine, cosine, offset), as a phasor."""
    basis = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)], axis=1)
    c, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return complex(c[0], c[1])


def _scenario(controller: Any) -> str:
    cfg = getattr(controller, "cfg", None)
    return str(cfg.scenario) if cfg is not None else "ice"


def _drive(make: Maker, n: int, lead: tuple[np.ndarray, np.ndarray]) -> Any:
    controllers = [make() for _ in range(n)]
    v0 = float(lead[1][0])
    return drive_platoon(controllers, [_scenario(controllers[0])] * n, lead, [AccController().reference_gap(v0)] * n, host_speed=v0)


def sine_gain(make: Maker, speed: float, freq: float) -> tuple[float, float, float, bool]:
    """(gain, lag [s], closest gap [m], collided) of one follower behind a sinusoidal lead;
    the lag is how late its speed's wave follows the lead's (its phase over 2 pi f)."""
    t = np.arange(0.0, SETTLE_S + SINE_PERIODS / freq + 1e-9, 0.1)
    run = _drive(make, 1, (t, speed + SINE_AMPLITUDE * np.sin(2 * np.pi * freq * t)))
    m = run.t >= SETTLE_S
    if run.collided is not None or m.sum() < 10:
        return float("nan"), float("nan"), float(run.gaps.min()), True
    ratio = _sine_component(run.t[m], run.v[1, m], freq) / _sine_component(run.t[m], run.v[0, m], freq)
    lag = -float(np.angle(ratio)) / (2 * np.pi * freq)
    return abs(ratio), lag, float(run.gaps.min()), False


def gain_rows(name: str, make: Maker, speeds: Sequence[float] = SINE_SPEEDS, freqs: Sequence[float] = SINE_FREQS) -> list[GainRow]:
    law = make()
    theory = isinstance(law, AccController)
    rows = []
    for v in speeds:
        for f in freqs:
            gain, lag, gap, hit = sine_gain(make, v, f)
            h = abs(speed_transfer(law, 2 * np.pi * f)) if theory else float("nan")
            rows.append(GainRow(name, v, f, gain, lag, h, gap, hit))
    return rows


def held_out_lead(seed: int, seconds: float = LEAD_SECONDS) -> tuple[np.ndarray, np.ndarray]:
    """A lead like OpenACC's manually driven ones (times [s], speeds [m/s] every 0.1 s): it
    cruises 5-20 s, then moves to a new speed in :data:`LEAD_SPEEDS` at 0.3-1.2 m/s^2, over
    and over; drawn from ``seed`` alone."""
    rng = np.random.default_rng([seed, 57])
    v = [rng.uniform(6.0, 10.0)]
    while len(v) * LEAD_DT <= seconds:
        v += [v[-1]] * int(rng.uniform(5.0, 20.0) / LEAD_DT)
        target, accel = rng.uniform(*LEAD_SPEEDS), rng.uniform(0.3, 1.2)
        steps = max(1, int(abs(target - v[-1]) / (accel * LEAD_DT)))
        v += list(np.linspace(v[-1], target, steps + 1)[1:])
    speeds = np.array(v[: int(round(seconds / LEAD_DT)) + 1])
    return np.arange(speeds.shape[0]) * LEAD_DT, speeds


def still_lead(seconds: float = LEAD_SECONDS) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(round(seconds / LEAD_DT)) + 1) * LEAD_DT
    return t, np.full_like(t, STILL_SPEED)


def platoon_rows(name: str, make: Maker, seeds: Sequence[int] = LEAD_SEEDS, followers: int = FOLLOWERS, seconds: float = LEAD_SECONDS) -> list[PlatoonRow]:
    """A platoon behind each held-out lead, then behind the constant one."""
    rows = []
    leads = [(f"seed {s}", held_out_lead(s, seconds)) for s in seeds] + [("still", still_lead(seconds))]
    for label, lead in leads:
        run = _drive(make, followers, lead)
        amp = amplification(run.t, run.v)
        gap = min((s.min_gap_m for s in safety(run.t, run.v, run.gaps)), default=float("nan"))
        r = amp.lead_to_last
        rows.append(PlatoonRow(name, label, run.v.shape[0], r.speed_rms, r.speed_peak, amp.lead_speed_dev_rms, amp.last_speed_dev_rms, gap,
                               run.collided is not None))  # fmt: skip
    return rows


def law_maker(name: str) -> Maker:
    """A law of :data:`~agent_client.rl.teachers.REGISTRY` (``acc``: the shipped gains)."""
    return lambda: teacher_law(name)


def model_maker(path: str) -> Maker:
    from agent_client.controllers.ddqn import DDQNController  # torch: only for a learned follower

    return lambda: DDQNController.from_checkpoint(path)


def string_tables(gains: Sequence[GainRow], platoons: Sequence[PlatoonRow]) -> list[str]:
    """Two Markdown tables: the gains (a row per driver and speed) and the platoons."""
    freqs = sorted({g.freq for g in gains})
    lines = ["Speed-to-speed gain of one follower behind a sinusoidal lead "
             f"(±{SINE_AMPLITUDE} m/s; the ACC's linear theory in brackets; over 1 amplifies down a platoon).", "",
             "| driver | speed [m/s] | " + " | ".join(f"{f:g} Hz" for f in freqs) + f" | peak | lag at {LAG_FREQ:g} Hz [s] |",
             "| --- | --- | " + " | ".join("---" for _ in freqs) + " | --- | --- |"]  # fmt: skip
    for (driver, speed), rows in _group(gains, lambda g: (g.driver, g.speed)).items():
        cells = {g.freq: ("collision" if g.collided else f"{g.gain:.2f}" + ("" if math.isnan(g.theory) else f" ({g.theory:.2f})")) for g in rows}
        peak = max((g.gain for g in rows if not g.collided), default=float("nan"))
        lag = next((g.lag_s for g in rows if g.freq == LAG_FREQ), float("nan"))
        lines.append(f"| {driver} | {speed:g} | " + " | ".join(cells.get(f, "") for f in freqs) + f" | {peak:.2f} | {lag:.2f} |")
    if platoons:
        lines += ["", "Platoons behind held-out leads like OpenACC's: lead-to-last amplification of speed deviation after the first fifth, "
                  "RMS / peak, and the last car's own deviation (behind the constant lead, the figure that counts).", "",
                  "| driver | lead | cars | lead dev [m/s] | RMS / peak | last car dev [m/s] | closest gap [m] |", "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
        for p in platoons:
            cell = "collision" if p.collided else ("-" if p.lead_dev_rms < STILL_LEAD_MPS else f"{p.speed_rms:.2f} / {p.speed_peak:.2f}")
            lines.append(f"| {p.driver} | {p.lead} | {p.cars} | {p.lead_dev_rms:.3f} | {cell} | {p.last_dev_rms:.3f} | {p.min_gap_m:.1f} |")
    return lines


def _group(rows: Sequence[Any], key: Callable[[Any], Any]) -> dict[Any, list[Any]]:
    out: dict[Any, list[Any]] = {}
    for r in rows:
        out.setdefault(key(r), []).append(r)
    return out


def run_string(out: Path, drivers: dict[str, Maker], *, followers: int = FOLLOWERS, seeds: Sequence[int] = LEAD_SEEDS) -> str:
    """Drive the suite for each driver (name -> maker); write ``out/string.md`` and ``out/string.json``; return the tables."""
    gains: list[GainRow] = []
    platoons: list[PlatoonRow] = []
    with progress_bar(2 * len(drivers), "string", unit="part") as bar:
        for name, make in drivers.items():
            gains += gain_rows(name, make)
            bar.update(1)
            platoons += platoon_rows(name, make, seeds, followers)
            bar.update(1)
    table = "\n".join(string_tables(gains, platoons)) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "string.md").write_text("# String stability on held-out leads\n\n" + table)
    (out / "string.json").write_text(json.dumps({"gains": [g._asdict() for g in gains], "platoons": [p._asdict() for p in platoons]}, indent=1, default=float) + "\n")
    return table
