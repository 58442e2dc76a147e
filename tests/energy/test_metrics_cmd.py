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


def _strict_json(text: str) -> dict[str, object]:
    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)  # NaN, Infinity are not JSON


def test_json_has_the_comfort_figures_and_the_settle(write_log: Callable[..., Path]) -> None:
    rows = make_log_rows(n=301)  # 30 s
    for r in rows[:150]:  # ±2 m/s² flips every 0.5 s in the first 15 s
        r["accel"] = 2.0 if (r["frame"] // 5) % 2 == 0 else -2.0  # type: ignore[operator]
    path = write_log(rows)
    runner = CliRunner()
    settled = _strict_json(runner.invoke(metrics, [str(path), "--json"]).output)
    assert settled["settle_s"] == 15.0
    assert settled["jerk_rms_mps3"] == 0.0 and settled["accel_sign_changes_per_min"] == 0.0
    whole = _strict_json(runner.invoke(metrics, [str(path), "--json", "--settle", "0"]).output)
    assert whole["accel_sign_changes_per_min"] == pytest.approx(29 / 0.5)
    assert whole["iso_jerk_window_share"] == pytest.approx(0.0)  # a(t + 1 s) = a(t)
    for key in ("speed_max_mps", "gap_min_m", "headway_min_s", "gap_rmse_55m_m"):
        assert whole[key] == settled[key]
    table = runner.invoke(metrics, [str(path), "--settle", "0"]).output
    assert "iso_jerk_window_share" in table and "accel_sign_changes_per_min" in table


def test_json_writes_null_for_an_overflow(write_log: Callable[..., Path]) -> None:
    path = write_log(make_log_rows())
    res = CliRunner().invoke(metrics, [str(path), "--json", "--time-gap", "1e308"])
    assert res.exit_code == 0, res.output
    assert _strict_json(res.output)["gap_rmse_time_gap_m"] is None  # v t_gap overflows
    res = CliRunner().invoke(metrics, [str(path), "--json", "--settle", "100"])
    assert _strict_json(res.output)["jerk_rms_mps3"] is None  # nothing left after 100 s


@pytest.mark.parametrize("option", ["--time-gap", "--d-safe", "--settle"])
@pytest.mark.parametrize("value", ["-1", "nan", "inf", "-inf"])
def test_bad_options_are_one_line_errors(
    write_log: Callable[..., Path], option: str, value: str
) -> None:
    path = write_log(make_log_rows())
    res = CliRunner().invoke(metrics, [str(path), "--json", option, value])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit)
    assert f"Invalid value for '{option}': must be a finite number >= 0, got" in res.output
    assert "{" not in res.output  # no JSON printed


def _with_card(path: Path, scenario: str) -> None:
    from agent_client.runlog import write_card

    write_card(path, {"episode": {"scenario": scenario, "trajectory": "test-1", "seed": 0}})


def test_the_vehicle_comes_from_the_cards_scenario_and_vehicle_overrides_it(write_log: Callable[..., Path]) -> None:
    path = write_log(make_log_rows(v=20.0, gap=50.0))
    runner = CliRunner()
    assert json.loads(runner.invoke(metrics, [str(path), "--json"]).output)["vehicle"] == "corolla"  # no card: as before
    _with_card(path, "ev")
    ev = runner.invoke(metrics, [str(path), "--json"])
    assert ev.exit_code == 0 and json.loads(ev.stdout)["vehicle"] == "leaf" and "energy_kj_per_mi" in json.loads(ev.stdout)
    forced = runner.invoke(metrics, [str(path), "--json", "--vehicle", "corolla"])
    assert json.loads(forced.stdout)["vehicle"] == "corolla"  # the option overrides...
    [note] = [ln for ln in forced.stderr.splitlines() if ln.strip()]  # ...and says so, in one line
    assert "--vehicle corolla" in note and "ev scenario" in note and "leaf" in note
    _with_card(path, "ice")
    assert json.loads(runner.invoke(metrics, [str(path), "--json"]).stdout)["vehicle"] == "corolla"
    same = runner.invoke(metrics, [str(path), "--json", "--vehicle", "average"])  # another ICE model: no mismatch
    assert json.loads(same.stdout)["vehicle"] == "average" and same.stderr == ""


def test_a_field_over_the_csv_limit_is_one_line_not_a_traceback(tmp_path: Path) -> None:
    import csv

    path = tmp_path / "run.csv"
    rows = [f"{i * 0.1:.1f},{i},20,20,50,0,0,0," for i in range(5)]
    rows[3] += "y" * (csv.field_size_limit() + 1)
    path.write_text(",".join(COLUMNS) + ",note\n" + "\n".join(rows) + "\n")
    result = CliRunner().invoke(metrics, [str(path)])
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit)
    assert [ln for ln in result.output.splitlines() if ln.strip()] == [
        f"Error: {path}, row 4 (line 5): not a CSV row (field larger than field limit ({csv.field_size_limit()}))"
    ]
