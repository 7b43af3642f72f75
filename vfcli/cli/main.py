"""The `vfcli` command group: registers the subcommands and turns user errors into one line."""
from __future__ import annotations

import sys

import click

from vfcli import __version__
from vfcli.errors import NotImplementedYet, VfcliError

EPILOG = """\b
Exit codes: 0 done or up to date, 1 internal error (a bug), 2 usage or config error,
3 bad input data, 4 store locked or not a vfcli store, 5 a needed stage is missing,
6 not implemented yet.
"""


class VfcliGroup(click.Group):
    """A click group that prints a :class:`VfcliError` as one line and exits with its code."""

    def invoke(self, ctx: click.Context):  # type: ignore[override]
        try:
            return super().invoke(ctx)
        except VfcliError as exc:
            name = ctx.invoked_subcommand or "vfcli"
            click.echo(f"vfcli {name}: error: {exc}", err=True)
            ctx.exit(exc.exit_code)


@click.group(cls=VfcliGroup, epilog=EPILOG, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="vfcli")
def cli() -> None:
    """vfcli: 3D vocal-fold motion from high-speed video, vibrometry and subglottal pressure.

    Each command reads and writes one HDF5 store per recording (FILE). Run them in
    order: ingest-hsc, ingest-ldv, sync, flow, mesh, optimize, export. Commands whose
    inputs and config are unchanged do nothing (use --force to rerun).
    """


def _not_built(name: str, reads: str, writes: str, summary: str) -> click.Command:
    @click.command(name, context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
                   help=f"{summary}\n\nReads: {reads}. Writes: {writes}.\n\nNOT IMPLEMENTED YET: exits with code 6.")
    @click.pass_context
    def cmd(ctx: click.Context) -> None:
        raise NotImplementedYet(f"`vfcli {name}` is not implemented yet")

    return cmd


def _register() -> None:
    from vfcli.cli.config import config_cmd
    from vfcli.cli.info import info_cmd
    from vfcli.cli.schemas import schemas_cmd

    cli.add_command(config_cmd)
    cli.add_command(info_cmd)
    cli.add_command(schemas_cmd)
    from vfcli.cli.flow import flow_cmd
    from vfcli.cli.ingest import ingest_hsc_cmd, ingest_ldv_cmd
    from vfcli.cli.mesh import mesh_cmd
    from vfcli.cli.optimize import optimize_cmd
    from vfcli.cli.sync import sync_cmd
    from vfcli.cli.synth import synth_cmd
    from vfcli.cli.export import export_cmd
    from vfcli.cli.report import report_cmd

    built = {"ingest-hsc": ingest_hsc_cmd, "ingest-ldv": ingest_ldv_cmd, "mesh": mesh_cmd, "sync": sync_cmd, "synth": synth_cmd, "flow": flow_cmd, "optimize": optimize_cmd,
             "export": export_cmd, "report": report_cmd}
    todo = [
        ("ingest-hsc", "Ingest the high-speed video and the pressure recorded with it."),
        ("ingest-ldv", "Ingest the scanning-vibrometer grid."),
        ("sync", "Align the sequential LDV epochs to the video through the pressure."),
        ("flow", "Gap mask, optical flow and the tri-variate surface velocity field."),
        ("mesh", "Build and tetrahedralise the M5 model of both folds."),
        ("optimize", "Fit the force field so the FEM model matches the recording."),
        ("export", "Export the reconstructed motion for ParaView."),
        ("synth", "Write a phantom recording (raw instrument files) with known truth."),
        ("diagnose", "Locate the mismatch and name the missing physics."),
        ("report", "Write an HTML report of a recording."),
        ("batch", "Run the pipeline over many recordings (cluster)."),
    ]
    for name, summary in todo:
        if name not in built:
            reads, writes = stage_io(name)
            built[name] = _not_built(name, reads, writes, summary)
        cli.add_command(built[name], name)


def stage_io(command: str) -> tuple[str, str]:
    """('/a, /b', '/c') : the groups a command reads and writes, from the store layout."""
    from vfcli.store import layout

    written = [st for st in layout.STAGES.values() if st.written_by == command]
    writes = ", ".join(st.group_path("<run>") if st.has_runs else st.group_path() for st in written)
    reads = sorted({f"/{r}" for st in written for r in st.reads} - {f"/{st.name}" for st in written})
    return ", ".join(reads) or "raw files or nothing", writes or "no store group"


_register()


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="vfcli")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
