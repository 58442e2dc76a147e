"""`vacc drive` with lead scenarios, custom traces, --host-speed, --gap and --set-speed."""

from __future__ import annotations

import csv

import pytest
from click.testing import CliRunner

from agent_client.cli import drive
from protocol.scenarios import LEAD_SCENARIOS


def _run(*args: str):
    return CliRunner().invoke(drive, list(args), catch_exceptions=False)


def _rows(path) -> list[dict[str, float]]:
    with open(path, newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


@pytest.mark.parametrize("name", list(LEAD_SCENARIOS))
def test_every_lead_scenario_drives_from_the_cli(tmp_path, name):
    log = tmp_path / "run.csv"
    result = _run("--controller", "acc", "--scenario", "ice", "--trajectory", name, "--seed", "1", "--duration", "3", "--log", str(log))
    assert result.exit_code == 0, result.output
    assert f"acc on ice/{name} (seed 1)" in result.output
    assert len(_rows(log)) == 31


def test_same_seed_same_log_and_options_reach_the_world(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    args = ["--controller", "acc", "--trajectory", "stop-and-go", "--seed", "4", "--duration", "5", "--quiet"]
    assert _run(*args, "--log", str(a)).exit_code == 0
    assert _run(*args, "--log", str(b)).exit_code == 0
    assert a.read_bytes() == b.read_bytes()
    c = tmp_path / "c.csv"
    result = _run(*args, "--host-speed", "3.5", "--gap", "12", "--set-speed", "10", "--log", str(c))
    assert result.exit_code == 0, result.output
    rows = _rows(c)
    assert rows[0]["v_host"] == 3.5 and rows[0]["gap"] == pytest.approx(12.0)
    assert max(r["v_host"] for r in rows) <= 10.0


def test_csv_lead_is_driven_as_given(tmp_path):
    # A 0-27 m/s cycle on the ICE car, whose Table 2 band is 27-33 m/s.
    trace = tmp_path / "cycle.csv"
    trace.write_text("t_s,speed_mps\n0,0\n10,15\n20,27\n30,27\n40,5\n")
    log = tmp_path / "t.csv"
    result = _run("--controller", "acc", "--scenario", "ice", "--trajectory", str(trace), "--gap", "20", "--log", str(log), "--quiet")
    assert result.exit_code == 0, result.output
    rows = _rows(log)
    assert rows[0]["v_lead"] == 0.0 and rows[0]["v_host"] == 0.0  # the host starts at the lead's speed
    assert rows[0]["gap"] == pytest.approx(20.0)
    assert max(r["v_lead"] for r in rows) == pytest.approx(27.0)
    assert rows[-1]["v_lead"] == pytest.approx(5.0) and not any(r["collision"] for r in rows)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--host-speed", "40"], "Invalid value for --host-speed: host speed 40.0 m/s is outside 0..33.5 m/s (the set speed)"),
        (["--host-speed", "20", "--set-speed", "15"], "host speed 20.0 m/s is outside 0..15 m/s"),
        (["--gap", "-3"], "Invalid value for --gap: gap -3.0 m is outside (0, 300) m"),
        (["--gap", "nan"], "gap nan m is outside"),
        (["--set-speed", "0"], "Invalid value for --set-speed: set speed 0.0 m/s is outside 1..80 m/s"),
        (["--trajectory", "parked"], "unknown trajectory 'parked'; expected one of test-1, test-2, test-3, test-4, random, stopped,"),
        (["--trajectory", "test-5"], "unknown trajectory 'test-5'; expected one of test-1, test-2, test-3, test-4, random, stopped,"),
        # a missing file lists the names too, not only "No such file or directory"
        (["--trajectory", "no-such-dir/lead.csv"], "no such trace file 'no-such-dir/lead.csv'; expected one of test-1, test-2, test-3, test-4, random,"),
    ],
)
def test_bad_values_are_one_line_errors(tmp_path, args, words):
    result = _run("--controller", "acc", "--log", str(tmp_path / "x.csv"), *args)
    assert result.exit_code == 2
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and words in errors[0], result.output
    assert not (tmp_path / "x.csv").exists()  # refused before any server was spawned


def test_csv_a_car_cannot_drive_is_refused(tmp_path):
    trace = tmp_path / "jump.csv"
    trace.write_text("t_s,speed_mps\n0,30\n1,10\n")
    result = _run("--controller", "acc", "--trajectory", str(trace), "--log", str(tmp_path / "x.csv"))
    assert result.exit_code != 0
    assert "trace samples 0-1 accelerate at -20 m/s^2, beyond the physical limit of +-9.81 m/s^2 (1 g)" in result.output
    assert "Traceback" not in result.output


def test_csv_over_the_trace_limits_is_refused_before_any_server(tmp_path):
    from protocol.scenarios import TRACE_MAX_SAMPLES

    long = tmp_path / "long.csv"
    long.write_text("t_s,speed_mps\n0,10\n1e12,10\n")
    result = _run("--controller", "acc", "--trajectory", str(long), "--log", str(tmp_path / "x.csv"))
    assert result.exit_code != 0 and "a trace spans at most 14400 s (4 h); this one spans 1e+12 s" in result.output
    many = tmp_path / "many.csv"
    with many.open("w") as f:  # one sample over the limit, and far more rows after it
        f.write("t_s,speed_mps\n" + "".join(f"{i * 0.01},10\n" for i in range(TRACE_MAX_SAMPLES + 1000)))
    result = _run("--controller", "acc", "--trajectory", str(many), "--log", str(tmp_path / "x.csv"))
    assert result.exit_code != 0 and f"many.csv:{TRACE_MAX_SAMPLES + 2}: a trace holds at most {TRACE_MAX_SAMPLES} samples" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "x.csv").exists()


def test_csv_encodings_bom_read_utf16_refused_in_one_line(tmp_path):
    from agent_client.errors import InputFileError
    from agent_client.traces import load_trace

    bom = tmp_path / "bom.csv"
    bom.write_text("t_s,speed_mps\n0,10\n10,12\n", encoding="utf-8-sig")
    t, v = load_trace(bom)
    assert list(t) == [0.0, 10.0] and list(v) == [10.0, 12.0]
    wide = tmp_path / "wide.csv"
    wide.write_text("t_s,speed_mps\n0,10\n10,12\n", encoding="utf-16")
    with pytest.raises(InputFileError, match="wide.csv") as info:
        load_trace(wide)
    assert "\n" not in str(info.value)
    huge = tmp_path / "huge.csv"
    huge.write_text("t_s,speed_mps\n0," + "1" * (200 * 1024) + "\n")
    with pytest.raises(InputFileError, match="huge.csv") as info:
        load_trace(huge)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("model", "scenario"), [("ev-gap", "ice"), ("ice-gap", "ev")])
def test_a_checkpoint_of_the_other_scenario_is_refused_in_one_line(tmp_path, model, scenario):
    from click.testing import CliRunner

    from vacc.cli import main
    from vacc.paths import models_dir

    log = tmp_path / "run.csv"
    result = CliRunner().invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(models_dir() / f"{model}.pt"), "--scenario", scenario, "--log", str(log)])
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit)
    [line] = [ln for ln in result.stderr.splitlines() if ln.strip()]
    trained = model.split("-")[0]
    assert f"trained for the {trained} scenario, not --scenario {scenario}" in line
    assert list(tmp_path.iterdir()) == []  # refused before a server or a log
