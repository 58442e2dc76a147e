"""The one `vacc` command group: a thin composition root.

Each side owns its commands; this module only names where they live, so that
``sim_server`` and ``agent_client`` never import each other. Commands load lazily:
``vacc drive`` does not pay for importing torch, ``vacc serve`` not for gymnasium.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys

import click

from protocol.logs import LOG_LEVELS

COMMANDS = {
    "serve": "sim_server.cli:serve",
    "drive": "agent_client.cli:drive",
    "train": "agent_client.rl.cli:train",
    "checkpoint": "vacc.checkpoint_cmd:checkpoint",
    "metrics": "vacc.metrics_cmd:metrics",
    "snapshot": "vacc.snapshot_cmd:snapshot",
    "bench": "vacc.bench:bench",
    "demo": "vacc.demo:demo",
    "evaluate": "vacc.evaluate:evaluate",
    "gates": "vacc.gates:gates",
    "models": "vacc.models_cmd:models",
    "reproduce": "vacc.reproduce:reproduce_command",
    "seeds": "vacc.seeds_cmd:seeds",
    "video": "vacc.video:video",
    "plot": "vacc.plot:plot",
    "platoon": "vacc.platoon_cmd:platoon",
}


class LazyGroup(click.Group):
    """A group whose commands are imported when first used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = COMMANDS.get(cmd_name)
        if target is None:
            return None
        module, _, attr = target.partition(":")
        command = getattr(importlib.import_module(module), attr)
        assert isinstance(command, click.Command)
        return command


VERBOSITY = ("warning", "info", "debug")  # the level of no -v, -v, -vv


def configure_logging(level: str | None) -> None:
    """Show our log messages (the ``vacc.*`` loggers) from ``level`` up on stderr, and spawn
    servers at ``level``. None leaves Python's default: warnings and errors only."""
    if level is None:
        return
    from agent_client.launcher import SERVER_LOG_LEVEL_ENV

    os.environ[SERVER_LOG_LEVEL_ENV] = level  # the launcher reads it; actor processes and a local Ray inherit it
    logging.basicConfig(stream=sys.stderr, format="%(name)s: %(message)s")
    logging.getLogger("vacc").setLevel(level.upper())


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="Log more on stderr, here and in the simulator servers spawned: -v info (e.g. their counters at exit), -vv debug.")
@click.option("--log-level", type=click.Choice(LOG_LEVELS), default=None, help="The least severe log messages shown, here and in the simulator servers spawned (overrides -v and $VACC_SERVER_LOG_LEVEL).  [default: warning]")
@click.version_option(package_name="vacc")
def main(verbose: int, log_level: str | None) -> None:
    """vacc: vision-based adaptive cruise control over a UDP lockstep co-simulation."""
    configure_logging(log_level or (VERBOSITY[min(verbose, len(VERBOSITY) - 1)] if verbose else None))
