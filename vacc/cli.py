"""The one `vacc` command group: a thin composition root.

Each side registers its own commands; this module only wires them together so that
``sim_server`` and ``agent_client`` never import each other.
"""

from __future__ import annotations

import click


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vacc")
def main() -> None:
    """vacc: vision-based adaptive cruise control over a UDP lockstep co-simulation."""


# Commands are attached below; keep this file free of logic.
from agent_client.cli import drive  # noqa: E402
from sim_server.cli import serve  # noqa: E402

main.add_command(serve)
main.add_command(drive)
from vacc.metrics_cmd import metrics  # noqa: E402
main.add_command(metrics)
from vacc.bench import bench  # noqa: E402

main.add_command(bench)
from vacc.demo import demo  # noqa: E402

main.add_command(demo)

from vacc.snapshot_cmd import snapshot  # noqa: E402
main.add_command(snapshot)
