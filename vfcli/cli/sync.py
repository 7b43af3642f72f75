"""`vfcli sync`."""
from __future__ import annotations

import click

from vfcli.cli.common import store_command


@click.command("sync")
@store_command
def sync_cmd(ctx):  # type: ignore[no-untyped-def]
    """Align the sequential LDV epochs to the video through the subglottal pressure.

    Reads: /hsc, /ldv. Writes: /sync (per point: offset, f0, drift, quality, whether it
    aligned and why not, and the vertical velocity on the video's frame times).
    Config section [sync].
    """
    from vfcli.stages.sync import run_sync

    return run_sync(ctx)
