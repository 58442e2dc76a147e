"""Energy and emissions of a run: CMEM for ICE cars, the EV energy rate model, metrics.

Depends on numpy only and imports no other package of the project.

* :mod:`energy.cmem`: CMEM fuel and tailpipe CO2/CO/HC/NOx; the calibrated 2022
  Toyota Corolla and the paper-era "average" category.
* :mod:`energy.ev`: VT-CPEM Nissan Leaf with regeneration, and the paper's eq. 6
  with coefficients fitted to VT-CPEM (not the UCR values).
* :mod:`energy.metrics`: :func:`evaluate_run`, every metric of a run log.
* :mod:`energy.comfort`: the ISO 15622 window tests and acceleration sign changes.
* :mod:`energy.string_stability`: a platoon's amplification per pair and lead to last, its
  speed-to-speed gains (Welch), minimum gaps and TTC, total energy.
* :mod:`energy.openacc`: the nine OpenACC real-platoon files shipped in ``energy/data/openacc``.
* :mod:`energy.frontier`: the least eq. 6 energy a follower with preview reaches at a gap error.
* :mod:`energy.runlog` (whole or in chunks), :mod:`energy.segments` (a log in segments with
  context, for scoring a long one), :mod:`energy.cycles`, :mod:`energy.units`, :mod:`energy.errors`.
* :func:`write_params`, :func:`data_path`: the fitted parameters in ``energy/data``, for the
  calibration scripts of ``scripts/``.
"""

from __future__ import annotations

from energy._data import data_path, write_params
from energy.cmem import AVERAGE_PAPER_ERA, COROLLA_2022, CmemResult, CmemVehicle, cmem_rates
from energy.cmem import per_mile as cmem_per_mile
from energy.cycles import CYCLES, Cycle, load_cycle, read_speed_csv
from energy.errors import DataError, EnergyError, RunLogError, TraceError
from energy.ev import (
    LEAF,
    EvResult,
    LeafVtCpem,
    eq6_per_mile,
    eq6_power_kw,
    vtcpem_per_mile,
    vtcpem_power_w,
)
from energy.metrics import SCENARIO_VEHICLES, SETTLE_S, VEHICLE_NAMES, evaluate_run
from energy.runlog import REQUIRED_COLUMNS, RunLog, read_run_log

__all__ = [
    "AVERAGE_PAPER_ERA",
    "COROLLA_2022",
    "CYCLES",
    "LEAF",
    "REQUIRED_COLUMNS",
    "SETTLE_S",
    "VEHICLE_NAMES",
    "SCENARIO_VEHICLES",
    "CmemResult",
    "CmemVehicle",
    "Cycle",
    "DataError",
    "EnergyError",
    "EvResult",
    "LeafVtCpem",
    "RunLog",
    "RunLogError",
    "TraceError",
    "cmem_per_mile",
    "cmem_rates",
    "data_path",
    "eq6_per_mile",
    "eq6_power_kw",
    "evaluate_run",
    "load_cycle",
    "read_run_log",
    "read_speed_csv",
    "write_params",
    "vtcpem_per_mile",
    "vtcpem_power_w",
]
