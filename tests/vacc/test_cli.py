"""The `vacc` group's logging options: quiet by default, -v/--log-level for the client and its spawned servers."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from agent_client.launcher import Road

STATS = "vacc-server stats"  # the spawned server's counters at exit, logged at info


def _drive(tmp_path, *group_options: str, server_level: str | None = None) -> subprocess.CompletedProcess[str]:
    """`vacc [OPTIONS] drive` for 2 s against a spawned server, ``VACC_SERVER_LOG_LEVEL`` as given."""
    env = {k: v for k, v in os.environ.items() if k != "VACC_SERVER_LOG_LEVEL"}
    if server_level is not None:
        env["VACC_SERVER_LOG_LEVEL"] = server_level
    args = [*group_options, "drive", "--controller", "acc", "--duration", "2", "--log", str(tmp_path / "run.csv")]
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=120, env=env)


def test_a_spawned_server_is_quiet_by_default(tmp_path):
    result = _drive(tmp_path)
    assert result.returncode == 0, result.stderr
    assert STATS not in result.stderr and "vacc.client" not in result.stderr, result.stderr


@pytest.mark.parametrize("options", [["-v"], ["--log-level", "info"]])
def test_v_or_log_level_info_shows_the_servers_counters_and_the_clients_messages(tmp_path, options):
    result = _drive(tmp_path, *options)
    assert result.returncode == 0, result.stderr
    assert STATS in result.stderr and "vacc.client: simulator server pid" in result.stderr, result.stderr
    assert "starting a simulator server" not in result.stderr  # a debug message


def test_vv_shows_debug_messages(tmp_path):
    result = _drive(tmp_path, "-vv")
    assert result.returncode == 0, result.stderr
    assert "vacc.client: starting a simulator server: " in result.stderr and "--log-level debug" in result.stderr


def test_the_environment_variable_still_works_and_the_option_overrides_it(tmp_path):
    assert STATS in _drive(tmp_path, server_level="info").stderr
    overridden = _drive(tmp_path, "--log-level", "warning", server_level="info")
    assert overridden.returncode == 0 and STATS not in overridden.stderr, overridden.stderr


def test_a_bad_level_is_refused_in_one_line_naming_where_it_came_from(tmp_path):
    result = _drive(tmp_path, server_level="loud")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.strip() == "Error: VACC_SERVER_LOG_LEVEL='loud': not a log level (debug, info, warning, error)"
    result = _drive(tmp_path, "--log-level", "loud")
    assert result.returncode == 2 and "--log-level" in result.stderr


@pytest.mark.parametrize(
    ("options", "shown"),
    [([], True), (["--log-level", "error"], False), (["--log-level", "error", "serve", "--log-level", "info"], True)],
    ids=["serve's default: info", "the group's level", "serve's own option wins"],
)
def test_vacc_serve_in_process_follows_the_group_unless_given_its_own_level(options, shown):
    args = [*options] if "serve" in options else [*options, "serve"]
    result = subprocess.run([sys.executable, "-m", "vacc", *args, "--port", "0", "--max-seconds", "0.2"],
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert (STATS in result.stderr) is shown, result.stderr


def test_drive_traffic_goes_to_the_spawned_server_and_is_refused_with_server(tmp_path):
    result = _drive(tmp_path, "-vv")
    assert "--traffic 3" in result.stderr, result.stderr
    args = [sys.executable, "-m", "vacc", "drive", "--controller", "acc", "--duration", "1", "--log", str(tmp_path / "t.csv")]
    for n in ("-1", "11"):
        bad = subprocess.run([*args, "--traffic", n], capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and "--traffic" in bad.stderr and "0<=x<=10" in bad.stderr, bad.stderr
    bad = subprocess.run([*args, "--traffic", "5", "--server", "127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "vacc serve --traffic 5" in bad.stderr, bad.stderr
    assert not (tmp_path / "t.csv").exists()


def test_drive_sun_elevation_goes_to_the_spawned_server_and_is_refused_with_server(tmp_path):
    args = [sys.executable, "-m", "vacc", "drive", "--controller", "acc", "--duration", "1", "--log", str(tmp_path / "t.csv")]
    result = subprocess.run([sys.executable, "-m", "vacc", "-vv", *args[3:], "--sun-elevation", "0.4,0.5"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "--traffic 3 --sun-elevation 0.4,0.5" in result.stderr, result.stderr
    (tmp_path / "t.csv").unlink()
    bad = subprocess.run([*args, "--sun-elevation", "0.5,0.4"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "Invalid value for '--sun-elevation': must have 0.05 <= LOW <= HIGH <= 1.5 rad, got 0.5,0.4" in bad.stderr, bad.stderr
    bad = subprocess.run([*args, "--sun-elevation", "low", "--server", "127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "'low' is not LOW,HIGH in radians" in bad.stderr, bad.stderr
    bad = subprocess.run([*args, "--sun-elevation", "0.4,0.5", "--server", "127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "start the --server one with vacc serve --sun-elevation 0.4,0.5" in bad.stderr, bad.stderr
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize(("road", "note"), [(Road(), ""), (Road(0), ", 0 cars in each adjacent lane (default 3)"),
                                            (Road(3, (0.35, 0.5)), ", the sun 0.35-0.5 rad high (default 0.35-1.2)")])
def test_a_road_names_itself_and_its_server_options(road, note):
    assert road.note() == note
    assert road.server_args() == ("--traffic", str(road.traffic), "--sun-elevation", ",".join(map(str, road.sun_elevation)))
