"""`vacc drive`: drive one episode with a controller and write the run log."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import functools
import importlib.metadata
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click
import numpy as np

from agent_client.controllers import CONTROLLERS, camera, make_controller
from agent_client.controllers.hdm import NAME as HDM_NAME
from agent_client.controllers.human_file import (
    PADS,
    HumanFile,
    HumanFileHeader,
    HumanFileRecorder,
    RecordingController,
    read_human_file,
    road_extra,
    start_extra,
    trajectory_label,
)
from agent_client.controllers.keyboard import (
    DrivingWindow,
    JoystickMap,
    KeyboardController,
    require_display,
    require_pygame,
)
from agent_client.drive import COLD_START_HELP, DriveSummary, drive_episode
from agent_client.errors import ClientError, FatalSessionError, SessionError
from agent_client.launcher import DEFAULT_ROAD, Road, local_server
from agent_client.outputs import writable_file_option, write_cause
from agent_client.runlog import COLUMNS, file_sha256, write_card
from agent_client.session import GIVE_UP, Session
from agent_client.traces import load_trace
from protocol.constants import (
    CAMERA_SIZE,
    MAX_FOLLOWERS,
    SUN_ELEVATION,
    TRAFFIC_PER_LANE,
    TRAFFIC_PER_LANE_RANGE,
)
from protocol.faults import FaultConfig
from protocol.options import SunElevation, key_option
from protocol.scenarios import (
    DEFAULT_SET_SPEED,
    RANDOM,
    SCENARIOS,
    TEST_DURATION,
    TEST_TRAJECTORIES,
    TRAJECTORIES,
    check_initial,
)

LIVE_IMAGE = CAMERA_SIZE  # [px] the live window asks for the full camera (shown scaled up)


def parse_hostport(value: str) -> tuple[str, int]:
    """'HOST:PORT' to (host, port).

    Raises:
        click.BadParameter: if it is not of that form.
    """
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise click.BadParameter(f"{value!r} is not HOST:PORT", param_hint="--server")
    if not 0 < int(port) < 65536:
        raise click.BadParameter(f"{value!r}: port {int(port)} is out of range (1..65535)", param_hint="--server")
    return host.strip("[]"), int(port)


def parse_faults(ctx: click.Context, param: click.Parameter, value: str | None) -> FaultConfig | None:
    if not value:
        return None
    try:
        return FaultConfig.parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


def parse_joystick_map(ctx: click.Context, param: click.Parameter, value: str) -> JoystickMap:
    try:
        return JoystickMap.parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


def load_lead(trajectory: str) -> tuple[np.ndarray, np.ndarray] | None:
    """None for a named trajectory, else the (times [s], speeds [m/s]) of a CSV trace.

    Raises:
        click.BadParameter: one line: an unknown name, or what is wrong with the file.
    """
    if trajectory in TRAJECTORIES:
        return None
    if not Path(trajectory).exists():  # a mistyped name or path: say both what exists and what was meant
        what = "no such trace file" if trajectory.lower().endswith(".csv") else "unknown trajectory"
        raise click.BadParameter(f"{what} {trajectory!r}; expected one of {', '.join(TRAJECTORIES)} or an existing PATH.csv", param_hint="--trajectory")
    try:
        return load_trace(trajectory)
    except ClientError as exc:
        raise click.BadParameter(str(exc), param_hint="--trajectory") from None


def check_start(host_speed: float | None, gap: float | None, set_speed: float) -> None:
    """Check --host-speed, --gap and --set-speed before a server is spawned.

    Raises:
        click.BadParameter: one line naming the option and its range.
    """
    for hint, values in (
        ("--set-speed", {"set_speed": set_speed}),
        ("--host-speed", {"set_speed": set_speed, "host_speed": host_speed}),
        ("--gap", {"set_speed": set_speed, "gap": gap}),
    ):
        try:
            check_initial(host_speed=values.get("host_speed"), gap=values.get("gap"), set_speed=values["set_speed"])
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint=hint) from None


def run_card(
    *, episode: dict[str, Any], welcome: dict[str, Any] | None, addr: tuple[str, int], spawned: bool, controller: str,
    checkpoint: str | None, human_file: str | None, faults: FaultConfig | None, server_faults: str | None, columns: tuple[str, ...],
) -> dict[str, Any]:
    """The card of a ``vacc drive`` run (:func:`agent_client.runlog.write_card`), its end still open."""
    w = welcome or {}
    trace = episode["trajectory"] if episode["trajectory"] not in TRAJECTORIES else None
    return {
        "written": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "vacc": importlib.metadata.version("vacc"),
        "episode": {**episode, "trace_sha256": file_sha256(trace) if trace else None},
        "road": {
            "traffic": w.get("traffic"), "sun_elevation": w.get("sun_elevation"),  # None: a server older than protocol 5 does not say
            "seed_salt": w.get("seed_salt"), "server": w.get("server"), "address": f"{addr[0]}:{addr[1]}", "spawned": spawned,
            "protocol": w.get("version"), "control_period": w.get("control_period"), "physics_dt": w.get("physics_dt"),
            **({"seat": w["seat"], "seats": w["seats"]} if "seat" in w else {}),  # a platoon's seat: car seat + 1 behind the lead
        },
        "controller": {
            "name": controller,
            "checkpoint": checkpoint, "checkpoint_sha256": file_sha256(checkpoint) if checkpoint else None,
            "human_file": human_file, "human_file_sha256": file_sha256(human_file) if human_file else None,
        },
        "faults": {"client": dataclasses.asdict(faults) if faults else None, "server": server_faults},
        "columns": list(COLUMNS + columns),
        "end": None,
    }  # fmt: skip


@contextlib.contextmanager
def server_address(server: str | None, *server_args: str) -> Iterator[tuple[str, int]]:
    """The given server, or a local server process spawned (and reaped) for the block."""
    if server is not None:
        yield parse_hostport(server)
        return
    with local_server(*server_args) as addr:
        yield addr


@dataclasses.dataclass(frozen=True)
class DriveEpisode:
    """The episode a ``vacc drive`` run asks the server for."""

    scenario: str  # "ice" | "ev"
    trajectory: str  # a name of TRAJECTORIES, or a CSV trace's path
    seed: int
    start: dict[str, float | None]  # set_speed, host_speed [m/s] and gap [m]; None: drawn
    duration: float | None  # [s]; None: to the trajectory's end
    cold_start: bool  # no camera pre-roll before the controller engages
    trace: tuple[np.ndarray, np.ndarray] | None  # a CSV trace's (times [s], speeds [m/s])


def spawned_road(server: str | None, traffic: int, sun_elevation: tuple[float, float]) -> Road:
    """The road a spawned server is started with; a ``--server`` one keeps its own.

    Raises:
        click.UsageError: ``--traffic`` or ``--sun-elevation`` changed with ``--server``.
    """
    road = Road(traffic, sun_elevation)
    if server is not None and road != DEFAULT_ROAD:
        option = f"--traffic {traffic}" if traffic != TRAFFIC_PER_LANE else "--sun-elevation " + ",".join(map(str, sun_elevation))
        raise click.UsageError(f"{option} sets a spawned server's road; start the --server one with vacc serve {option}")
    return road


def load_replay(human_file: str | None, *, scenario: str, trajectory: str, seed: int, start: dict[str, float | None]) -> HumanFile:
    """The human-file ``--controller human-file`` replays, checked against the episode.

    Raises:
        click.UsageError: no ``--human-file``.
        click.ClickException: the file is unreadable or was recorded on another episode.
    """
    if human_file is None:
        raise click.UsageError("--controller human-file needs --human-file PATH")
    try:
        replay = read_human_file(human_file)
        replay.check(scenario=scenario, trajectory=trajectory, seed=seed, **start)
    except ClientError as exc:
        raise click.ClickException(str(exc)) from None
    return replay


def controller_before_server(
    controller: str, *, server: str | None, seed: int, checkpoint: str | None, replay: HumanFile | None, pad: str,
) -> Any:
    """The controller, built before a server is spawned; None for ``keyboard``, which is
    built inside its window (:func:`open_keyboard`) once the session is open.

    Raises:
        click.ClickException: ``keyboard`` without pygame or a display.
        click.UsageError: ``ddqn`` without ``--checkpoint``.
        click.BadParameter: a checkpoint (or controller) that cannot be loaded.
    """
    if controller == "keyboard":
        try:
            require_pygame()  # fail before a server is spawned
            require_display()
        except ClientError as exc:
            raise click.ClickException(str(exc)) from None
        if server is not None:
            click.echo("note: --server given: start it with 'vacc serve --realtime' to drive at wall-clock speed", err=True)
        return None
    if controller == "ddqn" and checkpoint is None:
        raise click.UsageError("--controller ddqn needs --checkpoint PATH")
    try:
        return make_controller(controller, seed=seed, checkpoint=checkpoint, human_file=replay, pad=pad)
    except ClientError as exc:
        raise click.BadParameter(str(exc), param_hint="--checkpoint") from None


def check_scenario(policy: Any, scenario: str, checkpoint: str | None) -> None:
    """A model drives only the scenario it was trained for: the other one's leads and
    vehicle are not what its policy learned, so the run would be silently wrong.

    Raises:
        click.ClickException: one line naming both scenarios.
    """
    trained = getattr(getattr(policy, "cfg", None), "scenario", None)
    if trained is not None and trained != scenario:
        raise click.ClickException(f"--checkpoint {checkpoint}: trained for the {trained} scenario, not --scenario {scenario}; "
                                   f"give --scenario {trained}, or a checkpoint of {scenario}")  # fmt: skip


def spawn_args(road: Road, *, server_faults: str | None, realtime: bool, key_file: str | None) -> tuple[list[str], bytes | None]:
    """A spawned server's arguments, and the shared key of ``key_file`` (None without one).

    Raises:
        click.BadParameter: an unreadable or malformed key file.
    """
    server_args = (["--faults", server_faults] if server_faults else []) + (["--realtime"] if realtime else []) + list(road.server_args())
    key = key_option(key_file)
    if key_file is not None:
        server_args += ["--key-file", key_file]
    return server_args, key


def open_keyboard(period: float, stack: contextlib.ExitStack, *, window_scale: int, joystick: int, joystick_map: JoystickMap) -> KeyboardController:
    """The keyboard (and pedals) controller in a driving window that ``stack`` closes.

    Args:
        period: the session's control period [s].
        joystick: SDL index of the pedals' device; -1: none.
    """
    window = DrivingWindow(scale=window_scale)
    stack.callback(window.close)
    return KeyboardController(period, window, joystick=None if joystick < 0 else joystick, joystick_map=joystick_map)


def drive_logged(
    episode: DriveEpisode, policy: Any, *, server: str | None, server_args: list[str], controller: str, replay: HumanFile | None,
    keyboard: Callable[[float, contextlib.ExitStack], Any] | None, faults: FaultConfig | None, session_options: dict[str, Any],
    checkpoint: str | None, human_file: str | None, server_faults: str | None, log_path: str, record_path: str | None,
    watch: Callable[[contextlib.ExitStack], Callable[[dict[str, Any]], None] | None] | None = None,
) -> tuple[dict[str, Any], DriveSummary]:
    """Open the session, write the card, drive the episode into ``log_path``; the card (its
    end still open) and the summary.

    Args:
        keyboard: builds the live controller from the control period, or None when
            ``policy`` drives.
        faults: faults injected on the client's sends.
        session_options: the :class:`Session`'s other keywords (give_up, image_format, image_size, key).
        watch: builds, once the session is open, what sees every observation (the live view,
            the progress bar), closed by the stack it is given; it only reads them.

    Raises:
        click.ClickException: the session failed (the card, once written, says so) or
            another client error.
    """
    ep, start = episode, episode.start
    card: dict[str, Any] | None = None
    try:
        with (
            server_address(server, *server_args) as addr,
            Session(addr, faults=faults, client_name=f"vacc-drive/{controller}", **session_options) as session,
            contextlib.ExitStack() as stack,
        ):
            period = float(session.welcome["control_period"]) if session.welcome else 0.1
            if replay is not None:
                replay.check(scenario=ep.scenario, trajectory=ep.trajectory, seed=ep.seed, control_period=period, **start)
            if keyboard is not None:
                policy = keyboard(period, stack)
            card = run_card(
                episode={"scenario": ep.scenario, "trajectory": ep.trajectory, "seed": ep.seed, **start, "duration": ep.duration,
                         "preroll": 0 if ep.cold_start else getattr(policy, "history_steps", 0)},
                welcome=session.welcome, addr=addr, spawned=server is None, controller=controller, checkpoint=checkpoint,
                human_file=human_file, faults=faults, server_faults=server_faults, columns=getattr(policy, "log_columns", ()),
            )  # fmt: skip
            write_card(log_path, card)  # before the first row: an interrupted run keeps its card
            if record_path is not None:
                header = HumanFileHeader(ep.scenario, trajectory_label(ep.trajectory), ep.seed, period, duration=ep.duration, extra={**start_extra(**start), **road_extra(session.welcome)})
                recorder = stack.enter_context(HumanFileRecorder(record_path, header, (f"controller={controller}",)))
                policy = RecordingController(policy, recorder)
            summary = drive_episode(
                session, policy, scenario=ep.scenario, seed=ep.seed, trajectory=ep.trajectory, trace=ep.trace,
                duration=ep.duration, log=Path(log_path), **start, preroll=0 if ep.cold_start else None,
                on_step=watch(stack) if watch is not None else None,
            )  # fmt: skip
    except (FatalSessionError, SessionError) as exc:
        if card is None:  # no session, so no card and no log: name none
            raise click.ClickException(str(exc)) from None
        write_card(log_path, {**card, "end": {"error": str(exc)}})
        raise click.ClickException(f"{exc} (log so far: {log_path})") from None
    except ClientError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:  # a log or record write (a full disk): one line naming the file
        raise click.ClickException(f"{exc.filename or log_path}: could not be written: {write_cause(exc)}") from None
    assert card is not None  # written before the episode
    return card, summary


PROGRESS_AFTER = 2.0  # [s] of wall time before a drive's progress bar shows: short runs stay quiet
PROGRESS_EVERY = 10  # [control steps] between the bar's updates


def expected_seconds(episode: DriveEpisode) -> float | None:
    """How long [s] of simulated time the episode runs, where known before it starts (the tests,
    a random lead, a --duration); None for a lead scenario or a trace (the bar then counts up)."""
    whole = TEST_DURATION if episode.trajectory in (*TEST_TRAJECTORIES, RANDOM) else None
    if episode.duration is None:
        return whole
    return episode.duration if whole is None else min(episode.duration, whole)


def watchers(episode: DriveEpisode, *, view: bool, progress: bool) -> Callable[[contextlib.ExitStack], Callable[[dict[str, Any]], None] | None]:
    """What sees each observation of a drive: the live view (``--view``) and a progress bar of
    simulated against wall time (on a terminal, once a run has taken over :data:`PROGRESS_AFTER`)."""

    def build(stack: contextlib.ExitStack) -> Callable[[dict[str, Any]], None] | None:
        calls: list[Callable[[dict[str, Any]], None]] = []
        if view:
            from agent_client.view import LiveView

            live = LiveView(title=f"vacc drive --view: {episode.scenario}/{Path(episode.trajectory).name} (seed {episode.seed})")
            stack.callback(live.close)
            calls.append(live)
        if progress:
            from agent_client.progress import progress_bar

            total = expected_seconds(episode)
            shape = "{percentage:3.0f}%|{bar}| {n:.1f}/{total_fmt}" if total is not None else "{n:.1f}"
            bar = stack.enter_context(progress_bar(
                total, "drive", unit="s", delay=PROGRESS_AFTER,  # type: ignore[arg-type]
                bar_format="{desc}: " + shape + " s simulated in {elapsed} wall ({rate_fmt})",
            ))  # fmt: skip

            def advance(obs: dict[str, Any]) -> None:
                if obs["frame"] % PROGRESS_EVERY == 0 or obs["terminated"] or obs["truncated"]:  # a bar update costs more than a step
                    bar.update(max(0.0, float(obs["t"]) - bar.n))

            calls.append(advance)
        if len(calls) <= 1:
            return calls[0] if calls else None

        def both(obs: dict[str, Any]) -> None:
            for call in calls:
                call(obs)

        return both

    return build


def check_view(view: bool, controller: str) -> None:
    """Refuse ``--view`` before a server is spawned: with the keyboard (it has its own window),
    without pygame, or without a display (the keyboard driver's one line).

    Raises:
        click.UsageError, click.ClickException: one line.
    """
    if not view:
        return
    if controller == "keyboard":
        raise click.UsageError("--view: the keyboard driver shows its own window; leave --view out")
    try:
        require_pygame()
        require_display()
    except ClientError as exc:
        raise click.ClickException(str(exc)) from None


def echo_summary(summary: DriveSummary, episode: DriveEpisode, *, controller: str, log_path: str, record_path: str | None) -> None:
    """Print what was driven, where it was written, and the run's summary lines."""
    if record_path is not None:
        click.echo(f"human-file -> {record_path}")
    trajectory = episode.trajectory if episode.trace is None else Path(episode.trajectory).name
    click.echo(f"{HDM_NAME if controller == 'hdm' else controller} on {episode.scenario}/{trajectory} (seed {episode.seed}) -> {log_path}")
    for line in summary.lines():
        click.echo("  " + line)


@click.command("drive")
@click.option("--controller", required=True, type=click.Choice(CONTROLLERS), help="Who drives.")
@click.option("--server", default=None, metavar="HOST:PORT", help="Use this server; default: spawn a local one.")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(SCENARIOS))
@click.option("--trajectory", default="test-1", show_default=True, metavar="{test-1..test-4,random,SCENARIO,PATH.csv}", help=f"Lead trajectory: {', '.join(TRAJECTORIES)} (lead scenarios: docs/scenarios.md), or a CSV speed trace t_s,speed_mps, driven as given.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode seed: initial conditions, traffic, scenery, scenario parameters.")
@click.option("--host-speed", default=None, type=float, metavar="M/S", help="Host's initial speed [m/s], 0..set speed. Default: drawn from the seed (a CSV trace: the lead's first speed).")
@click.option("--gap", default=None, type=float, metavar="M", help="Initial gap [m], (0, 300). Default: drawn from the seed.")
@click.option("--set-speed", default=DEFAULT_SET_SPEED, show_default=True, type=float, metavar="M/S", help="Cruise set speed [m/s]: the host never drives faster; the ACC cruises at it.")
@click.option("--checkpoint", default=None, type=click.Path(dir_okay=False), help="DDQN checkpoint (--controller ddqn).")
@click.option("--cold-start", is_flag=True, help=COLD_START_HELP)
@click.option("--human-file", default=None, type=click.Path(dir_okay=False), help="Recorded forces (--controller human-file).")
@click.option("--log", "log_path", required=True, type=click.Path(dir_okay=False, writable=True), callback=writable_file_option, help="Run log CSV to write.")
@click.option("--duration", default=None, type=click.FloatRange(min=0.1), help="Stop after this many simulated seconds.")
@click.option("--faults", callback=parse_faults, default=None, help="Inject faults on the client's sends, e.g. 'drop=0.1,dup=0.05,reorder=0.05'.")
@click.option("--traffic", default=TRAFFIC_PER_LANE, show_default=True, type=click.IntRange(*TRAFFIC_PER_LANE_RANGE), help="Cars in each adjacent lane (twice as many oncoming) of the spawned server; with --server, start it with vacc serve --traffic.")
@click.option("--sun-elevation", default=",".join(map(str, SUN_ELEVATION)), show_default=True, type=SunElevation(), help="Range [rad] the spawned server draws the sun's height from (random leads and lead scenarios); with --server, start it with vacc serve --sun-elevation.")
@click.option("--server-faults", default=None, help="Faults for the spawned server's sends (same syntax).")
@click.option("--give-up", default=GIVE_UP, show_default=True, type=click.FloatRange(min=0.1), help="Seconds without a reply before the run fails.")
@click.option("--key-file", default=None, type=click.Path(dir_okay=False), help="Shared key of the server (vacc serve --key-file): every datagram carries a MAC.")
@click.option("--quiet", is_flag=True, help="Print no summary.")
@click.option("--record", "record_path", default=None, type=click.Path(dir_okay=False, writable=True), callback=writable_file_option, help="Also write the forces driven as a human-file (docs/human.md).")
@click.option("--pad", default="error", show_default=True, type=click.Choice(PADS), help="--controller human-file: past the file's end, fail, hold the last force, or coast at 0.")
@click.option("--realtime/--no-realtime", default=None, help="Spawn the server paced to the wall clock. Default: on for --controller keyboard only.")
@click.option("--joystick", default=0, show_default=True, type=int, help="--controller keyboard: SDL index of the joystick/wheel whose pedals to read, if plugged in; -1: none.")
@click.option("--joystick-map", default="throttle=1,brake=2,released=1,pressed=-1,deadzone=0.05", show_default=True, callback=parse_joystick_map, help="Pedal axes and raw travel (G27-style default).")
@click.option("--window-scale", default=2, show_default=True, type=click.IntRange(1, 4), help="--controller keyboard: zoom of the 400x400 camera image.")
@click.option("--seat", default=None, type=click.IntRange(0, MAX_FOLLOWERS - 1), help="Take this seat of a platoon server's (vacc serve --followers; needs --server), 0 nearest the lead. Default: the first free one there.")
@click.option("--view", is_flag=True, help="Watch the run in a window: the camera, a head-up strip (speed, set speed, gap, acceleration, force) and a scrolling plot of gap and speed. The log is the same as without it.")
def drive(
    controller: str,
    server: str | None,
    scenario: str,
    trajectory: str,
    seed: int,
    host_speed: float | None,
    gap: float | None,
    set_speed: float,
    checkpoint: str | None,
    cold_start: bool,
    human_file: str | None,
    log_path: str,
    duration: float | None,
    faults: FaultConfig | None,
    traffic: int,
    sun_elevation: tuple[float, float],
    server_faults: str | None,
    give_up: float,
    key_file: str | None,
    quiet: bool,
    record_path: str | None,
    pad: str,
    realtime: bool | None,
    joystick: int,
    joystick_map: JoystickMap,
    window_scale: int,
    seat: int | None,
    view: bool,
) -> None:
    """Drive one episode with a controller over UDP and write the run log.

    The log has one row per control step: t,frame,v_host,v_lead,gap,accel,force,
    collision,a_lead (SI units), then gap_est for a DDQN model with a gap head
    (vacc train --aux-gap). Beside it, LOG's card (run.csv -> run.card.json) says
    what the CSV cannot: the episode asked for, the road (the server's traffic, sun
    range and seed salt), the controller and its checkpoint's SHA-256, and how the run ended.
    Exits non-zero if the server is lost.
    """
    check_start(host_speed, gap, set_speed)
    check_view(view, controller)
    if seat is not None and server is None:
        raise click.UsageError("--seat needs --server: a platoon server's address (vacc serve --followers N, or vacc platoon)")
    road = spawned_road(server, traffic, sun_elevation)
    trace = load_lead(trajectory)
    start = {"set_speed": set_speed, "host_speed": host_speed, "gap": gap}
    replay = None
    if controller == "human-file":
        replay = load_replay(human_file, scenario=scenario, trajectory=trajectory, seed=seed, start=start)
        duration = replay.header.duration if duration is None else duration
    policy = controller_before_server(controller, server=server, seed=seed, checkpoint=checkpoint, replay=replay, pad=pad)
    check_scenario(policy, scenario, checkpoint)
    live = controller == "keyboard"
    realtime = live if realtime is None else realtime
    server_args, key = spawn_args(road, server_faults=server_faults, realtime=realtime, key_file=key_file)
    image_format, image_size = ("rgb", LIVE_IMAGE) if live else camera(policy)  # a DDQN checkpoint's zoom decides
    if view and image_format == "none":  # a controller that needs no camera: the view shows the full one
        image_format, image_size = "rgb", LIVE_IMAGE
    episode = DriveEpisode(scenario, trajectory, seed, start, duration, cold_start, trace)
    keyboard = functools.partial(open_keyboard, window_scale=window_scale, joystick=joystick, joystick_map=joystick_map) if live else None
    card, summary = drive_logged(
        episode, policy, server=server, server_args=server_args, controller=controller, replay=replay, keyboard=keyboard,
        faults=faults, session_options={"give_up": give_up, "image_format": image_format, "image_size": image_size, "key": key, "seat": seat},
        checkpoint=checkpoint, human_file=human_file, server_faults=server_faults, log_path=log_path, record_path=record_path,
        watch=watchers(episode, view=view, progress=not live and sys.stderr.isatty()),
    )  # fmt: skip
    write_card(log_path, {**card, "end": dataclasses.asdict(summary)})
    if not quiet:
        echo_summary(summary, episode, controller=controller, log_path=log_path, record_path=record_path)
    sys.stdout.flush()
