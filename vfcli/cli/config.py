"""`vfcli config FILE`: store or update a recording's config, or show it."""
from __future__ import annotations

import click

from vfcli.stages.base import save_recording_config
from vfcli.cli.common import store_command


@click.command("config")
@store_command
@click.option("--show", is_flag=True, help="Print the effective config (stored + --set) as JSON.")
def config_cmd(ctx, show: bool):  # type: ignore[no-untyped-def]
    """Store the recording config given with --config (creates FILE if needed).

    Reads and writes the root attribute with the recording config; no stage.
    """
    from vfcli.stages.base import StageResult

    if show:
        click.echo(ctx.config.model_dump_json(indent=2))
        return []
    changed = save_recording_config(ctx)
    return StageResult("/ (recording config)", "written" if changed else "up-to-date")
