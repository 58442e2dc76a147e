from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import energy
from energy import RunLogError, load_cycle, read_speed_csv, units
from energy.cycles import CYCLES, UDDS_BAG2_START_S
from energy.trace import intervals

DISTANCE_MI = {"udds": 7.451, "hwfet": 10.257, "us06": 8.008, "wltc_3b": 23.27 / 1.609344}


@pytest.mark.parametrize("name", CYCLES)
def test_shipped_cycle_distance_matches_provenance(name: str) -> None:
    c = load_cycle(name)
    assert np.all(np.diff(c.t) == 1.0)
    assert units.m_to_mi(intervals(c.t, c.v).distance_m) == pytest.approx(
        DISTANCE_MI[name], rel=2e-3
    )


def test_cycles_load_from_the_package_not_shared_data() -> None:
    pkg = Path(energy.__file__).parent
    assert (pkg / "data" / "cycles" / "udds.csv").is_file()
    assert (pkg / "data" / "README.md").is_file()


def test_bag2_window() -> None:
    bag2 = load_cycle("udds").window(UDDS_BAG2_START_S)
    assert bag2.t[0] == UDDS_BAG2_START_S and bag2.t[-1] == 1369.0


def test_unknown_cycle() -> None:
    with pytest.raises(KeyError, match="unknown cycle"):
        load_cycle("nedc")


def test_read_speed_csv_errors(tmp_path: Path) -> None:
    p = tmp_path / "trace.csv"
    p.write_text("t_s,speed_mps\n0,1\n1,-2\n")
    with pytest.raises(RunLogError, match=r"trace\.csv, row 2 \(line 3\): negative speed"):
        read_speed_csv(p)
    p.write_text("t_s,v\n0,1\n")
    with pytest.raises(RunLogError, match="missing column 'speed_mps'"):
        read_speed_csv(p)
    with pytest.raises(RunLogError, match="cannot read file"):
        read_speed_csv(tmp_path / "nope.csv")
