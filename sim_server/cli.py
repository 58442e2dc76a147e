"""`vacc serve` / `python -m sim_server`: run one simulator server."""

from __future__ import annotations

import logging
import signal
import sys

import click

from protocol.constants import (
    MAX_FOLLOWERS,
    SUN_ELEVATION,
    TRAFFIC_PER_LANE,
    TRAFFIC_PER_LANE_RANGE,
)
from protocol.faults import FaultConfig
from protocol.fragment import DEFAULT_DATAGRAM, MAX_DATAGRAM, MIN_DATAGRAM
from protocol.logs import LOG_LEVELS
from protocol.options import SunElevation, key_option
from protocol.transport import is_loopback
from sim_server.seats import JOIN_TIMEOUT, SEAT_TIMEOUT
from sim_server.server import ServerConfig, SimServer
from sim_server.world import WorldConfig


def _faults(ctx: click.Context, param: click.Parameter, value: str | None) -> FaultConfig | None:
    if not value:
        return None
    try:
        return FaultConfig.parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


log = logging.getLogger("vacc.server")


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind.")
@click.option("--port", default=47800, show_default=True, type=click.IntRange(0, 65535), help="UDP port; 0 picks a free one.")
@click.option("--seed", default=0, show_default=True, type=int, help="Salt mixed into every episode seed.")
@click.option("--realtime", is_flag=True, help="Pace the world to the wall clock (for a human driver).")
@click.option("--substeps", default=5, show_default=True, type=click.IntRange(1, 1000), help="Physics steps of 0.02 s per control step.")
@click.option("--traffic", default=TRAFFIC_PER_LANE, show_default=True, type=click.IntRange(*TRAFFIC_PER_LANE_RANGE), help="Cars in each adjacent lane (twice as many oncoming), drawn from the episode seed.")
@click.option("--sun-elevation", default=",".join(map(str, SUN_ELEVATION)), show_default=True, type=SunElevation(), help="Range [rad] each episode's sun height is drawn from (random leads and lead scenarios); a low sun throws long shadows across the road.")
@click.option("--session-timeout", default=10.0, show_default=True, type=click.FloatRange(0.1, 3600), help="Seconds of silence before a client's session is freed.")
@click.option("--faults", callback=_faults, default=None, help="Inject faults on sends, e.g. 'drop=0.1,dup=0.05,reorder=0.05,seed=1'.")
@click.option("--max-datagram", default=DEFAULT_DATAGRAM, show_default=True, type=click.IntRange(MIN_DATAGRAM, MAX_DATAGRAM), help="Largest datagram sent, bytes (use ~1400 across a real network).")
@click.option("--allow-remote", is_flag=True, help="Allow binding an address other than loopback (needs --key-file).")
@click.option("--key-file", default=None, type=click.Path(dir_okay=False), help="Shared key: every datagram both ways carries a MAC; clients need the same file.")
@click.option("--followers", default=0, show_default=True, type=click.IntRange(0, MAX_FOLLOWERS), help=f"Host a platoon of this many followers (1..{MAX_FOLLOWERS}), one client per seat; 0: one car.")
@click.option("--seat-timeout", default=SEAT_TIMEOUT, show_default=True, type=click.FloatRange(0.1, 3600), help="Platoon: seconds to wait for a seat's action once another seat's came, then end every seat's session, naming it.")
@click.option("--join-timeout", default=JOIN_TIMEOUT, show_default=True, type=click.FloatRange(0.1, 3600), help="Platoon: seconds to wait for every seat's reset, from the first join or reset.")
@click.option("--max-seconds", default=None, type=click.FloatRange(0), help="Exit after this many seconds (for scripts).")
@click.option("--parent-pid", default=None, type=int, help="Exit when this process dies (set by launchers).")
@click.option("--log-level", default="info", show_default=True, type=click.Choice(LOG_LEVELS), help="Least severe log messages shown on stderr (the stats line at exit is info; spawned servers default to warning, see `vacc --log-level`).")
def serve(
    host: str,
    port: int,
    seed: int,
    realtime: bool,
    substeps: int,
    traffic: int,
    sun_elevation: tuple[float, float],
    session_timeout: float,
    faults: FaultConfig | None,
    max_datagram: int,
    allow_remote: bool,
    key_file: str | None,
    followers: int,
    seat_timeout: float,
    join_timeout: float,
    max_seconds: float | None,
    parent_pid: int | None,
    log_level: str,
) -> None:
    """Run a simulator server: one world, lockstep over UDP (a platoon with --followers).

    Prints 'vacc-server listening on HOST:PORT' on stdout once bound, then serves until
    interrupted. Counters of served and rejected datagrams are printed at exit.
    """
    logging.basicConfig(stream=sys.stderr, level=log_level.upper(), format="%(message)s")  # a no-op under `vacc -v`: it set logging up
    if click.get_current_context().get_parameter_source("log_level") is click.ParameterSource.COMMANDLINE:
        log.setLevel(log_level.upper())  # this command's own option wins over the group's
    key = key_option(key_file)
    if realtime and followers:
        raise click.UsageError("--realtime paces one car to a human's wall clock; a platoon (--followers) is not paced")
    if not is_loopback(host):
        if not allow_remote:
            raise click.UsageError(f"--host {host} is not a loopback address; pass --allow-remote to bind it")
        if key is None:
            raise click.UsageError("--allow-remote needs --key-file: a reachable simulator must authenticate its clients")
        click.echo(f"warning: binding {host}: the simulator is reachable from the network (datagrams authenticated)", err=True)
    config = ServerConfig(
        host=host,
        port=port,
        seed=seed,
        realtime=realtime,
        session_timeout=session_timeout,
        world=WorldConfig(substeps=substeps, traffic_per_lane=traffic, sun_elevation=sun_elevation),
        faults=faults,
        max_datagram=max_datagram,
        parent_pid=parent_pid,
        key=key,
        followers=followers,
        seat_timeout=seat_timeout,
        join_timeout=join_timeout,
    )
    try:
        server = SimServer(config)
    except OSError as exc:
        raise click.ClickException(f"cannot bind {host}:{port}: {exc.strerror or exc}") from None
    with server:
        signal.signal(signal.SIGTERM, lambda *_: server.stop())
        h, p = server.address
        click.echo(f"vacc-server listening on {h}:{p}")
        sys.stdout.flush()
        try:
            server.serve(max_seconds=max_seconds)
        except KeyboardInterrupt:
            pass
        finally:
            log.info("vacc-server stats: %s", server.stats_line())
