"""``vacc metrics`` through click's test runner."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner
from energy_log_rows import COLUMNS, make_log_rows

from vacc.metrics_cmd import metrics


def test_table_and_json(write_log: Callable[..., Path]) -> None:
    path = write_log(make_log_rows(v=20.0, gap=50.0))
    runner = CliRunner()
    table = runner.invoke(metrics, [str(path), "--vehicle", "corolla"])
    assert table.exit_code == 0, table.output
    assert "gap_rmse_55m_m" in table.output and "co2_g_per_mi" in table.output
    out = runner.invoke(metrics, [str(path), "--vehicle", "leaf", "--json"])
    assert out.exit_code == 0, out.output
    data = json.loads(out.output)
    assert data["gap_rmse_55m_m"] == pytest.approx(5.0)
    assert data["vehicle"] == "leaf" and data["energy_kj_per_mi"] > 0.0
    assert data["ttc_min_s"] is None


def test_registered_in_the_vacc_group() -> None:
    import click

    from vacc.cli import main
    from vacc.metrics_cmd import metrics

    ctx = click.Context(main)
    assert "metrics" in main.list_commands(ctx)
    assert main.get_command(ctx, "metrics") is metrics


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda r: r[3].update(v_host="nan"), "row 4 (line 5): column 'v_host' is nan"),
        (lambda r: r[3].update(v_lead=-1), "row 4 (line 5): negative speed"),
        (lambda r: r[5].update(t=0), "row 6 (line 7): time not strictly increasing"),
        (lambda r: [x.update(v_host=0.0) for x in r], "zero distance travelled"),
    ],
)
def test_bad_input_is_a_clean_error(write_log: Callable[..., Path], mutate, message: str) -> None:  # type: ignore[no-untyped-def]
    rows = make_log_rows()
    mutate(rows)
    path = write_log(rows, name="bad.csv")
    res = CliRunner().invoke(metrics, [str(path)])
    assert res.exit_code != 0
    assert isinstance(res.exception, SystemExit)  # no traceback
    assert f"bad.csv, {message}" in res.output or (
        message in res.output and "bad.csv" in res.output
    )


def test_missing_column_and_missing_file(write_log: Callable[..., Path], tmp_path: Path) -> None:
    path = write_log(make_log_rows(), columns=[c for c in COLUMNS if c != "collision"])
    res = CliRunner().invoke(metrics, [str(path)])
    assert res.exit_code != 0 and "missing column(s) collision" in res.output
    res = CliRunner().invoke(metrics, [str(tmp_path / "none.csv"), "--json"])
    assert res.exit_code != 0 and "none.csv: file not found" in res.output
    assert isinstance(res.exception, SystemExit)
