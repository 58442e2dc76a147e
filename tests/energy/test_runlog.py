"""Every bad-input error of the run-log reader names the file, the row and the problem."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from energy_log_rows import COLUMNS, make_log_rows

from energy import EnergyError, RunLogError, read_run_log, runlog
from energy.runlog import iter_run_log


def test_reads_a_good_log_with_extra_columns(write_log: Callable[..., Path]) -> None:
    rows = make_log_rows(n=11, dt=0.02)
    for r in rows:
        r["reward"] = 0.5
    log = read_run_log(write_log(rows, columns=[*COLUMNS, "reward"]))
    assert log.t.size == 11 and log.distance_m == pytest.approx(20.0 * 0.2)


def _bad(
    rows: list[dict[str, object]], row: int, key: str, value: object
) -> list[dict[str, object]]:
    rows[row - 1][key] = value
    return rows


# (a mutation of make_log_rows, the message it must raise)
BAD_ROWS = [
    (lambda r: _bad(r, 3, "v_host", "nan"), r"row 3 \(line 4\): column 'v_host' is nan"),
    (lambda r: _bad(r, 3, "gap", "inf"), r"row 3 \(line 4\): column 'gap' is inf"),
    (lambda r: _bad(r, 4, "accel", "abc"), r"row 4 \(line 5\): column 'accel' is not a number"),
    (lambda r: _bad(r, 2, "force", ""), r"row 2 \(line 3\): column 'force' is empty"),
    (
        lambda r: _bad(r, 5, "v_host", -0.1),
        r"row 5 \(line 6\): negative speed in column 'v_host'",
    ),
    (
        lambda r: _bad(r, 5, "v_lead", -3),
        r"row 5 \(line 6\): negative speed in column 'v_lead'",
    ),
    (lambda r: _bad(r, 6, "t", 0.1), r"row 6 \(line 7\): time not strictly increasing"),
    (lambda r: _bad(r, 3, "t", r[1]["t"]), r"row 3 \(line 4\): time not strictly increasing"),
    (lambda r: _bad(r, 2, "force", 1.5), r"row 2 \(line 3\): force 1.5 outside \[-1, 1\]"),
    (lambda r: _bad(r, 2, "collision", 2), r"row 2 \(line 3\): collision must be 0 or 1"),
    (lambda r: _bad(r, 2, "frame", 1.5), r"row 2 \(line 3\): frame must be an integer"),
    (
        lambda r: _bad(r, 7, "gap", -1.0),
        r"row 7 \(line 8\): negative gap -1.0 m without a collision",
    ),
]


@pytest.mark.parametrize(("mutate", "match"), BAD_ROWS)
def test_bad_value_names_file_row_and_problem(
    write_log: Callable[..., Path],
    mutate: Callable[[list[dict[str, object]]], list[dict[str, object]]],
    match: str,
) -> None:
    path = write_log(mutate(make_log_rows()), name="bad_run.csv")
    with pytest.raises(RunLogError, match=r"bad_run\.csv, " + match) as e:
        read_run_log(path)
    assert isinstance(e.value, ValueError) and isinstance(e.value, EnergyError)
    assert e.value.path == str(path) and e.value.row is not None


def test_negative_gap_allowed_on_collision_row(write_log: Callable[..., Path]) -> None:
    rows = make_log_rows()
    rows[-1].update(gap=-0.2, collision=1)
    assert read_run_log(write_log(rows)).collision[-1] == 1


def test_missing_column(write_log: Callable[..., Path]) -> None:
    path = write_log(make_log_rows(), columns=[c for c in COLUMNS if c != "gap"])
    with pytest.raises(RunLogError, match=r"run\.csv: missing column\(s\) gap"):
        read_run_log(path)


def test_short_row(tmp_path: Path) -> None:
    p = tmp_path / "short.csv"
    p.write_text(",".join(COLUMNS) + "\n0,0,1,1,50,0,0,0\n0.1,1,1,1\n")
    with pytest.raises(RunLogError, match=r"short\.csv, row 2 \(line 3\): column 'gap' is empty"):
        read_run_log(p)


def test_zero_distance(write_log: Callable[..., Path]) -> None:
    with pytest.raises(
        RunLogError, match=r"run\.csv: zero distance travelled \(v_host is 0 on all 51 rows\)"
    ):
        read_run_log(write_log(make_log_rows(v=0.0)))


def test_too_few_rows(write_log: Callable[..., Path]) -> None:
    with pytest.raises(RunLogError, match="need at least 2 data rows, got 1"):
        read_run_log(write_log(make_log_rows(n=1)))


def test_missing_and_empty_file(tmp_path: Path) -> None:
    with pytest.raises(RunLogError, match=r"nope\.csv: file not found"):
        read_run_log(tmp_path / "nope.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(RunLogError, match=r"empty\.csv: empty file"):
        read_run_log(tmp_path / "empty.csv")


@pytest.mark.parametrize("text", ["1_0", "0x10", "1e1_0", "١٠"])
def test_a_number_in_another_spelling_than_digits_is_refused_with_its_row(write_log: Callable[..., Path], text: str) -> None:
    path = write_log(_bad(make_log_rows(n=5), 3, "frame", text))
    with pytest.raises(RunLogError, match=r"row 3 \(line 4\): column 'frame' is not a number"):
        read_run_log(path)


def test_a_repeated_column_name_is_refused_with_the_header_line(tmp_path: Path) -> None:
    path = tmp_path / "dup.csv"
    rows = [f"{i * 0.1:.1f},{i},20,20,50,0,0,0,45" for i in range(3)]
    path.write_text("t,frame,v_host,v_lead,gap,accel,force,collision,gap\n" + "\n".join(rows) + "\n")
    with pytest.raises(RunLogError, match=r"dup.csv: line 1: column\(s\) gap named twice"):
        read_run_log(path)


def test_a_field_over_the_csv_limit_is_one_line_with_its_row(tmp_path: Path) -> None:
    import csv

    path = tmp_path / "big.csv"
    rows = [f"{i * 0.1:.1f},{i},20,20,50,0,0,0" for i in range(4)]
    rows[2] += ',"' + "x" * (csv.field_size_limit() + 10) + '"'
    path.write_text(",".join(COLUMNS) + ",note\n" + "\n".join(rows) + "\n")
    with pytest.raises(RunLogError, match=r"big.csv, row 3 \(line 4\): not a CSV row \(field larger than field limit") as info:
        read_run_log(path)
    assert "\n" not in str(info.value)


def test_a_long_log_is_read_in_bounded_memory(tmp_path: Path) -> None:
    """Streaming: the columns grow by 64 bytes a row; the text is never held whole."""
    import tracemalloc

    n = 50_000
    path = tmp_path / "long.csv"
    with path.open("w") as f:
        f.write(",".join(COLUMNS) + ",note\n")
        f.writelines(f"{i * 0.1:.1f},{i},20.0,20.0,50.0,0.0,0.0,0,{'n' * 40}\n" for i in range(n))
    tracemalloc.start()
    try:
        log = read_run_log(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert log.t.size == n
    assert peak < 100 * n, peak  # [bytes] 8 float64 columns = 64 a row; the rows as text held ~1 kB a row


@pytest.mark.parametrize(("mutate", "match"), BAD_ROWS[:2] + BAD_ROWS[5:8] + BAD_ROWS[-1:])
@pytest.mark.parametrize("rows", [1, 2, 5])
def test_chunked_reading_names_the_same_row(
    write_log: Callable[..., Path], monkeypatch: pytest.MonkeyPatch, rows: int,
    mutate: Callable[[list[dict[str, object]]], list[dict[str, object]]], match: str,
) -> None:
    """Chunks of 1, 2 or 5 rows: the row before a chunk's first is still checked against."""
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", rows)
    with pytest.raises(RunLogError, match=r"bad_run\.csv, " + match):
        read_run_log(write_log(mutate(make_log_rows()), name="bad_run.csv"))


@pytest.mark.parametrize(("mutate", "match"), BAD_ROWS)
def test_the_row_by_row_reading_names_the_same_row(
    write_log: Callable[..., Path], monkeypatch: pytest.MonkeyPatch,
    mutate: Callable[[list[dict[str, object]]], list[dict[str, object]]], match: str,
) -> None:
    """A row the fast path does not take is read field by field: the same messages."""
    monkeypatch.setattr(runlog, "_FAST_ROW", re.compile(r"(?!)"))
    with pytest.raises(RunLogError, match=r"bad_run\.csv, " + match):
        read_run_log(write_log(mutate(make_log_rows()), name="bad_run.csv"))


def test_a_bad_value_before_an_unreadable_row_is_named_first(tmp_path: Path) -> None:
    """The fast path checks a chunk's values after reading it: an earlier row still comes first."""
    path = tmp_path / "two.csv"
    rows = [f"{i * 0.1:.1f},{i},20,20,50,0,0,0" for i in range(6)]
    rows[2] = "0.2,2,20,20,50,0,3.0,0"  # force 3: row 3
    rows[4] = "0.4,4,20,20,abc,0,0,0"  # not a number: row 5
    path.write_text(",".join(COLUMNS) + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(RunLogError, match=r"row 3 \(line 4\): force 3.0 outside"):
        read_run_log(path)


def test_iter_run_log_gives_the_log_in_chunks(write_log: Callable[..., Path], monkeypatch: pytest.MonkeyPatch) -> None:
    rows = make_log_rows(n=23)
    rows[5].update(gap=-0.5, collision=1)
    path = write_log(rows)
    whole = read_run_log(path)
    chunks = list(iter_run_log(path, rows=5))
    assert [c.t.size for c in chunks] == [5, 5, 5, 5, 3]
    monkeypatch.setattr(runlog, "SEGMENT_ROWS", 5)
    joined = read_run_log(path)  # read in chunks too
    for c in COLUMNS:
        assert np.array_equal(np.concatenate([getattr(k, c) for k in chunks]), getattr(whole, c)), c
        assert np.array_equal(getattr(joined, c), getattr(whole, c)), c


def test_the_whole_file_checks_come_after_the_last_chunk(write_log: Callable[..., Path]) -> None:
    seen = []
    with pytest.raises(RunLogError, match="zero distance travelled"):
        for chunk in iter_run_log(write_log(make_log_rows(n=12, v=0.0)), rows=5):
            seen.append(chunk.t.size)
    assert seen == [5, 5, 2]


def test_one_moving_interval_across_a_chunk_edge_is_a_distance(write_log: Callable[..., Path]) -> None:
    rows = make_log_rows(n=6, v=0.0)
    rows[5]["v_host"] = 1.0  # only the interval 4-5 moves; row 5 is the second chunk
    assert [c.t.size for c in iter_run_log(write_log(rows), rows=5)] == [5, 1]
