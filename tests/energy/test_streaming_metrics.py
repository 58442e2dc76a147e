"""Scoring a run log segment by segment gives the figures of scoring it whole."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from energy_stream_logs import synthetic_log, varied_logs, write_csv

from energy import comfort, evaluate_run, read_run_log, runlog
from energy.metrics import comfort_metrics
from energy.segments import segments

FROZEN = Path(__file__).parent / "data" / "evaluate_run_frozen.json"
"""evaluate_run's figures of :func:`varied_logs` as scored before streaming (the whole log at
once), and the platform they were scored on; re-record (``python
tests/energy/test_streaming_metrics.py``) only for a deliberate change of a figure."""
CASES = [(veh, settle) for veh in ("corolla", "leaf") for settle in (0.0, 15.0)] + [("average", 15.0)]


def _score_all(tmp: Path, cases: list[tuple[str, float]] = CASES) -> dict[str, dict[str, object]]:
    out = {}
    for name, cols in varied_logs().items():
        path = write_csv(tmp / f"{name}.csv", cols)
        for veh, settle in cases:
            out[f"{name}/{veh}/settle{settle:g}"] = evaluate_run(path, veh, settle_s=settle)
    return out


def _platform() -> dict[str, str]:
    """What the figures' last bits depend on beyond the code: numpy's version and the SIMD
    code its float64 exp and power run (CMEM, the EV models; AVX-512 differs by an ulp)."""
    version = {"numpy": ".".join(np.__version__.split(".")[:2])}
    if not hasattr(np.lib, "introspect"):  # numpy < 2: not the frozen platform
        return version
    info = np.lib.introspect.opt_func_info(func_name="^(exp|power)$", signature="float64")
    return version | {f: next(iter(loops.values()))["current"] for f, loops in info.items()}


def _frozen() -> dict[str, dict[str, object]]:
    return json.loads(FROZEN.read_text())["figures"]


def _assert_close(got: dict[str, object], want: dict[str, object], case: str) -> None:
    """Every key alike: ints, strings and None exactly, floats to 1e-12 relative."""
    assert list(got) == list(want), case
    for key, value in got.items():
        w = want[key]
        assert isinstance(value, float) == isinstance(w, float), (case, key, value, w)
        if isinstance(value, float) and isinstance(w, float) and value != w:
            assert math.isclose(value, w, rel_tol=1e-12, abs_tol=0.0), (case, key, value, w)
        else:
            assert value == w, (case, key, value, w)


def test_a_one_segment_log_scores_exactly_as_before(tmp_path: Path) -> None:
    """To the bit on the platform the figures were frozen on; elsewhere to 1e-12."""
    frozen = json.loads(FROZEN.read_text())
    exact = frozen["platform"] == _platform()
    got = _score_all(tmp_path)
    assert got.keys() == frozen["figures"].keys()
    for case, metrics in got.items():
        want = frozen["figures"][case]
        if not exact:
            _assert_close(metrics, want, case)
            continue
        assert list(metrics) == list(want), case
        for key, value in metrics.items():
            assert isinstance(value, float) == isinstance(want[key], float), (case, key)  # an int stays an int
            assert value == want[key], (case, key, value, want[key])


@pytest.mark.parametrize(("rows", "cases"), [(7, CASES[1:3]), (64, CASES), (1000, CASES)])
def test_a_log_in_segments_scores_as_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rows: int, cases: list[tuple[str, float]]
) -> None:
    """Segments of 7 rows (0.14 s at 0.02 s: the 2-s windows reach over many), 64, 1000."""
    frozen = _frozen()
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", rows)
    for case, metrics in _score_all(tmp_path, cases).items():
        _assert_close(metrics, frozen[case], case)


@pytest.mark.parametrize("rows", [2, 13, 20, 39])
def test_a_last_segment_of_one_row_and_other_edges(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rows: int
) -> None:
    """40 rows: 13 and 39 leave a last segment of one row; 20, two equal ones."""
    path = write_csv(tmp_path / "short.csv", varied_logs()["short"])
    whole = {settle: evaluate_run(path, "leaf", settle_s=settle) for settle in (0.0, 1.0, 3.85)}
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", rows)
    for settle, want in whole.items():
        _assert_close(evaluate_run(path, "leaf", settle_s=settle), want, f"settle {settle}")


def test_an_in_memory_log_goes_through_the_same_segments(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_csv(tmp_path / "stops.csv", varied_logs()["stops_0.1s"])
    log = read_run_log(path)
    whole, brakes = evaluate_run(log, "corolla"), comfort_metrics(log)
    assert whole == evaluate_run(path, "corolla")
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", 50)
    _assert_close(evaluate_run(log, "corolla"), whole, "in memory")
    _assert_close(comfort_metrics(log), brakes, "comfort")
    assert brakes["unprompted_hard_brakes"] == comfort.unprompted_hard_brakes(log.t, log.accel, log.gap, log.v_host, log.v_lead) > 0


@pytest.mark.parametrize("rows", [1, 3, 40])
def test_segments_cover_the_log_once_with_their_context(rows: int) -> None:
    cols = synthetic_log(500, 0.02, 0.3, seed=5)
    log = runlog.RunLog("mem", **cols)  # type: ignore[arg-type]
    cores = []
    for seg in segments(log.chunks(17), rows, lambda t: t - 1.0, 2.0):
        t = seg.rows.t
        assert np.array_equal(t, log.t[seg.start : seg.start + t.size])
        assert 1 <= seg.c1 - seg.c0 <= rows
        cores.append(t[seg.c0 : seg.c1])
        if seg.start > 0:  # back past 1 s before the core, and the row before it
            assert t[0] < t[seg.c0] - 1.0 and seg.c0 >= 1
        assert seg.end or (t[-1] >= t[seg.c1 - 1] + 2.0 and seg.c1 < t.size)
        assert not seg.end or seg.start + t.size == log.t.size
    assert np.array_equal(np.concatenate(cores), log.t)


def _long_log(path: Path, n: int) -> Path:
    """``n`` rows at 0.1 s of a host swaying around 20 m/s, written at once."""
    i = np.arange(n)
    t = i * 0.1
    v = 20.0 + 3.0 * np.sin(i * 0.01)
    a = np.gradient(v, t)
    cols = [t, i, v, v + 0.5, 40.0 + 5.0 * np.cos(i * 0.003), a, np.clip(a / 3.0, -1.0, 1.0), 0 * i]
    with path.open("w") as f:
        f.write("t,frame,v_host,v_lead,gap,accel,force,collision\n")
        np.savetxt(f, np.column_stack(cols), fmt="%.6f", delimiter=",")
    return path


@pytest.mark.parametrize("vehicle", ["corolla", "leaf"])
def test_a_long_log_is_scored_in_bounded_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, vehicle: str) -> None:
    """Streaming: what grows with the rows is the dt, headway and weight kept to the end
    (24 B a row; 48 while they grow and at the end, with the percentiles' order and
    cumulative weights), not the columns and CMEM's [rows, gears] arrays of a whole log
    (over 280 B a row). Small segments, so that a short log (tracing is slow) has many."""
    import tracemalloc

    n = 30_000
    path = _long_log(tmp_path / "long.csv", n)
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", 1024)
    tracemalloc.start()
    try:
        m = evaluate_run(path, vehicle)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert m["rows"] == n
    assert peak < 1_000_000 + 64 * n, peak  # [bytes] a whole-log scoring took ~12 MB here


if __name__ == "__main__":  # re-record the frozen figures
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        FROZEN.write_text(json.dumps({"platform": _platform(), "figures": _score_all(Path(d))}, indent=1) + "\n")
