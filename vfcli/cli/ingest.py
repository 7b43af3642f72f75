"""`vfcli ingest-hsc` and `vfcli ingest-ldv`."""
from __future__ import annotations

import click

from vfcli.cli.common import store_command


@click.command("ingest-hsc")
@store_command
@click.argument("video", type=click.Path(exists=True))
@click.option("--pressure", type=click.Path(exists=True, dir_okay=False), help="Pressure recorded with the video (TDMS, CSV or WAV).")
def ingest_hsc_cmd(ctx, video: str, pressure: str | None):  # type: ignore[no-untyped-def]
    """Ingest the high-speed VIDEO (MRAW+CIHX/CIH, TIFF, image folder, AVI) and its pressure.

    Reads: raw files. Writes: /hsc (frames unchanged in bit depth, one frame per chunk,
    frame times; the pressure with its time axis). Config sections [ingest_hsc], [camera].
    """
    from vfcli.stages.ingest import run_ingest_hsc

    return run_ingest_hsc(ctx, video, pressure)


@click.command("ingest-ldv")
@store_command
@click.argument("scan", type=click.Path(exists=True, dir_okay=False))
def ingest_ldv_cmd(ctx, scan: str):  # type: ignore[no-untyped-def]
    """Ingest a scanning-vibrometer SCAN (Polytec UFF, CSV or MAT).

    Reads: raw files. Writes: /ldv (point coordinates in the camera frame, grid index,
    velocity and pressure reference per point, dropout flags). Config sections
    [ingest_ldv], [ldv_frame].
    """
    from vfcli.stages.ingest import run_ingest_ldv

    return run_ingest_ldv(ctx, scan)
