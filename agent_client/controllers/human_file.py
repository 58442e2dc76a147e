"""Human-files: forces recorded at the wheel, and their replay as a controller.

A human-file is ASCII text::

    # vacc-human-file v1
    # scenario=ice trajectory=test-1 seed=0 control_period=0.1 protocol=1 duration=none
    # controller=keyboard
    frame,force
    0,0.0
    1,0.05
    ...

* Line 1 is the magic line naming the format version.
* Line 2 holds ``key=value`` pairs, separated by spaces: ``scenario``, ``trajectory``
  (a test name, ``random``, or a trace CSV's file name; URL-quoted), ``seed``,
  ``control_period`` [s], ``protocol`` (the wire protocol version) and
  ``duration`` [s] or ``none``. Optional: ``set_speed`` [m/s] (absent: the default
  33.5), ``host_speed`` [m/s] and ``gap`` [m] (absent: drawn from the seed); a
  replay must ask for the same. Unknown keys are kept and ignored.
* Further ``#`` lines are comments (e.g. which input device drove).
* The column row ``frame,force``, then one row per control step: the force u in
  [-1, 1] applied at frame ``frame`` (the step from frame n to n + 1), frames 0, 1,
  2, ... without gaps. Forces are written with Python's repr, so a replay sends
  exactly the recorded numbers and reproduces the run log byte for byte.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any
from urllib.parse import quote, unquote

from agent_client.errors import InputFileError
from protocol.messages import PROTOCOL_VERSION
from protocol.numbers import plain_float, plain_int
from protocol.scenarios import DEFAULT_SET_SPEED, TRAJECTORIES

__all__ = [
    "MAGIC",
    "PADS",
    "HumanFileHeader",
    "HumanFile",
    "read_human_file",
    "HumanFileRecorder",
    "HumanFileController",
    "RecordingController",
    "trajectory_label",
    "start_extra",
    "road_extra",
]

MAGIC = "# vacc-human-file v1"
COLUMNS = "frame,force"
PADS = ("error", "hold", "zero")
REQUIRED_KEYS = ("scenario", "trajectory", "seed", "control_period", "protocol")
PERIOD_TOLERANCE = 1e-9  # [s] control periods are compared as numbers, not strings
# Protocol 2 only added reset and obs fields (initial conditions, set speed), so a
# protocol-1 recording replays the same run below the default 33.5 m/s set speed;
# 3 to 5 changed only the handshake, the welcome and the pre-roll, which a recording
# starts after; 6 is a keyed session's (its run card says 6), which only seals the same
# datagrams.
REPLAYABLE_PROTOCOLS = (1, 2, 3, 4, 5, 6)  # written out: a new version must be decided on
MAX_DURATION = 86_400.0  # [s] a day: no vacc episode lasts an hour; a longer one is a typo, not a drive
START_KEYS = (("set_speed", "--set-speed"), ("host_speed", "--host-speed"), ("gap", "--gap"))


def start_extra(*, set_speed: float | None, host_speed: float | None, gap: float | None) -> dict[str, str]:
    """Header items recording a run's set speed [m/s] and given initial host speed [m/s] and gap [m]."""
    values = {"set_speed": DEFAULT_SET_SPEED if set_speed is None else set_speed, "host_speed": host_speed, "gap": gap}
    return {k: repr(float(v)) for k, v in values.items() if v is not None}


def road_extra(welcome: dict[str, Any] | None) -> dict[str, str]:
    """Header items recording the road the human saw (a server's welcome since protocol 5):
    its traffic and the range of the sun's height. They change the scenery, not the drive,
    so a replay is not checked against them."""
    w = welcome or {}
    extra = {} if w.get("traffic") is None else {"traffic": str(int(w["traffic"]))}
    if isinstance(w.get("sun_elevation"), list | tuple) and len(w["sun_elevation"]) == 2:
        extra["sun_elevation"] = ",".join(repr(float(v)) for v in w["sun_elevation"])
    return extra


def trajectory_label(trajectory: str) -> str:
    """How a trajectory is named in a header: test names as they are, a trace CSV by file name."""
    if trajectory in TRAJECTORIES:
        return trajectory
    return Path(trajectory).name


@dataclass(frozen=True)
class HumanFileHeader:
    """What a human-file was recorded against."""

    scenario: str
    trajectory: str  # label, see trajectory_label()
    seed: int
    control_period: float  # [s]
    protocol: int = PROTOCOL_VERSION
    duration: float | None = None  # [s] the live run's --duration, if any
    extra: dict[str, str] = field(default_factory=dict)

    def line(self) -> str:
        """The header's key=value line (line 2 of the file)."""
        pairs = {
            "scenario": self.scenario,
            "trajectory": self.trajectory,
            "seed": str(self.seed),
            "control_period": repr(float(self.control_period)),
            "protocol": str(self.protocol),
            "duration": "none" if self.duration is None else repr(float(self.duration)),
            **self.extra,
        }
        return "# " + " ".join(f"{k}={quote(v, safe='/.-_:+,')}" for k, v in pairs.items())


@dataclass(frozen=True)
class HumanFile:
    """A parsed human-file: its header and forces indexed by frame."""

    path: Path
    header: HumanFileHeader
    forces: tuple[float, ...]
    header_line: int  # line number of the key=value line (for errors)
    last_line: int  # line number of the last row

    def check(
        self,
        *,
        scenario: str,
        trajectory: str,
        seed: int,
        control_period: float | None = None,
        set_speed: float | None = None,
        host_speed: float | None = None,
        gap: float | None = None,
    ) -> None:
        """Refuse a replay against something other than what was recorded.

        ``set_speed`` None means the default; ``host_speed`` and ``gap`` None mean
        drawn from the seed.

        Raises:
            InputFileError: naming the file, the header line and what differs.
        """
        where = f"{self.path}: line {self.header_line}"
        h = self.header
        label = trajectory_label(trajectory)
        for key, have, want, option in (
            ("scenario", h.scenario, scenario, "--scenario"),
            ("trajectory", h.trajectory, label, "--trajectory"),
            ("seed", h.seed, seed, "--seed"),
        ):
            if have != want:
                raise InputFileError(f"{where}: recorded with {key}={have}, but {option} {want} was requested")
        if h.protocol not in REPLAYABLE_PROTOCOLS:
            raise InputFileError(f"{where}: recorded with protocol={h.protocol}, this client speaks protocol {PROTOCOL_VERSION}")
        asked = start_extra(set_speed=set_speed, host_speed=host_speed, gap=gap)
        recorded = {"set_speed": repr(DEFAULT_SET_SPEED), **{k: v for k, v in h.extra.items() if k in dict(START_KEYS)}}
        for key, option in START_KEYS:
            if recorded.get(key) != asked.get(key):
                was, now = recorded.get(key, "none (drawn)"), asked.get(key, "none (drawn)")
                raise InputFileError(f"{where}: recorded with {key}={was}, but {option} {now} was requested")
        if control_period is not None and abs(h.control_period - control_period) > PERIOD_TOLERANCE:
            raise InputFileError(
                f"{where}: recorded with control_period={h.control_period!r} s, the server steps {control_period!r} s"
            )


def _parse_header(path: Path, lineno: int, text: str) -> HumanFileHeader:
    where = f"{path}: line {lineno}"
    if not text.startswith("#"):
        raise InputFileError(f"{where}: missing header line 'scenario=... trajectory=... seed=... control_period=... protocol=...'")
    pairs: dict[str, str] = {}
    for item in text[1:].split():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputFileError(f"{where}: header item {item!r} is not key=value")
        pairs[key] = unquote(value)
    missing = [k for k in REQUIRED_KEYS if k not in pairs]
    if missing:
        raise InputFileError(f"{where}: header lacks {', '.join(missing)}")
    try:
        seed = plain_int(pairs["seed"])
        period = plain_float(pairs["control_period"])
        protocol = plain_int(pairs["protocol"])
        dur_text = pairs.get("duration", "none")
        duration = None if dur_text == "none" else plain_float(dur_text)
    except ValueError as exc:
        raise InputFileError(f"{where}: bad header value: {exc}") from None
    if not (math.isfinite(period) and period > 0):
        raise InputFileError(f"{where}: control_period {period!r} must be > 0 s")
    if duration is not None and not (math.isfinite(duration) and 0 < duration <= MAX_DURATION):
        raise InputFileError(f"{where}: duration {duration!r} must be in (0, {MAX_DURATION:g}] s or none")
    if protocol not in REPLAYABLE_PROTOCOLS:  # before a server is spawned, naming the line
        raise InputFileError(f"{where}: recorded with protocol={protocol}, this client speaks protocol {PROTOCOL_VERSION} "
                             f"and replays {', '.join(map(str, REPLAYABLE_PROTOCOLS))}")  # fmt: skip
    extra = {k: v for k, v in pairs.items() if k not in (*REQUIRED_KEYS, "duration")}
    return HumanFileHeader(pairs["scenario"], pairs["trajectory"], seed, period, protocol, duration, extra)


def read_human_file(path: str | Path) -> HumanFile:
    """Parse and check a human-file.

    Raises:
        InputFileError: naming the file and line: missing or bad header, bad column
            row, a force that is not a number in [-1, 1] (NaN included), a missing,
            duplicate or out-of-order frame, or no rows at all.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{path}: not an ASCII human-file ({exc.reason} at byte {exc.start})") from None
    if not lines or lines[0].strip() != MAGIC:
        got = repr(lines[0][:40]) if lines else "an empty file"
        raise InputFileError(f"{path}: line 1: missing header: expected {MAGIC!r}, got {got}")
    if len(lines) < 2:
        raise InputFileError(f"{path}: line 2: missing header line after {MAGIC!r}")
    header = _parse_header(path, 2, lines[1].strip())
    i = 2
    while i < len(lines) and lines[i].startswith("#"):
        i += 1  # comments
    if i >= len(lines) or lines[i].strip() != COLUMNS:
        raise InputFileError(f"{path}: line {i + 1}: expected the column row {COLUMNS!r}")
    forces: list[float] = []
    first_seen: dict[int, int] = {}
    last_line = i + 1
    for lineno, raw in enumerate(lines[i + 1 :], start=i + 2):
        text = raw.strip()
        if not text:
            continue
        last_line = lineno
        where = f"{path}: line {lineno}"
        frame_text, sep, force_text = text.partition(",")
        try:
            if not sep:
                raise ValueError
            frame = plain_int(frame_text)
            force = plain_float(force_text)
        except ValueError:
            raise InputFileError(f"{where}: expected 'frame,force', got {text!r}") from None
        if not (math.isfinite(force) and -1.0 <= force <= 1.0):
            raise InputFileError(f"{where}: force {force_text.strip()} at frame {frame} is not a number in [-1, 1]")
        expected = len(forces)
        if frame in first_seen:
            raise InputFileError(f"{where}: duplicate frame {frame} (first on line {first_seen[frame]})")
        if frame != expected:
            what = "missing" if frame > expected else "out of order"
            raise InputFileError(f"{where}: frame {expected} is {what}: got frame {frame}")
        first_seen[frame] = lineno
        forces.append(force)
    if not forces:
        raise InputFileError(f"{path}: line {last_line}: no rows after the column row")
    return HumanFile(path, header, tuple(forces), header_line=2, last_line=last_line)


class HumanFileRecorder:
    """Writes a human-file row by row (flushed, so a closed window keeps what was driven).

    Args:
        path: file to write.
        header: what the run is driven against.
        comments: extra ``#`` lines, e.g. ``controller=keyboard``.
    """

    def __init__(self, path: str | Path, header: HumanFileHeader, comments: tuple[str, ...] = ()):
        self.path = Path(path)
        self.header = header
        self.comments = comments
        self._file: IO[str] | None = None
        self.rows = 0
        self._next_frame = 0

    def __enter__(self) -> HumanFileRecorder:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("w", newline="\n", encoding="ascii")
        self._file.write(MAGIC + "\n" + self.header.line() + "\n")
        for comment in self.comments:
            self._file.write(f"# {comment}\n")
        self._file.write(COLUMNS + "\n")
        self._file.flush()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file; safe to call twice."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def write(self, frame: int, force: float) -> None:
        """Append the force applied at ``frame``; frames must come in order from 0."""
        assert frame == self._next_frame, f"recorder got frame {frame}, expected {self._next_frame}"
        self._next_frame += 1
        self.rows += 1
        if self._file is not None:
            self._file.write(f"{frame},{float(force)!r}\n")
            self._file.flush()


@dataclass
class RecordingController:
    """Wraps a controller and records every force it returns to a human-file."""

    inner: Callable[[dict[str, Any]], float]
    recorder: HumanFileRecorder

    @property
    def log_columns(self) -> tuple[str, ...]:
        """The wrapped controller's own log columns (vacc drive's run log)."""
        return getattr(self.inner, "log_columns", ())

    @property
    def log_values(self) -> tuple[float, ...]:
        """Their values at the last decision."""
        return getattr(self.inner, "log_values", ())

    def reset(self) -> None:
        """Reset the wrapped controller."""
        reset = getattr(self.inner, "reset", None)
        if reset is not None:
            reset()

    @property
    def history_steps(self) -> int:
        """The wrapped controller's pre-roll (nothing is recorded before frame 0)."""
        return int(getattr(self.inner, "history_steps", 0))

    def warm(self, obs: dict[str, Any]) -> None:
        """Pass a pre-roll frame to the wrapped controller."""
        warm = getattr(self.inner, "warm", None)
        if warm is not None:
            warm(obs)

    def __call__(self, obs: dict[str, Any]) -> float:
        u = float(self.inner(obs))
        self.recorder.write(int(obs["frame"]), u)
        return u


@dataclass
class HumanFileController:
    """Replays a human-file's forces frame by frame.

    Args:
        human_file: the parsed file.
        pad: what to do past its last row: "error" (raise), "hold" (repeat the last
            force) or "zero" (coast at u = 0).
    """

    human_file: HumanFile
    pad: str = "error"

    name = "human-file"

    def __post_init__(self) -> None:
        if self.pad not in PADS:
            raise ValueError(f"pad {self.pad!r} is not one of {PADS}")

    def reset(self) -> None:
        """Nothing to forget: the forces are indexed by frame."""

    def __call__(self, obs: dict[str, Any]) -> float:
        """The recorded force at ``obs['frame']``.

        Raises:
            InputFileError: past the end of the file with pad "error".
        """
        frame = int(obs["frame"])
        forces = self.human_file.forces
        if frame < len(forces):
            return forces[frame]
        if self.pad == "hold":
            return forces[-1]
        if self.pad == "zero":
            return 0.0
        hf = self.human_file
        raise InputFileError(
            f"{hf.path}: line {hf.last_line}: the file ends at frame {len(forces) - 1}, before the "
            f"trajectory (t = {obs['t']:.1f} s, frame {frame} needs a force); "
            "use --pad hold or --pad zero to drive on"
        )
