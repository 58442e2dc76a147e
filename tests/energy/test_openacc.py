"""The shipped OpenACC files read right, and the real platoons' amplification."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from energy.errors import DataError
from energy.openacc import OPENACC_FILES, read_openacc, real_amplification

# Lead-to-last RMS speed-deviation ratio after the first fifth, as measured (2 decimals).
# Whole runs (skip 0) give the 1.1-10.9 and 46x; after the first fifth the
# nearly constant leads (part4, part5, part20: lead deviation < 0.1 m/s) make the ratio
# meaningless (101x, 33x, 6.8x).
REAL_RATIO = {
    "long_setting_dynamic_part18.csv": 2.22,
    "long_setting_dynamic_part19.csv": 1.09,
    "long_setting_dynamic_part2.csv": 1.11,
    "medium_setting_dynamic_part8.csv": 1.43,
    "mixed_dynamic_part5.csv": 33.33,
    "short_setting_dynamic_part1.csv": 3.58,
    "short_setting_dynamic_part10.csv": 2.07,
    "short_setting_dynamic_part20.csv": 6.75,
    "short_setting_dynamic_part4.csv": 101.22,
}


def test_every_shipped_file_reads() -> None:
    assert sorted(REAL_RATIO) == sorted(OPENACC_FILES)
    for name in OPENACC_FILES:
        run = read_openacc(name)
        assert run.acc and run.distance_setting in ("S", "M", "L")
        assert run.vehicles[0] == "SMART_TARGET"
        assert run.speed.shape == (run.n_cars, run.t.size)
        assert run.ivs.shape == (run.n_cars - 1, run.t.size)
        assert np.nanmax(run.speed) < 20.0 and np.nanmin(run.ivs) > 0.0
        assert run.time_jumps() == []
        assert np.diff(run.t) == pytest.approx(0.1, abs=1e-6)


def test_one_file_in_detail() -> None:
    run = read_openacc("short_setting_dynamic_part1.csv")
    assert run.date == "8.10.2019"
    assert run.vehicles == ("SMART_TARGET", "MERCEDES_GLE450", "JAGUAR_I_PACE", "BMW_I3", "TESLA_MODELX", "TESLA_MODEL3")
    assert run.t[0] == pytest.approx(0.2)
    assert run.speed[0, 0] == pytest.approx(11.127171558284447)
    assert np.isnan(run.speed[2, 0])  # an empty cell is a gap
    assert run.ivs[0, 0] == pytest.approx(15.469322726485007)
    assert run.missing() == {"Speed3": 2, "IVS2": 2, "IVS3": 2}


@pytest.mark.parametrize("name", OPENACC_FILES)
def test_real_amplification(name: str) -> None:
    assert real_amplification(read_openacc(name)).lead_to_last.speed_rms == pytest.approx(REAL_RATIO[name], abs=0.006)


def test_bad_files_say_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="cannot read"):
        read_openacc(tmp_path / "none.csv")
    good = read_openacc("short_setting_dynamic_part10.csv")
    src = Path(__file__).resolve().parents[2] / "energy" / "data" / "openacc" / good.name
    lines = src.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(["Dates,1", *lines[1:]]))
    with pytest.raises(DataError, match="metadata row 'Date'"):
        read_openacc(bad)
    bad.write_text("\n".join([*lines[:7], lines[7].replace(",", ",x", 1)]))
    with pytest.raises(DataError, match="not a number"):
        read_openacc(bad)
    bad.write_text("\n".join([*lines[:6], lines[8], lines[7]]))
    with pytest.raises(DataError, match="strictly increasing"):
        read_openacc(bad)
