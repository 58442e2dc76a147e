"""``vacc evaluate --suite openacc``: simulated platoons behind the real leads of OpenACC.

For each of the nine shipped OpenACC files (:data:`energy.openacc.OPENACC_FILES`), the
recorded lead's speed drives platoons of the real platoon's length in the kinematic
platoon (:mod:`vacc.platoon_sim`): all ACC (the shipped gains), all HDM, and mixed
(ACC and HDM alternating, ACC first). Each is tabulated beside the real platoon of the
same file: the lead-to-last amplification of speed deviation (RMS and peak, after the
first fifth, :mod:`energy.string_stability`), the last car's own RMS deviation, and the
closest gap.

Where the lead's own deviation is under :data:`STILL_LEAD_MPS` (a constant-speed lead),
a ratio means nothing: the table gives the last car's deviation instead (``dev``).

Learned followers (``--model NAME=PATH``) drive from their cameras in the camera platoon
world (:mod:`vacc.platoon_world`): a platoon of the real one's length, every follower the
model, each starting at the ACC's reference gap for the lead's first speed and settling to
its own spacing in the first fifth, which the figures leave out.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from agent_client.controllers.acc import AccController
from agent_client.controllers.hdm import HdmParams, HumanDriverModel
from agent_client.progress import progress_bar
from energy.openacc import OPENACC_FILES, OpenAccRun, read_openacc
from energy.string_stability import amplification, safety
from vacc.platoon_sim import lead_profile, simulate_platoon
from vacc.platoon_world import drive_platoon

__all__ = ["PLATOONS", "STILL_LEAD_MPS", "PlatoonRow", "camera_row", "openacc_rows", "openacc_table", "run_openacc", "simulated_row"]

STILL_LEAD_MPS = 0.1  # [m/s] a lead deviating less than this makes no wave to amplify


def _acc(i: int) -> tuple[Any, Callable[[float], float]]:
    law = AccController()
    return law, law.reference_gap


def _hdm(i: int) -> tuple[Any, Callable[[float], float]]:
    p = HdmParams()
    return HumanDriverModel(p, seed=i), lambda v: p.s0 + p.t_gap * v


# Each platoon kind: follower i (1 = nearest the lead) -> (controller, its equilibrium gap [m] at a speed [m/s]).
PLATOONS: dict[str, Callable[[int], Any]] = {
    "acc": _acc,
    "hdm": _hdm,
    "mixed": lambda i: _acc(i) if i % 2 == 1 else _hdm(i),
}


class PlatoonRow(NamedTuple):
    """One platoon behind one file's lead: the real one or a simulated kind."""

    file: str
    platoon: str  # "real", or a key of PLATOONS
    cars: int  # the lead included
    speed_rms: float  # [-] lead-to-last RMS speed-deviation ratio after the first fifth
    speed_peak: float  # [-] the same for the peak deviation
    lead_dev_rms: float  # [m/s]
    last_dev_rms: float  # [m/s]
    min_gap_m: float  # [m] the closest any follower came (bumper to bumper)
    collided: bool


def _row(file: str, platoon: str, t: np.ndarray, v: np.ndarray, gaps: np.ndarray, collided: bool) -> PlatoonRow:
    amp = amplification(t, v)
    gap = min((s.min_gap_m for s in safety(t, v, gaps)), default=float("nan"))
    r = amp.lead_to_last
    return PlatoonRow(file, platoon, v.shape[0], r.speed_rms, r.speed_peak, amp.lead_speed_dev_rms, amp.last_speed_dev_rms, gap, collided)


def _lead(run: OpenAccRun) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(run.speed[0])
    return run.t[ok], run.speed[0, ok]


def simulated_row(run: OpenAccRun, platoon: str, followers: int | None = None) -> PlatoonRow:
    """A ``platoon`` of the real one's length (or of ``followers``) behind ``run``'s recorded lead, from equilibrium."""
    t, v = _lead(run)
    made = [PLATOONS[platoon](i) for i in range(1, 1 + (followers or run.n_cars - 1))]
    sim = simulate_platoon(lead_profile(t, v, t[-1] - t[0]), [c for c, _ in made], [gap(float(v[0])) for _, gap in made])
    return _row(run.name, platoon, sim.t, sim.v, sim.gaps, sim.collided is not None)


def camera_row(run: OpenAccRun, name: str, checkpoint: str, followers: int | None = None) -> PlatoonRow:
    """A platoon of the real one's length (or of ``followers``) behind ``run``'s recorded lead,
    every follower the policy ``checkpoint`` driving from its camera (named ``name`` in the table)."""
    from agent_client.controllers.ddqn import DDQNController  # torch: only for a learned platoon

    t, v = _lead(run)
    controllers = [DDQNController.from_checkpoint(checkpoint) for _ in range(followers or run.n_cars - 1)]
    v0 = float(v[0])
    sim = drive_platoon(controllers, [controllers[0].cfg.scenario] * len(controllers), (t - t[0], v), [AccController().reference_gap(v0)] * len(controllers),
                        host_speed=v0)  # fmt: skip
    return _row(run.name, name, sim.t, sim.v, sim.gaps, sim.collided is not None)


def openacc_rows(files: Sequence[str] = OPENACC_FILES, platoons: Sequence[str] = tuple(PLATOONS), models: dict[str, str] | None = None,
                 followers: int | None = None) -> list[PlatoonRow]:  # fmt: skip
    """The real platoon, each simulated kind and each learned model (name -> checkpoint), file
    by file; the simulated ones of the real one's length, or of ``followers``.

    Raises:
        energy.errors.DataError: a file that does not read.
    """
    rows = []
    with progress_bar(len(files), "openacc", unit="file", enabled=bool(models)) as bar:  # a learned platoon takes minutes a file
        for name in files:
            run = read_openacc(name)
            rows.append(_row(name, "real", run.t, run.speed, run.ivs, False))
            rows += [simulated_row(run, kind, followers) for kind in platoons]
            rows += [camera_row(run, model, path, followers) for model, path in (models or {}).items()]
            bar.update(1)
    return rows


def _cell(row: PlatoonRow) -> str:
    if row.collided:
        return "collision"
    if row.lead_dev_rms < STILL_LEAD_MPS:
        return f"dev {row.last_dev_rms:.3f} m/s"
    return f"{row.speed_rms:.2f} / {row.speed_peak:.2f}"


def openacc_table(rows: Sequence[PlatoonRow]) -> list[str]:
    """A Markdown table: one line per file, one column per platoon (RMS / peak ratio)."""
    kinds = list(dict.fromkeys(r.platoon for r in rows))
    by_file: dict[str, dict[str, PlatoonRow]] = {}
    for r in rows:
        by_file.setdefault(r.file, {})[r.platoon] = r
    lines = [
        "Lead-to-last amplification of speed deviation after the first fifth, RMS / peak "
        f"(a constant-speed lead, under {STILL_LEAD_MPS} m/s of deviation: the last car's own deviation).",
        "",
        "| file | cars: real, simulated | lead dev [m/s] | " + " | ".join(kinds) + " | closest gap, simulated [m] |",
        "| --- | --- | --- | " + " | ".join("---" for _ in kinds) + " | --- |",
    ]
    for name, got in by_file.items():
        real = got["real"]
        closest = min((r.min_gap_m for k, r in got.items() if k != "real"), default=float("nan"))
        sim_cars = "+".join(str(c) for c in sorted({r.cars for k, r in got.items() if k != "real"}))
        lines.append(f"| {name} | {real.cars}, {sim_cars} | {real.lead_dev_rms:.3f} | " + " | ".join(_cell(got[k]) for k in kinds) + f" | {closest:.1f} |")
    return lines


def run_openacc(out: Path, files: Sequence[str] = OPENACC_FILES, platoons: Sequence[str] = tuple(PLATOONS), models: dict[str, str] | None = None,
                followers: int | None = None) -> str:  # fmt: skip
    """Drive the suite; write ``out/openacc.md`` and ``out/openacc.json``; return the table."""
    rows = openacc_rows(files, platoons, models, followers)
    table = "\n".join(openacc_table(rows)) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "openacc.md").write_text("# Real ACC platoons (OpenACC) beside simulated ones\n\n" + table)
    (out / "openacc.json").write_text(json.dumps([r._asdict() for r in rows], indent=1, default=float) + "\n")
    return table
