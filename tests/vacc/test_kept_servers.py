"""The evaluation's kept servers: a worker drives its runs through one server, which must
drive each run exactly as a fresh server would, and is reaped when the runs are done."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from agent_client.launcher import Road
from vacc import runs
from vacc.runs import Job, drive_jobs, run_job

pytestmark = pytest.mark.integration
MODEL = Path(__file__).resolve().parents[2] / "models" / "ice-gap.pt"
# Roads no other test uses (one per test: xdist may run them side by side), so that their
# servers can be told apart by their command line.
ROAD = Road(traffic=3, sun_elevation=(0.417, 0.419))
OTHER_ROAD = Road(traffic=3, sun_elevation=(0.421, 0.423))


def _work(out: Path) -> list[Job]:
    """Runs that differ in method, lead and seed; the policy's run reads the camera, so the
    traffic's and the sun's state at each reset shows in its log."""
    spec = [("acc", "stopped", 3), ("ddqn-gap", "random", 5), ("human", "brake-stop", 4), ("ddqn-gap", "cut-in", 2)]
    return [
        Job(method, trajectory, "ice", seed, str(out / f"{method}-{trajectory}-{seed}.csv"), 4.0,
            checkpoint=str(MODEL) if method.startswith("ddqn") else None, road=ROAD)  # fmt: skip
        for method, trajectory, seed in spec
    ]


def _our_servers(road: Road = ROAD) -> list[int]:
    mark = ",".join(map(str, road.sun_elevation)).encode()
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"sim_server" in cmd and mark in cmd:
            pids.append(int(entry.name))
    return pids


def test_a_kept_server_drives_each_run_as_a_fresh_server_and_is_reaped(tmp_path: Path) -> None:
    fresh, kept = tmp_path / "fresh", tmp_path / "kept"
    fresh.mkdir(), kept.mkdir()
    for job in _work(fresh):  # a new server for every run
        run_job(job)
        runs._KEPT.close()
    assert not _our_servers()
    drive_jobs(list(reversed(_work(kept))), 1, "kept")  # one worker: one server, the runs in another order
    assert not _our_servers(), "a worker's kept server outlived the runs"
    for path in sorted(fresh.iterdir()):
        assert (kept / path.name).read_bytes() == path.read_bytes(), f"{path.name} differs on a kept server"
    assert len(os.listdir(kept)) == 4


def test_a_kept_server_is_reused_and_reaped_on_close() -> None:
    kept, args = runs.KeptServers(), OTHER_ROAD.server_args()
    try:
        first = kept.address(*args)
        assert kept.address(*args) == first
        assert len(_our_servers(OTHER_ROAD)) == 1
        kept.discard(*args)
        assert not _our_servers(OTHER_ROAD)
        kept.address(*args)
    finally:
        kept.close()
    assert not _our_servers(OTHER_ROAD)
