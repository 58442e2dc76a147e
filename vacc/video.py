"""`vacc video RUN.csv --out run.mp4|run.gif`: re-render a logged run as a video.

A run is deterministic from its card (trajectory, seed, start, road) and its actions,
so the video replays the logged forces against a fresh server, asking for the full
colour camera, and checks every row against the log: the first row that differs is
named (its line and column) and nothing is kept. Each frame is the camera with the
head-up strip and the scrolling plot of :mod:`agent_client.view`; ``--network-view``
adds the network's 105x150 grey input beside it (computed from the colour frame by
:func:`agent_client.preprocess.preprocess` at the zoom asked for; a zoom-1 policy saw
the same crop from a camera rendered at half size).

MP4 goes through OpenCV's ``VideoWriter`` (H.264, ``avc1``, where the installed
OpenCV has it, else MPEG-4 Part 2, ``mp4v``); GIF through Pillow, at half size.
"""

from __future__ import annotations

import contextlib
import subprocess
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np

from agent_client.launcher import DEFAULT_ROAD, Road, local_server
from agent_client.progress import progress_bar
from agent_client.runlog import COLUMNS, format_row, read_card
from protocol.constants import CAMERA_SIZE
from protocol.scenarios import TRAJECTORIES
from vacc.runs import Job

__all__ = [
    "Episode", "ReplayMismatch", "episode_from_card", "read_rows", "replay", "VideoWriter", "write_video", "video_job", "make_videos", "video",
]  # fmt: skip

FPS = 10  # [1/s] one frame per control step: the video plays in simulated real time
GIF_SCALE = 2  # a GIF frame is 1/GIF_SCALE of the picture each way (a GIF holds every frame in memory)
CODECS = ("avc1", "mp4v")  # H.264 first; OpenCV's pip wheels often lack it


class ReplayMismatch(click.ClickException):
    """A replayed row differs from the logged one; the message names where."""


@dataclass(frozen=True)
class Episode:
    """What a replay asks the server for: the episode of the log, and the road it was driven on."""

    scenario: str
    trajectory: str  # a named trajectory, or a CSV trace's path
    seed: int
    set_speed: float | None = None  # [m/s]; None: the server's default
    host_speed: float | None = None  # [m/s]; None: drawn from the seed
    gap: float | None = None  # [m]; None: drawn from the seed
    duration: float | None = None  # [s]; None: to the trajectory's end
    road: Road = DEFAULT_ROAD
    seed_salt: int = 0  # the server's --seed


def episode_from_card(log: str | Path) -> Episode:
    """The episode of a ``vacc drive`` log, from its card.

    Raises:
        click.ClickException: no card beside the log, or an unreadable one.
    """
    try:
        card = read_card(log)
    except Exception as exc:  # InputFileError: one line already
        raise click.ClickException(str(exc)) from None
    if card is None:
        raise click.ClickException(f"{log}: no run card beside it ({Path(log).stem}.card.json); a video replays the episode the card names")
    ep, road = card["episode"], card.get("road") or {}
    sun = road.get("sun_elevation")
    return Episode(
        ep["scenario"], ep["trajectory"], int(ep["seed"]), ep.get("set_speed"), ep.get("host_speed"), ep.get("gap"), ep.get("duration"),
        Road(int(road["traffic"]) if road.get("traffic") is not None else DEFAULT_ROAD.traffic, tuple(sun) if sun else DEFAULT_ROAD.sun_elevation),
        int(road.get("seed_salt") or 0),
    )  # fmt: skip


def read_rows(log: str | Path) -> list[list[str]]:
    """The data rows of a run log, each its :data:`agent_client.runlog.COLUMNS` fields as written.

    Raises:
        click.ClickException: not a run log (its header does not start with the columns), or no rows.
    """
    lines = Path(log).read_text(encoding="ascii", errors="replace").splitlines()
    if not lines or lines[0].split(",")[: len(COLUMNS)] != list(COLUMNS):
        raise click.ClickException(f"{log}: not a run log (its header is not {','.join(COLUMNS)},...)")
    rows = [line.split(",")[: len(COLUMNS)] for line in lines[1:] if line]
    if not rows:
        raise click.ClickException(f"{log}: no rows to replay")
    return rows


def _check(log: str | Path, k: int, logged: list[str], obs: dict[str, Any]) -> None:
    """Raise where row ``k`` (0-based data row) replayed differs from the log."""
    got = format_row(obs).split(",")
    for name, a, b in zip(COLUMNS, logged, got, strict=True):
        if a != b:
            raise ReplayMismatch(f"{log}:{k + 2}: row {k + 1}, column {name!r}: the log has {a}, the replay {b}; the log does not match its card's episode")


@contextlib.contextmanager
def replay(ep: Episode, log: str | Path, rows: list[list[str]]) -> Iterator[Iterator[dict[str, Any]]]:
    """Replay ``rows`` (the logged forces) on a fresh spawned server; yields an iterator of the
    observations, each checked against its row before it is yielded.

    Raises:
        ReplayMismatch: a row differs (from the iterator).
    """
    from agent_client.session import Session
    from agent_client.traces import load_trace

    trace = None if ep.trajectory in TRAJECTORIES else load_trace(ep.trajectory)
    args = (*ep.road.server_args(), "--seed", str(ep.seed_salt))
    with local_server(*args, stderr=subprocess.DEVNULL) as addr, Session(addr, image_format="rgb", image_size=CAMERA_SIZE, client_name="vacc-video") as s:

        def frames() -> Iterator[dict[str, Any]]:
            # frame 0 is the same state with or without a camera pre-roll, so none is driven
            obs = s.reset(scenario=ep.scenario, seed=ep.seed, trajectory=ep.trajectory, trace=trace, duration=ep.duration,
                          host_speed=ep.host_speed, gap=ep.gap, set_speed=ep.set_speed, preroll=0)  # fmt: skip
            for k, row in enumerate(rows):
                _check(log, k, row, obs)
                yield obs
                if k + 1 < len(rows):
                    if obs["terminated"] or obs["truncated"]:
                        raise ReplayMismatch(f"{log}:{k + 3}: the replayed episode ended at row {k + 1}, but the log goes on")
                    obs = s.step(float(rows[k + 1][COLUMNS.index("force")]))  # the force that produced the next row

        yield frames()


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """File descriptor 2 to /dev/null for the block (native libraries write there directly)."""
    import os
    import sys

    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class VideoWriter:
    """MP4 (OpenCV) or GIF (Pillow) frames of one size; a context manager.

    Raises:
        click.ClickException: an unknown suffix, or no MP4 codec OpenCV can open.
    """

    def __init__(self, path: str | Path, size: tuple[int, int], fps: int = FPS):
        self.path, self.size, self.fps = Path(path), size, fps
        self.frames = 0
        self._gif: list[Any] = []
        self._cv: Any = None
        self.codec = "gif"
        suffix = self.path.suffix.lower()
        if suffix == ".mp4":
            import cv2

            self.path.parent.mkdir(parents=True, exist_ok=True)
            for codec in CODECS:
                with _quiet_stderr():  # FFmpeg prints its failed H.264 probes to fd 2
                    writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter.fourcc(*codec), fps, size)
                if writer.isOpened():
                    self._cv, self.codec = writer, codec
                    break
                writer.release()
            if self._cv is None:
                raise click.ClickException(f"{self.path}: OpenCV has no MP4 codec here (tried {', '.join(CODECS)}); write a .gif")
        elif suffix != ".gif":
            raise click.ClickException(f"{self.path}: a video is .mp4 or .gif, not {suffix or 'no suffix'!r}")

    def write(self, rgb: np.ndarray) -> None:
        """Append one (H, W, 3) RGB frame of the writer's size."""
        import cv2

        self.frames += 1
        if self._cv is not None:
            self._cv.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            return
        from PIL import Image

        small = cv2.resize(rgb, (rgb.shape[1] // GIF_SCALE, rgb.shape[0] // GIF_SCALE), interpolation=cv2.INTER_AREA)
        self._gif.append(Image.fromarray(small).quantize(colors=128))

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(keep=exc[0] is None)

    def close(self, keep: bool = True) -> None:
        """Finish the file (``keep`` False: remove what was written); safe to call twice."""
        if self._cv is not None:
            self._cv.release()
            self._cv = None
        if self._gif and keep:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._gif[0].save(self.path, save_all=True, append_images=self._gif[1:], duration=1000 // self.fps, loop=0)
        self._gif = []
        if not keep:
            self.path.unlink(missing_ok=True)


def write_video(log: str | Path, out: str | Path, ep: Episode, *, network_zoom: int | None = None) -> VideoWriter:
    """Replay ``log`` as ``ep`` and write its video to ``out``; returns the (closed) writer.

    Args:
        network_zoom: show the network's input at this zoom (1 or 2) beside the camera; None: not shown.

    Raises:
        ReplayMismatch: a row differs from the log (nothing is kept).
        click.ClickException: not a run log, or no writer for ``out``.
    """
    from agent_client.preprocess import preprocess
    from agent_client.session import Session
    from agent_client.view import Hud

    rows = read_rows(log)
    hud, writer = Hud(), None
    try:
        with replay(ep, log, rows) as frames:
            for obs in frames:
                hud.update(obs)
                image = Session.image(obs)
                net = preprocess(image, network_zoom) if network_zoom is not None and image is not None else None
                picture = hud.frame(image, obs, net)
                if writer is None:
                    writer = VideoWriter(out, (picture.shape[1], picture.shape[0]))
                writer.write(picture)
    except BaseException:
        if writer is not None:
            writer.close(keep=False)
        raise
    assert writer is not None  # read_rows: at least one row
    writer.close()
    return writer


def video_job(job: Job, out: Path) -> tuple[str, str | None]:
    """Write the video of one driven job (:mod:`vacc.video`): (its log's name, the video's path
    relative to ``out``, or None for the lead, whose log is not a run of its own to replay)."""
    log = Path(job.log)
    if job.method == "lead":
        return log.name, None
    path = Path("videos") / log.with_suffix(".mp4").name
    write_video(log, out / path, Episode(job.scenario, job.trajectory, job.seed, duration=job.duration, road=job.road))
    return log.name, str(path)


def make_videos(work: list[Job], out: Path, jobs: int) -> dict[str, str]:
    """One video per run of ``work`` into ``out/videos``, ``jobs`` at a time: log name -> video path (relative to ``out``).

    Raises:
        click.ClickException: a replay failed or differed from its log.
    """
    made: dict[str, str] = {}
    with ProcessPoolExecutor(max_workers=min(jobs, len(work))) as pool, progress_bar(len(work), "videos", unit="run") as bar:
        futures = [pool.submit(video_job, j, out) for j in work]
        try:
            for fut in as_completed(futures):
                name, path = fut.result()
                if path is not None:
                    made[name] = path
                bar.update(1)
        except Exception as exc:
            for f in futures:
                f.cancel()
            raise click.ClickException(f"a video failed: {exc}") from None
    return made


@click.command("video")
@click.argument("log", type=click.Path(exists=True, dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="The video: .mp4 (H.264 where OpenCV has it, else MPEG-4) or .gif (half size).")
@click.option("--network-view", is_flag=True, help="Show the network's 105x150 grey input beside the camera.")
@click.option("--zoom", default=1, show_default=True, type=click.Choice(["1", "2"]), help="--network-view: the checkpoint's zoom (1: the paper's halved camera).")
def video(log: str, out: str, network_view: bool, zoom: str) -> None:
    """Re-render LOG (a vacc drive run log with its card) as a video: replay its logged
    forces against a fresh server, check every row against the log, and write the camera
    with a head-up strip (speed, set speed, gap, acceleration, force) and a scrolling plot."""
    writer = write_video(log, out, episode_from_card(log), network_zoom=int(zoom) if network_view else None)
    click.echo(f"{log}: {writer.frames} rows replayed, each as logged -> {out} ({writer.codec}, {writer.fps} fps)")
