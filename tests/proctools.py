"""Process helpers for the tests: start a job and always reap it, who spawned what, is it gone."""

from __future__ import annotations

import contextlib
import csv
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path


def procs() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every process."""
    out = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            out[int(d.name)] = (ppid, cmd)
    return out


def servers_of(pids) -> list[int]:
    """Simulator servers spawned by any of ``pids`` (they carry --parent-pid)."""
    marks = {f"--parent-pid {p} " for p in pids}
    return [pid for pid, (_, cmd) in procs().items() if "sim_server" in cmd and any(m in cmd + " " for m in marks)]


def descendants(root: int) -> set[int]:
    table = procs()
    found, frontier = set(), {root}
    while frontier:
        frontier = {pid for pid, (ppid, _) in table.items() if ppid in frontier} - found
        found |= frontier
    return found


def state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0].join("()")
    except OSError:
        return "(gone)"


def wait_gone(pids, timeout: float = 15.0) -> list[int]:
    """Wait until none of ``pids`` is alive (zombies count as gone); return those still alive."""
    deadline = time.monotonic() + timeout
    while True:
        alive = [p for p in pids if Path(f"/proc/{p}").exists() and "(Z)" not in state(p)]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.2)


def assert_no_servers_left(actor_pids, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while servers_of(actor_pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert servers_of(actor_pids) == [], "simulator servers left behind"


def wait_until_both_actors_deliver(run_dir: Path, timeout: float = 300.0) -> None:
    """Poll ``run_dir/scalars.csv`` until actors 0 and 1 have each delivered a batch; fail
    saying so after ``timeout`` s (generous: starting Ray on a loaded 2-core host took
    over 120 s once, and a silent return then failed the next check for the wrong reason)."""
    deadline = time.monotonic() + timeout
    seen: set[str] = set()
    while time.monotonic() < deadline:
        path = run_dir / "scalars.csv"
        rows = list(csv.DictReader(open(path))) if path.exists() else []
        seen = {r["name"] for r in rows if r["name"].startswith("charts/transitions/actor-")}
        if {"charts/transitions/actor-0", "charts/transitions/actor-1"} <= seen:
            return
        time.sleep(0.3)
    raise AssertionError(f"{run_dir}: both actors had not delivered after {timeout:.0f} s (delivered: {sorted(seen) or 'none'})")


class ProcessSpawnedInUnitTest(RuntimeError):
    """A test of the unit tier started a Python process (tests/conftest.py)."""


def reap_job(proc: subprocess.Popen, group: bool | None = None) -> None:
    """Kill ``proc`` if it still runs (SIGKILL: its whole process group when it leads one, as
    a terminal job), wait for it and close its pipes. Safe to call twice."""
    if group is None:
        group = _leads_its_group(proc.pid)
    if proc.poll() is None:
        if group:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        else:
            proc.kill()
        proc.wait()
    for pipe in (proc.stdin, proc.stdout, proc.stderr):
        if pipe is not None:
            pipe.close()


def _leads_its_group(pid: int) -> bool:
    try:
        return os.getpgid(pid) == pid
    except ProcessLookupError:
        return False


@contextlib.contextmanager
def job(argv: list[str], *, own_group: bool = False, stdout=subprocess.DEVNULL, stderr_path: Path | None = None, **kw) -> Iterator[subprocess.Popen]:
    """``argv`` as a child process for the ``with`` block, always reaped after it.

    ``own_group``: a session of its own, as a job started from a terminal, so that
    ``os.killpg(proc.pid, SIGINT)`` is a Ctrl-C. ``stderr_path``: where its stderr goes.
    """
    with contextlib.ExitStack() as stack:
        err = stack.enter_context(open(stderr_path, "w")) if stderr_path is not None else kw.pop("stderr", None)
        proc = subprocess.Popen(argv, stdout=stdout, stderr=err, text=True, start_new_session=own_group, **kw)
    try:
        yield proc
    finally:
        reap_job(proc, group=own_group)


def vacc_job(args: list[str], **kw) -> contextlib.AbstractContextManager[subprocess.Popen]:
    """``python -m vacc ARGS`` as a :func:`job`."""
    return job([sys.executable, "-m", "vacc", *args], **kw)
