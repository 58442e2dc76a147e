"""The one `vacc` command group: a thin composition root.

Each side owns its commands; this module only names where they live, so that
``sim_server`` and ``agent_client`` never import each other. Commands load lazily:
``vacc drive`` does not pay for importing torch, ``vacc serve`` not for gymnasium.
"""

from __future__ import annotations

import importlib

import click

COMMANDS = {
    "serve": "sim_server.cli:serve",
    "drive": "agent_client.cli:drive",
    "train": "agent_client.rl.cli:train",
    "metrics": "vacc.metrics_cmd:metrics",
    "snapshot": "vacc.snapshot_cmd:snapshot",
    "bench": "vacc.bench:bench",
    "demo": "vacc.demo:demo",
    "evaluate": "vacc.evaluate:evaluate",
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


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vacc")
def main() -> None:
    """vacc: vision-based adaptive cruise control over a UDP lockstep co-simulation."""
