"""`vfcli flow FILE`: gap, opening and optical flow, then the tri-variate velocity field."""
from __future__ import annotations

import click

from vfcli.cli.common import store_command


@click.command("flow")
@store_command
def flow_cmd(ctx):  # type: ignore[no-untyped-def]
    """Segment the gap, compute the optical flow and the surface velocity field (config section [flow]).

    Reads: /hsc, /sync, /ldv. Writes: /flow, /fields. /flow holds the gap mask, glottal
    area, opening function and horizontal velocity (u, v) per frame; /fields the
    velocity (u, v, w), with w the thin-plate spline of the synced LDV points, and where
    it is valid.
    """
    from vfcli.stages.flow import run_flow

    return run_flow(ctx)
