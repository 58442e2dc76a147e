"""Errors that say what happened: an output that cannot be written, a port out of range,
a server never reached, a full disk; each one line, naming what it is about."""

from __future__ import annotations

import errno
import socket

import pytest
from click.testing import CliRunner

from agent_client.errors import OutputFileError
from agent_client.outputs import unwritable_dir, unwritable_file, write_cause, write_text
from vacc.cli import main

IMPOSSIBLE = "/proc/x.csv"  # /proc takes no new files, even for root


def _one_line(result) -> str:
    assert result.exit_code not in (0, None), result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("Error: ") and not any(ln.startswith(("  File", "OSError", "PermissionError")) for ln in lines), result.stderr
    return lines[-1]


def test_the_probes_leave_nothing_behind(tmp_path):
    assert unwritable_file(tmp_path / "new.csv") is None and not (tmp_path / "new.csv").exists()
    (tmp_path / "old.csv").write_text("kept")
    assert unwritable_file(tmp_path / "old.csv") is None and (tmp_path / "old.csv").read_text() == "kept"
    assert unwritable_dir(tmp_path / "a" / "b") is None and list(tmp_path.iterdir()) == [tmp_path / "old.csv"]
    assert unwritable_file(IMPOSSIBLE) is not None and unwritable_dir("/proc/x/run") is not None
    assert unwritable_file(tmp_path) == "is a folder"
    (tmp_path / "file").write_text("")
    assert "not a folder" in unwritable_dir(tmp_path / "file" / "run")


def test_a_full_disk_is_said_in_so_many_words():
    assert write_cause(OSError(errno.ENOSPC, "No space left on device")) == "no space left on device"
    assert write_cause(RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 128 vs 64")) == "no space left on device"
    assert write_cause(OSError(errno.EACCES, "Permission denied")) == "permission denied"


def test_write_text_names_the_file_and_the_cause(tmp_path, monkeypatch):
    from pathlib import Path

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(OutputFileError, match=f"^{tmp_path / 'summary.json'}: could not be written: no space left on device$"):
        write_text(tmp_path / "summary.json", "{}")


@pytest.mark.parametrize(
    "args",
    [
        ["drive", "--controller", "acc", "--log", IMPOSSIBLE],
        ["drive", "--controller", "acc", "--log", "{tmp}/run.csv", "--record", IMPOSSIBLE],
        ["train", "--reward", "gap", "--steps", "10", "--out", "/proc/x/run"],
        ["evaluate", "--out", "/proc/x/eval", "--duration", "1"],
    ],
)
def test_an_impossible_output_path_is_one_line_naming_it(tmp_path, args):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    line = _one_line(CliRunner().invoke(main, args))
    bad = next(a for a in args if a.startswith("/proc"))
    assert bad in line and "cannot be written" in line, line
    assert list(tmp_path.iterdir()) == []  # nothing was started


def test_a_port_out_of_range_says_so(tmp_path):
    result = CliRunner().invoke(main, ["drive", "--controller", "acc", "--log", str(tmp_path / "r.csv"), "--server", "127.0.0.1:99999"])
    assert result.exit_code == 2 and "port 99999 is out of range" in result.output and "--server" in result.output
    assert "is not HOST:PORT" in CliRunner().invoke(main, ["drive", "--controller", "acc", "--log", str(tmp_path / "r.csv"), "--server", "nowhere"]).output


def test_a_server_never_reached_is_said_so_without_frames_or_a_log_never_written(tmp_path):
    log = tmp_path / "run.csv"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:  # bound, never answers
        silent.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        line = _one_line(CliRunner().invoke(main, ["drive", "--controller", "acc", "--server", address, "--give-up", "0.3", "--log", str(log)]))
    assert "never reached" in line and address in line
    assert "episode -1" not in line and "frame" not in line and str(log) not in line
    assert list(tmp_path.iterdir()) == []
