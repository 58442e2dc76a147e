"""Human-files: format, every bad-file case, padding, and byte-identical replay."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from agent_client.cli import drive
from agent_client.controllers.human_file import (
    MAGIC,
    HumanFileController,
    HumanFileHeader,
    HumanFileRecorder,
    read_human_file,
)
from agent_client.errors import InputFileError
from protocol.messages import PROTOCOL_VERSION

# protocol=1: a recording from before protocol 2 still replays (only fields were added).
HEADER = "# scenario=ice trajectory=test-1 seed=0 control_period=0.1 protocol=1 duration=1.0"


def _file(tmp_path: Path, body: str, name: str = "h.csv") -> Path:
    path = tmp_path / name
    path.write_text(body, encoding="ascii")
    return path


def _good(rows: int = 10) -> str:
    return "\n".join([MAGIC, HEADER, "# controller=keyboard", "frame,force", *(f"{i},{0.1 * (i % 3)!r}" for i in range(rows))]) + "\n"


def test_round_trip_through_the_recorder(tmp_path):
    header = HumanFileHeader("ev", "my trace.csv", 7, 0.1, duration=None)
    forces = [0.0, 0.1, -0.30000000000000004, 1.0, -1.0]
    with HumanFileRecorder(tmp_path / "r.csv", header, ("controller=keyboard",)) as rec:
        for i, u in enumerate(forces):
            rec.write(i, u)
    hf = read_human_file(tmp_path / "r.csv")
    assert hf.header.scenario == "ev" and hf.header.trajectory == "my trace.csv" and hf.header.seed == 7
    assert hf.header.control_period == 0.1 and hf.header.duration is None and hf.header.protocol == PROTOCOL_VERSION
    assert list(hf.forces) == forces  # exact: written with repr
    text = (tmp_path / "r.csv").read_text()
    assert text.startswith(MAGIC + f"\n# scenario=ev trajectory=my%20trace.csv seed=7 control_period=0.1 protocol={PROTOCOL_VERSION}")
    assert "\nframe,force\n0,0.0\n" in text


def test_good_file_parses(tmp_path):
    hf = read_human_file(_file(tmp_path, _good()))
    assert len(hf.forces) == 10 and hf.header.duration == 1.0
    hf.check(scenario="ice", trajectory="test-1", seed=0, control_period=0.1)


BAD = {
    "empty": ("", 1, "missing header"),
    "no magic": ("frame,force\n0,0.0\n", 1, "missing header"),
    "wrong version": ("# vacc-human-file v9\n" + HEADER + "\nframe,force\n0,0\n", 1, "missing header"),
    "no header line": (MAGIC + "\nframe,force\n0,0.0\n", 2, "missing header line"),
    "header lacks keys": (MAGIC + "\n# scenario=ice seed=0\nframe,force\n0,0\n", 2, "lacks trajectory, control_period, protocol"),
    "bad header value": (MAGIC + "\n" + HEADER.replace("seed=0", "seed=x") + "\nframe,force\n0,0\n", 2, "bad header value"),
    "no column row": (MAGIC + "\n" + HEADER + "\n0,0.0\n", 3, "column row"),
    "no rows": (MAGIC + "\n" + HEADER + "\nframe,force\n", 3, "no rows"),
    "force above 1": (MAGIC + "\n" + HEADER + "\nframe,force\n0,0.5\n1,1.5\n", 5, "not a number in [-1, 1]"),
    "force below -1": (MAGIC + "\n" + HEADER + "\nframe,force\n0,-1.01\n", 4, "not a number in [-1, 1]"),
    "nan": (MAGIC + "\n" + HEADER + "\nframe,force\n0,0.0\n1,nan\n", 5, "not a number"),
    "inf": (MAGIC + "\n" + HEADER + "\nframe,force\n0,inf\n", 4, "not a number"),
    "missing frame": (MAGIC + "\n" + HEADER + "\nframe,force\n0,0.0\n1,0.0\n3,0.0\n", 6, "frame 2 is missing"),
    "duplicate frame": (MAGIC + "\n" + HEADER + "\nframe,force\n0,0.0\n1,0.0\n1,0.1\n", 6, "duplicate frame 1 (first on line 5)"),
    "first frame not 0": (MAGIC + "\n" + HEADER + "\nframe,force\n1,0.0\n", 4, "frame 0 is missing"),
    "garbage row": (MAGIC + "\n" + HEADER + "\nframe,force\n0,0.0\nhello\n", 5, "expected 'frame,force'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_name_file_and_line(tmp_path, case):
    body, line, words = BAD[case]
    path = _file(tmp_path, body)
    with pytest.raises(InputFileError) as err:
        read_human_file(path)
    assert str(path) in str(err.value)
    assert f"line {line}:" in str(err.value)
    assert words in str(err.value)


@pytest.mark.parametrize(
    ("request_", "words"),
    [
        ({"scenario": "ev"}, "scenario=ice, but --scenario ev"),
        ({"trajectory": "test-2"}, "trajectory=test-1, but --trajectory test-2"),
        ({"seed": 3}, "seed=0, but --seed 3"),
        ({"control_period": 0.2}, "control_period=0.1 s, the server steps 0.2 s"),
        ({"set_speed": 30.0}, "set_speed=33.5, but --set-speed 30.0"),
        ({"host_speed": 5.0}, "host_speed=none .drawn., but --host-speed 5.0"),
        ({"gap": 40.0}, "gap=none .drawn., but --gap 40.0"),
    ],
)
def test_header_must_match_the_request(tmp_path, request_, words):
    path = _file(tmp_path, _good())
    kwargs = {"scenario": "ice", "trajectory": "test-1", "seed": 0, "control_period": 0.1, **request_}
    with pytest.raises(InputFileError, match="line 2: .*" + words.replace("[", r"\[").replace("]", r"\]")) as err:
        read_human_file(path).check(**kwargs)
    assert str(path) in str(err.value)


def test_pad_modes_past_the_end(tmp_path):
    hf = read_human_file(_file(tmp_path, _good(3)))  # forces 0.0, 0.1, 0.2
    obs = {"frame": 5, "t": 0.5}
    with pytest.raises(InputFileError, match=r"line 7: the file ends at frame 2, before the trajectory"):
        HumanFileController(hf)(obs)
    assert HumanFileController(hf, "hold")(obs) == 0.2
    assert HumanFileController(hf, "zero")(obs) == 0.0
    assert HumanFileController(hf)({"frame": 1, "t": 0.1}) == 0.1


# -- through the CLI and a real server ------------------------------------------------


def _run(*args: str):
    return CliRunner().invoke(drive, list(args), catch_exceptions=False)


def test_cli_bad_file_is_a_clean_error(tmp_path):
    path = _file(tmp_path, BAD["nan"][0])
    result = _run("--controller", "human-file", "--human-file", str(path), "--log", str(tmp_path / "log.csv"))
    assert result.exit_code != 0
    assert "Traceback" not in result.output
    assert str(path) in result.output and "line 5" in result.output


def test_cli_header_mismatch_and_missing_option(tmp_path):
    path = _file(tmp_path, _good())
    result = _run("--controller", "human-file", "--human-file", str(path), "--scenario", "ev", "--log", str(tmp_path / "l.csv"))
    assert result.exit_code != 0 and "--scenario ev" in result.output and "line 2" in result.output
    result = _run("--controller", "human-file", "--log", str(tmp_path / "l.csv"))
    assert result.exit_code != 0 and "needs --human-file" in result.output


def test_cli_replay_of_a_recording_is_byte_identical_and_pads(tmp_path):
    live, human, again = tmp_path / "live.csv", tmp_path / "human.csv", tmp_path / "again.csv"
    result = _run("--controller", "hdm", "--duration", "20", "--log", str(live), "--record", str(human), "--quiet")
    assert result.exit_code == 0, result.output
    header = f"\n# scenario=ice trajectory=test-1 seed=0 control_period=0.1 protocol={PROTOCOL_VERSION} duration=20.0 set_speed=33.5 traffic=3 sun_elevation=0.35,1.2\n"
    assert human.read_text().startswith(MAGIC + header)
    # The replay takes its duration from the header.
    result = _run("--controller", "human-file", "--human-file", str(human), "--log", str(again), "--quiet")
    assert result.exit_code == 0, result.output
    assert again.read_bytes() == live.read_bytes()

    # Driven further than recorded: an error naming the file's last line, unless padded.
    last_line = len(human.read_text().splitlines())
    result = _run("--controller", "human-file", "--human-file", str(human), "--duration", "21", "--log", str(again))
    assert result.exit_code != 0 and f"line {last_line}" in result.output and "--pad" in result.output
    assert len(again.read_text().splitlines()) == 1 + 201  # the log keeps frames 0..200
    result = _run("--controller", "human-file", "--human-file", str(human), "--duration", "21", "--pad", "hold", "--log", str(again), "--quiet")
    assert result.exit_code == 0, result.output
    rows = again.read_text().splitlines()
    assert len(rows) == 1 + 211 and rows[-1].split(",")[6] == rows[-11].split(",")[6]  # force held


def test_a_protocol_2_recording_still_replays(tmp_path):
    """Protocol 3 only added welcome.seed_salt: recordings made under protocol 2 replay the same."""
    body = _good().replace("protocol=1", "protocol=2")
    assert read_human_file(_file(tmp_path, body)).header.protocol == 2


@pytest.mark.parametrize(
    ("header_change", "line", "words"),
    [
        (("protocol=1", "protocol=99"), 2, "protocol=99"),
        (("protocol=1", "protocol=0"), 2, "protocol=0"),
        (("duration=1.0", "duration=1e308"), 2, "duration"),
        (("duration=1.0", "duration=inf"), 2, "duration"),
        (("duration=1.0", "duration=nan"), 2, "duration"),
        (("seed=0", "seed=0_0"), 2, "'0_0'"),
        (("control_period=0.1", "control_period=0_1"), 2, "'0_1'"),
    ],
)
def test_unknown_protocols_absurd_durations_and_odd_numbers_in_the_header_are_refused_with_the_line(tmp_path, header_change, line, words):
    path = _file(tmp_path, _good().replace(*header_change))
    with pytest.raises(InputFileError, match=f"^{path}: line {line}: .*{words}") as info:
        read_human_file(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("row", ["1_0,0.1", "1,0_1", "0x1,0.1", "1,1e0_0"])
def test_a_frame_or_force_in_another_spelling_than_digits_is_refused_with_the_line(tmp_path, row):
    body = _good(rows=3).replace("\n1,0.1\n", f"\n{row}\n")
    path = _file(tmp_path, body)
    with pytest.raises(InputFileError, match=f"^{path}: line 6: expected 'frame,force'"):
        read_human_file(path)


def test_every_protocol_up_to_the_keyed_one_still_reads(tmp_path):
    """A recording of any version replays, 6 too: a keyed run's card says 6, and a human-file
    written from it was refused while the world is the same."""
    from agent_client.controllers.human_file import REPLAYABLE_PROTOCOLS
    from protocol.messages import KEYED_VERSION

    # a protocol bump fails here until someone decides whether its recordings replay
    assert max(REPLAYABLE_PROTOCOLS) == KEYED_VERSION == 6
    for version in range(1, KEYED_VERSION + 1):
        assert read_human_file(_file(tmp_path, _good().replace("protocol=1", f"protocol={version}"))).header.protocol == version
