"""`vfcli report`."""
from __future__ import annotations

import click

from vfcli.cli.common import report, setup_logging
from vfcli.errors import ConfigError


@click.command("report")
@click.argument("file", required=False, type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), help="HTML file to write (default: FILE with .html).")
@click.option("--index", "index_dir", type=click.Path(file_okay=False),
              help="Write an overview page of every store under this folder (DIR/index.html unless --out).")
@click.option("--quiet", "-q", is_flag=True, help="Errors only.")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary (JSON) on stdout.")
@click.option("-v", "--verbose", count=True, help="More logging (-vv for debug).")
def report_cmd(file, out, index_dir, quiet, as_json, verbose):  # type: ignore[no-untyped-def]
    """Write one self-contained HTML report of a recording (or, with --index DIR, an overview of many).

    Reads every stage of the store (never writes it). The page embeds its pictures and the
    overlay video (no network, no script): metadata and calibration, each stage's summary and
    warnings, sync quality, glottal gap and flow, the mesh, every optimisation run.
    """
    from pathlib import Path

    from vfcli.cli.outputs import check_output_file
    from vfcli.stages.report import write_index, write_report

    setup_logging(verbose, quiet)
    if bool(file) == bool(index_dir):
        raise ConfigError("give either FILE or --index DIR")
    check_output_file(out or (Path(index_dir) / "index.html" if index_dir else Path(file).with_suffix(".html")),
                      "--out")
    report(write_index(index_dir, out) if index_dir else write_report(file, out), as_json)
