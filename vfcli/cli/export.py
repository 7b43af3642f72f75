"""`vfcli export`."""
from __future__ import annotations

import click

from vfcli.cli.common import report, setup_logging
from vfcli.cli.choices import EXPORT_WHAT


@click.command("export")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--to", "out_dir", required=True, type=click.Path(file_okay=False), help="Folder to write into.")
@click.option("--run", "runs", multiple=True, help="Run to export (repeatable; default: every run in the store).")
@click.option("--what", default=",".join(EXPORT_WHAT), show_default=True, help="What to write, comma separated.")
@click.option("--time-ms", "times_ms", multiple=True, type=float,
              help="Time (ms) of an overlay PNG (repeatable; default: four times across the first run).")
@click.option("--point", "points", multiple=True, metavar="COL,ROW",
              help="Screen point (px) of figure 8 (repeatable; default: the middle of each fold's superior surface).")
@click.option("--fps", default=10.0, show_default=True, type=click.FloatRange(min=0.1), help="Frame rate of the MP4.")
@click.option("--force", is_flag=True, help="Rewrite even when the store and the options are unchanged.")
@click.option("--quiet", "-q", is_flag=True, help="Errors only.")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary (JSON) on stdout.")
@click.option("-v", "--verbose", count=True, help="More logging (-vv for debug).")
def export_cmd(file, out_dir, runs, what, times_ms, points, fps, force, quiet, as_json, verbose):  # type: ignore[no-untyped-def]
    """Export the reconstructed motion for ParaView, the model over the video, the paper's figures and CSV tables.

    Reads the store (never writes it): /mesh, /optimize/<run>, /hsc, /flow, /fields, /sync, /ldv.
    Writes into DIR: paraview/<run>.vtkhdf (transient, ParaView 5.12+) and <run>.pvd + .vtu,
    video/overlay.mp4 (H.264) and PNG frames, figures/*.png|svg, tables/*.csv, export.json.
    """
    from vfcli.cli.outputs import check_output_folder
    from vfcli.stages.export import export_store
    from vfcli.stages.export_job import parse_point, parse_what

    setup_logging(verbose, quiet)
    check_output_folder(out_dir, "--to")
    report(export_store(file, out_dir, list(runs) or None, parse_what(what), list(times_ms) or None, fps, force,
                        [parse_point(p) for p in points] or None), as_json)
