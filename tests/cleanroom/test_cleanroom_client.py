"""Clean-room client (spec_client.py, written from protocol/SPEC.md only) against the real server.

Each run drives ice/test-1, seed 7, 30 s (frames 0..300) with a fixed force sequence and is
compared field by field, as Python's shortest float repr (so bit for bit), with the run log
that the product's own client writes replaying the same forces (`vacc drive --controller
human-file`). Loopback only; every server is reaped in a `finally`.
"""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import spec_client as sc  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SEED, TRAJECTORY, DURATION = 7, "test-1", 30.0
ACTIONS = [round(0.6 * math.sin(i / 12) + 0.05 * ((i * 7) % 5 - 2), 4) for i in range(300)]
LOG_COLUMNS = ["t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision", "a_lead"]
LOSSY = "drop=0.2,dup=0.1,reorder=0.1,seed={}"
pytestmark = pytest.mark.timeout(120)


@contextmanager
def server(tmp_path: Path, *args: str):
    """`vacc serve --port 0 ARGS`; yields (host, port), then stderr's text holder."""
    out, err = tmp_path / "serve.out", tmp_path / "serve.err"
    cmd = [
        sys.executable,
        "-m",
        "vacc",
        "serve",
        "--port",
        "0",
        "--max-seconds",
        "110",
        "--parent-pid",
        str(os.getpid()),
        *args,
    ]
    with open(out, "w") as fo, open(err, "w") as fe:
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=fo, stderr=fe)
    try:
        yield _listening(proc, out, err)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _listening(proc: subprocess.Popen, out: Path, err: Path) -> tuple[str, int]:
    """Wait for 'vacc-server listening on HOST:PORT' (serve --help) and parse it."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        for line in out.read_text().splitlines():
            if line.startswith("vacc-server listening on "):
                host, port = line.split()[-1].rsplit(":", 1)
                return host, int(port)
        if proc.poll() is not None:
            raise RuntimeError(f"server exited {proc.returncode}: {err.read_text()}")
        time.sleep(0.05)
    raise RuntimeError("server never said it was listening")


def spec_run(addr, psk=None, faults=None) -> tuple[list[dict], int]:
    client = sc.SpecClient(addr, psk=psk, faults=faults)
    try:
        client.open()
        rows = sc.drive_episode(client, ACTIONS, SEED, TRAJECTORY, DURATION)
    finally:
        client.close()
    return rows, client.resends


def product_replay(addr, tmp_path: Path, key_file: Path | None = None) -> list[dict]:
    """The same forces replayed by `vacc drive --controller human-file`; its run log rows."""
    human, log = tmp_path / "forces.human.csv", tmp_path / "replay.csv"
    lines = [
        "# vacc-human-file v1",
        f"# scenario=ice trajectory={TRAJECTORY} seed={SEED} control_period=0.1 protocol=5 "
        f"duration={DURATION} set_speed=33.5",
        "# controller=cleanroom",
        "frame,force",
    ]
    human.write_text("\n".join(lines + [f"{i},{u!r}" for i, u in enumerate(ACTIONS)]) + "\n")
    cmd = [
        sys.executable,
        "-m",
        "vacc",
        "drive",
        "--controller",
        "human-file",
        "--human-file",
        str(human),
        "--server",
        f"{addr[0]}:{addr[1]}",
        "--trajectory",
        TRAJECTORY,
        "--seed",
        str(SEED),
        "--log",
        str(log),
        "--quiet",
    ]
    if key_file is not None:
        cmd += ["--key-file", str(key_file)]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=90)
    assert done.returncode == 0, done.stderr
    with open(log, newline="") as f:
        return list(csv.DictReader(f))


def assert_same(mine: list[dict], logged: list[dict]) -> None:
    """Every logged field equals the obs field's shortest repr (bit-identical floats)."""
    assert [r["frame"] for r in mine] == list(range(len(ACTIONS) + 1))
    assert len(mine) == len(logged)
    for obs, row in zip(mine, logged, strict=True):
        assert list(row) == LOG_COLUMNS
        got = {k: repr(obs[k]) for k in LOG_COLUMNS}
        got["collision"] = str(int(obs["collision"]))
        assert got == row, f"frame {obs['frame']}"
    assert mine[-1]["truncated"] and mine[-1]["reason"] == "end"


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> list[dict]:
    """The product's replay on a lossless, unkeyed server."""
    tmp = tmp_path_factory.mktemp("reference")
    with server(tmp) as addr:
        return product_replay(addr, tmp)


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    path = tmp_path / "vacc.key"
    path.write_bytes(os.urandom(32).hex().encode() + b"\n")  # stripped by both sides
    return path


def test_spec_vectors():
    done = sc.check_spec_vectors((REPO / "protocol" / "SPEC.md").read_text())
    assert len(done) == 6


def test_unkeyed_matches_product(tmp_path, reference):
    with server(tmp_path) as addr:
        mine, _ = spec_run(addr)
        assert_same(mine, product_replay(addr, tmp_path))
    assert_same(mine, reference)
    assert "rejected" not in (tmp_path / "serve.err").read_text()


def test_keyed_matches_product(tmp_path, reference, key_file):
    with server(tmp_path, "--key-file", str(key_file)) as addr:
        mine, _ = spec_run(addr, psk=sc.read_key_file(str(key_file)))
        assert_same(mine, product_replay(addr, tmp_path, key_file))
        with pytest.raises(sc.ProtocolError, match="no reply"):  # wrong key: never answered
            bad = sc.SpecClient(addr, psk=b"x" * 32, give_up=0.5)
            try:
                bad.open()
            finally:
                bad.close()
    assert_same(mine, reference)


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_lossy_matches_lossless(tmp_path, reference, key_file, keyed):
    args = ["--faults", LOSSY.format(11 + keyed)]
    if keyed:
        args += ["--key-file", str(key_file)]
    psk = sc.read_key_file(str(key_file)) if keyed else None
    with server(tmp_path, *args) as addr:
        # Server sends lose 20 %; the client's own sends lose 10 % and duplicate 10 % too.
        mine, resends = spec_run(addr, psk, sc.Faults(drop=0.1, dup=0.1, seed=5))
    assert resends > 20
    assert_same(mine, reference)


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_busy_then_welcome(tmp_path, key_file, keyed):
    """A second client is answered BUSY while the first holds the world, then welcomed (§5)."""
    import threading

    psk = sc.read_key_file(str(key_file)) if keyed else None
    args = ["--key-file", str(key_file)] if keyed else []
    with server(tmp_path, *args) as addr:
        first, second = sc.SpecClient(addr, psk=psk), sc.SpecClient(addr, psk=psk)
        result: dict = {}
        try:
            first.open()
            first.reset(0, SEED, TRAJECTORY, duration=1.0)  # holds the world now
            thread = threading.Thread(target=lambda: result.update(w=second.open()))
            thread.start()
            time.sleep(0.5)
            first.close()
            thread.join(10)
            assert result["w"]["type"] == "welcome" and second.busy_answers > 0
            assert second.reset(0, SEED, TRAJECTORY, duration=1.0)["frame"] == 0
        finally:
            first.close()
            second.close()
