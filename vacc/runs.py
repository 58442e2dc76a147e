"""The runs of `vacc evaluate`: what to drive (:class:`Job`), driving it, and scoring its logs.

The lowest layer of the evaluation: :mod:`vacc.evaluate` (the command), its suites
(:mod:`vacc.safety`, :mod:`vacc.random_suite`), :mod:`vacc.tables` and :mod:`vacc.figures`
import it, and it imports none of them. Each run is a client over UDP to a real simulator
process, which the worker that drives it keeps for its next run. The lead vehicle is driven as a follower's run and then written as its own:
its logs carry the lead's speed as ``v_host`` and a 55 m placeholder gap.
"""

from __future__ import annotations

import csv
import multiprocessing.util
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import click

from agent_client.launcher import DEFAULT_ROAD, KeptServers, Road
from agent_client.progress import progress_bar
from agent_client.rl.stop import STOP, handlers_active, worker_signals
from energy import SETTLE_S, RunLog, RunLogError, evaluate_run, read_run_log
from energy.metrics import Metrics
from protocol.scenarios import GAP_LIMIT, TEST_DURATION, TEST_TRAJECTORIES

__all__ = [
    "TRAJECTORIES", "Job", "Run", "EarlyEnd", "early_end", "parse_seeds", "seed_text", "log_path", "run_job", "drive_jobs", "score_runs",
]  # fmt: skip

TRAJECTORIES = TEST_TRAJECTORIES  # the tables are over the paper's test set


def parse_seeds(text: str) -> list[int]:
    """'0-9' or '0,3,5' (or a mix, '0-2,7') to a sorted list of seeds.

    Raises:
        ValueError: anything else, or an empty set.
    """
    seeds: set[int] = set()
    for part in (p.strip() for p in text.split(",") if p.strip()):
        lo, sep, hi = part.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()):
            raise ValueError(f"{text!r} is not a seed list like 0-9 or 0,3,5")
        a, b = int(lo), int(hi) if sep else int(lo)
        if b < a or b - a > 10_000:
            raise ValueError(f"{part!r} is not an increasing range of at most 10,000 seeds")
        seeds.update(range(a, b + 1))
    if not seeds:
        raise ValueError(f"{text!r} names no seed")
    return sorted(seeds)


def seed_text(seeds: Sequence[int]) -> str:
    """Seeds as ranges, the way ``--seeds`` takes them: [0, 1, 2, 5] -> "0-2,5"."""
    parts: list[str] = []
    for s in sorted(seeds):
        if parts and parts[-1].split("-")[-1] == str(s - 1):
            parts[-1] = f"{parts[-1].split('-')[0]}-{s}"
        else:
            parts.append(str(s))
    return ",".join(parts)


def log_path(out: Path, method: str, trajectory: str, seed: int | None = None) -> Path:
    """Run log of one run: ``logs/<method>-<trajectory>.csv`` when the evaluation has one
    seed (``seed`` None), ``logs/<method>-<trajectory>-seed<N>.csv`` when it has several."""
    return out / "logs" / (f"{method}-{trajectory}.csv" if seed is None else f"{method}-{trajectory}-seed{seed}.csv")


@dataclass(frozen=True)
class Job:
    """One method on one trajectory."""

    method: str
    trajectory: str
    scenario: str
    seed: int
    log: str
    duration: float | None
    checkpoint: str | None = None
    human_file: str | None = None
    cold_start: bool = False  # engage a DDQN policy at frame 0, without the camera's pre-roll
    road: Road = DEFAULT_ROAD  # the server's traffic and sun
    view: bool = False  # watch it in a window (vacc evaluate --view); the log is the same


def _controller(job: Job) -> Any:
    # imported here: torch and the camera load only in the worker processes that drive
    from agent_client.controllers import make_controller

    if job.method in ("human", "lead"):
        if not job.human_file:
            return make_controller("hdm", seed=job.seed)
        from agent_client.controllers.human_file import read_human_file

        replay = read_human_file(job.human_file)
        replay.check(scenario=job.scenario, trajectory=job.trajectory, seed=job.seed)
        return make_controller("human-file", human_file=replay, pad="hold")
    # every ddqn-* job has its checkpoint (the suites give it one); so has a --model NAME=PATH
    return make_controller("ddqn" if job.method.startswith("ddqn") or job.checkpoint else job.method, checkpoint=job.checkpoint)


_KEPT = KeptServers()  # this process's servers, one per road: the runs it drives reuse them


def run_job(job: Job) -> Job:
    """Drive one job through this process's server for its road (started on first use, kept
    for the next job); returns the job when its log is written."""
    from agent_client.controllers import camera
    from agent_client.drive import drive_episode
    from agent_client.session import Session

    if job.checkpoint is not None:  # a policy: torch (2 CPU-s to import), which a law's run never loads
        import torch

        torch.set_num_threads(1)  # one run per core
    controller = _controller(job)
    image, size = camera(controller)
    view = None
    if job.view:
        from agent_client.view import LiveView
        from protocol.constants import CAMERA_SIZE

        image, size = ("rgb", CAMERA_SIZE) if image == "none" else (image, size)  # the policy keeps the frames it needs
        view = LiveView(title=f"vacc evaluate --view: {job.method} on {job.scenario}/{job.trajectory} (seed {job.seed})")
    log = Path(job.log)
    if job.method == "lead":
        log = log.with_name(log.name + ".tmp")
    road = job.road.server_args()
    try:
        with Session(_KEPT.address(*road), image_format=image, image_size=size, client_name=f"vacc-evaluate/{job.method}") as s:
            drive_episode(s, controller, scenario=job.scenario, seed=job.seed, trajectory=job.trajectory, duration=job.duration, log=log,
                          preroll=0 if job.cold_start else None, on_step=view)  # fmt: skip
    except BaseException:
        _KEPT.discard(*road)  # its session may still be open: the next job gets a fresh server
        raise
    finally:
        if view is not None:
            view.close()
    if job.method == "lead":
        _lead_log(log, Path(job.log))
        log.unlink()
    return job


def drive_jobs(work: list[Job], jobs: int, label: str) -> None:
    """Drive every job, ``jobs`` at a time (in worker processes, each with its own kept
    server); jobs with a view one after another in this process.

    Raises:
        click.ClickException: a run failed; the others are cancelled.
    """
    if any(j.view for j in work):  # one window at a time, in this process
        with progress_bar(len(work), label, unit="run") as bar:
            try:
                for j in work:
                    try:
                        run_job(j)
                    except Exception as exc:
                        raise click.ClickException(f"a run failed: {exc}") from None
                    bar.update(1)
            finally:
                _KEPT.close()
        return
    stoppable = handlers_active()  # inside vacc reproduce: a first signal stops after the runs in flight
    with ProcessPoolExecutor(max_workers=min(jobs, len(work)), initializer=_worker_init, initargs=(stoppable,)) as pool, progress_bar(len(work), label, unit="run") as bar:
        futures = [pool.submit(run_job, j) for j in work]
        try:
            for fut in as_completed(futures):
                fut.result()
                bar.update(1)
                if stoppable and STOP.is_set():
                    raise KeyboardInterrupt
        except KeyboardInterrupt:
            for f in futures:
                f.cancel()
            raise
        except Exception as exc:
            for f in futures:
                f.cancel()
            raise click.ClickException(f"a run failed: {exc}") from None


def _worker_init(stoppable: bool) -> None:
    """A pool worker: reap its kept servers when it exits (multiprocessing runs the finalizer
    at a worker's normal exit; a killed worker's servers see their parent gone and exit)."""
    global _KEPT
    _KEPT = KeptServers()  # a forked worker's own: never the servers of the process it came from
    multiprocessing.util.Finalize(None, _KEPT.close, exitpriority=10)
    if stoppable:
        worker_signals()


def _lead_log(follower: Path, out: Path) -> None:
    # The lead's own run: its speed and acceleration as the "host" of a log.
    with follower.open() as f, out.open("w", newline="\n") as g:
        reader = csv.DictReader(f)
        assert reader.fieldnames is not None
        g.write(",".join(reader.fieldnames) + "\n")
        for row in reader:
            row.update(v_host=row["v_lead"], accel=row["a_lead"], gap="55.0", force="0.0", collision="0")
            g.write(",".join(row[k] for k in reader.fieldnames) + "\n")


END_SLACK_S = 0.15  # [s] a run whose last row is within this of its expected end ran to it (rows are 0.1 s apart)


class EarlyEnd(NamedTuple):
    """How and when a run ended before its duration."""

    at: float  # [s] the last row's time
    expected: float  # [s] when it should have ended
    how: str  # "collision", "lost the lead (gap past 300 m)" or "stopped"

    def text(self) -> str:
        return f"{self.how} at {self.at:.1f} s of {self.expected:g} s"


def early_end(log: RunLog, duration: float | None = None) -> EarlyEnd | None:
    """Whether a test run ended before ``duration`` [s] (None: the whole trajectory), and how.

    The log says how from its last row: a collision flagged, a gap past
    :data:`protocol.scenarios.GAP_LIMIT`, else the run was stopped.
    """
    expected = TEST_DURATION if duration is None else min(duration, TEST_DURATION)
    last = float(log.t[-1])
    if last >= log.t[0] + expected - END_SLACK_S:
        return None
    how = "collision" if log.collision[-1] else f"lost the lead (gap past {GAP_LIMIT:g} m)" if log.gap[-1] > GAP_LIMIT else "stopped"
    return EarlyEnd(last, expected, how)


class Run(NamedTuple):
    """One scored run: a method on a trajectory with one seed."""

    method: str
    trajectory: str
    seed: int | None
    """None: the one seed of a single-seed evaluation (its log has no seed in its name)."""
    log: RunLog
    metrics: Metrics
    early: EarlyEnd | None = None
    """Set when the run ended before its duration (:func:`early_end`)."""


def score_runs(
    out: Path, methods: Sequence[str], vehicle: str, settle: float = SETTLE_S, seeds: Sequence[int] | None = None,
    duration: float | None = None, ends: bool = False,
) -> list[Run]:  # fmt: skip
    """Read and score every run log of ``out/logs`` that exists (see :func:`log_path`),
    with ``ends``, marking each that ended before ``duration`` (:func:`early_end`).

    Args:
        settle: seconds at the start of each run left out of the comfort metrics [s].
        seeds: the seeds of a multi-seed evaluation; None: one seed.
        duration: the runs' ``--duration`` [s]; None: the whole trajectory.
        ends: mark the early ends (the caller knows the logs were driven for ``duration``).

    Raises:
        click.ClickException: a log is invalid.
    """
    runs = []
    for method in methods:
        for traj in TRAJECTORIES:
            for seed in seeds if seeds is not None else [None]:
                path = log_path(out, method, traj, seed)
                if path.exists():
                    try:
                        log = read_run_log(path)
                    except RunLogError as exc:
                        raise click.ClickException(str(exc)) from None
                    runs.append(Run(method, traj, seed, log, evaluate_run(log, vehicle, settle_s=settle),
                                    early_end(log, duration) if ends else None))  # fmt: skip
    return runs
