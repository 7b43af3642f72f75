"""`vfcli run STORE --raw DIR`: every stage of a recording in one process, only what is stale."""
from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import click

from vfcli.cli.choices import RUN_STEPS
from vfcli.cli.common import jobs_option, run_options, setup_logging
from vfcli.errors import VfcliError

#: The steps, for --until (`vfcli batch` imports this name too).
STEP_NAMES = RUN_STEPS


def _report_current(store: Path, out: Path) -> bool:
    """The report is newer than the store's last write (the store's file time changes on
    every commit; a report only reads the store)."""
    return out.exists() and out.stat().st_mtime_ns >= store.stat().st_mtime_ns


@click.command("run")
@click.argument("store", type=click.Path(dir_okay=False))
@click.option("--raw", "raw_dir", type=click.Path(file_okay=False),
              help="The recording's raw folder (video, pressure, scan, recording.toml; see README). "
                   "Without it the ingest steps are skipped.")
@click.option("--until", type=click.Choice(STEP_NAMES), help="Last step to run.")
@click.option("--dry-run", is_flag=True, help="Say which steps would run and why; write nothing.")
@click.option("--export", "export_dir", type=click.Path(file_okay=False),
              help="Then export everything into this folder (skipped when it is up to date).")
@click.option("--report", "report_file", type=click.Path(dir_okay=False),
              help="Then write the HTML report to this file (skipped when newer than the store).")
@jobs_option
@run_options
def run_cmd(store: str, raw_dir: str | None, until: str | None, dry_run: bool, export_dir: str | None,
            report_file: str | None, jobs: int | None, config_path: str | None, overrides: tuple[str, ...],
            force: bool, quiet: bool, as_json: bool, verbose: int) -> None:
    """Run every step of one recording in one process: ingest-hsc, ingest-ldv, sync, flow,
    mesh, optimize (run 'default'), diagnose (of run 'default'; skipped, saying why, when it
    could not calibrate its decision: fewer than 3 stretches of the window's length at whole
    glottal cycles from it in the recording), each only
    when it is not current (same rules as `vfcli info`: inputs by content, config, upstream
    stages), then --export / --report.

    The instrument files are found in the raw folder by extension (a manifest vfcli-files.toml
    names them when that is ambiguous); its recording.toml is the config unless --config.
    Reads: raw files and the store. Writes: every stage group of the store.
    """
    from vfcli.cli.outputs import check_output_file, check_output_folder
    from vfcli.parallel import local_map
    from vfcli.progress import make_progress
    from vfcli.stages.run import run_recording

    setup_logging(verbose, quiet)
    check_output_folder(export_dir, "--export")
    check_output_file(report_file, "--report")
    try:
        summary = run_recording(
            Path(store), Path(raw_dir) if raw_dir else None, until=until, overrides=list(overrides),
            config_path=Path(config_path) if config_path else None, dry_run=dry_run, force=force,
            command=" ".join(shlex.quote(a) for a in ["vfcli", *sys.argv[1:]]),
            progress=make_progress(False if quiet else None), local_map=local_map(jobs))
    except (VfcliError, KeyboardInterrupt) as exc:
        # the steps that ran (and are committed) before the one that failed or was interrupted; the error itself
        # is one line on stderr
        partial = getattr(exc, "partial", None)
        if partial is not None:
            _print(partial, [], as_json, quiet)
        raise
    extra: list[dict[str, Any]] = []
    if export_dir and not dry_run:
        from vfcli.stages.export import export_store

        t0 = time.perf_counter()
        res = export_store(store, export_dir, force=force)
        extra.append({"name": "export", "action": "ran" if res.status == "written" else "up to date",
                      "path": str(export_dir), "seconds": round(time.perf_counter() - t0, 3)})
    if report_file and not dry_run:
        if not force and _report_current(Path(store), Path(report_file)):
            extra.append({"name": "report", "action": "up to date", "path": str(report_file), "seconds": 0.0})
        else:
            from vfcli.stages.report import write_report

            t0 = time.perf_counter()
            write_report(store, report_file)
            extra.append({"name": "report", "action": "ran", "path": str(report_file),
                          "seconds": round(time.perf_counter() - t0, 3)})
    _print(summary, extra, as_json, quiet)


def _print(summary, extra: list[dict[str, Any]], as_json: bool, quiet: bool) -> None:
    """The run's summary on stdout: JSON, or one line per step (and per --export / --report output)."""
    if as_json:
        click.echo(json.dumps({**summary.to_json(), "outputs": extra}, indent=2))
        return
    if quiet:
        return
    for st in summary.stages:
        if st.action == "failed":
            continue     # its error is the command's one line on stderr
        took = f" [{st.seconds:.1f} s]" if st.seconds > 0 else ""
        click.echo(f"{st.name}: {st.action} ({st.reason}){took}")
    for out in extra:
        took = f" [{out['seconds']:.1f} s]" if out.get("seconds", 0) > 0 else ""
        click.echo(f"{out['name']}: {out['action']} ({out['path']}){took}")
