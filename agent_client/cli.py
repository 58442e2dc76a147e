"""`vacc drive`: drive one episode with a controller and write the run log."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path

import click

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.errors import ClientError, FatalSessionError, SessionError
from agent_client.launcher import local_server
from agent_client.session import GIVE_UP, Session
from agent_client.traces import load_trace
from protocol.faults import FaultConfig

CONTROLLERS = ("acc", "hdm", "ddqn", "human-file", "keyboard")
TEST_TRAJECTORIES = ("test-1", "test-2", "test-3", "test-4", "random")


def parse_hostport(value: str) -> tuple[str, int]:
    """'HOST:PORT' to (host, port).

    Raises:
        click.BadParameter: if it is not of that form.
    """
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise click.BadParameter(f"{value!r} is not HOST:PORT")
    return host.strip("[]"), int(port)


def parse_faults(ctx: click.Context, param: click.Parameter, value: str | None) -> FaultConfig | None:
    if not value:
        return None
    try:
        return FaultConfig.parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


@contextlib.contextmanager
def server_address(server: str | None, *server_args: str) -> Iterator[tuple[str, int]]:
    """The given server, or a local server process spawned (and reaped) for the block."""
    if server is not None:
        yield parse_hostport(server)
        return
    with local_server(*server_args) as addr:
        yield addr


@click.command("drive")
@click.option("--controller", required=True, type=click.Choice(CONTROLLERS), help="Who drives.")
@click.option("--server", default=None, metavar="HOST:PORT", help="Use this server; default: spawn a local one.")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(["ice", "ev"]))
@click.option("--trajectory", default="test-1", show_default=True, metavar="{test-1..test-4,random,PATH.csv}", help="Lead trajectory, or a CSV speed trace t_s,speed_mps.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode seed: initial conditions, traffic, scenery.")
@click.option("--checkpoint", default=None, type=click.Path(dir_okay=False), help="DDQN checkpoint (--controller ddqn).")
@click.option("--human-file", default=None, type=click.Path(dir_okay=False), help="Recorded forces (--controller human-file).")
@click.option("--log", "log_path", required=True, type=click.Path(dir_okay=False, writable=True), help="Run log CSV to write.")
@click.option("--duration", default=None, type=click.FloatRange(min=0.1), help="Stop after this many simulated seconds.")
@click.option("--faults", callback=parse_faults, default=None, help="Inject faults on the client's sends, e.g. 'drop=0.1,dup=0.05,reorder=0.05'.")
@click.option("--server-faults", default=None, help="Faults for the spawned server's sends (same syntax).")
@click.option("--give-up", default=GIVE_UP, show_default=True, type=click.FloatRange(min=0.1), help="Seconds without a reply before the run fails.")
@click.option("--quiet", is_flag=True, help="Print no summary.")
def drive(
    controller: str,
    server: str | None,
    scenario: str,
    trajectory: str,
    seed: int,
    checkpoint: str | None,
    human_file: str | None,
    log_path: str,
    duration: float | None,
    faults: FaultConfig | None,
    server_faults: str | None,
    give_up: float,
    quiet: bool,
) -> None:
    """Drive one episode with a controller over UDP and write the run log.

    The log has one row per control step: t,frame,v_host,v_lead,gap,accel,force,
    collision,a_lead (SI units). Exits non-zero if the server is lost.
    """
    if controller != "acc":
        raise click.UsageError(f"--controller {controller} is not available yet in this version; use --controller acc")
    policy = AccController()
    trace = None
    if trajectory not in TEST_TRAJECTORIES:
        try:
            trace = load_trace(trajectory)
        except ClientError as exc:
            raise click.BadParameter(str(exc), param_hint="--trajectory") from None
    server_args = ["--faults", server_faults] if server_faults else []
    try:
        with server_address(server, *server_args) as addr, Session(addr, give_up=give_up, faults=faults, client_name=f"vacc-drive/{controller}") as session:
            summary = drive_episode(
                session, policy, scenario=scenario, seed=seed, trajectory=trajectory, trace=trace,
                duration=duration, log=Path(log_path),
            )  # fmt: skip
    except (FatalSessionError, SessionError) as exc:
        raise click.ClickException(f"{exc} (log so far: {log_path})") from None
    except ClientError as exc:
        raise click.ClickException(str(exc)) from None
    if not quiet:
        click.echo(f"{controller} on {scenario}/{trajectory if trace is None else Path(trajectory).name} (seed {seed}) -> {log_path}")
        for line in summary.lines():
            click.echo("  " + line)
    sys.stdout.flush()
