"""The `vfcli` command group: lists the subcommands, loads one only when it runs, and turns
user errors and Ctrl-C into one line.

`vfcli --help` imports click and nothing heavy: each command's module (and the numpy,
scipy, h5py, OpenCV and pydantic it pulls) is imported when that command is looked up.
"""
from __future__ import annotations

import importlib
import sys

import click

from vfcli import __version__
from vfcli.allocator import keep_freed_blocks
from vfcli.errors import EXIT_INTERRUPTED, NotImplementedYet, VfcliError, interruption

EPILOG = """\b
Exit codes: 0 done or up to date, 1 internal error (a bug), 2 usage or config error,
3 bad input data, 4 store locked or not a vfcli store, 5 a needed stage is missing,
6 not implemented yet, 130 interrupted (Ctrl-C).
"""

#: name -> ("module:attribute" of the click command, or None when not built yet; the
#: one-line summary `vfcli --help` shows without importing the module).
COMMANDS: dict[str, tuple[str | None, str]] = {
    "ingest-hsc": ("vfcli.cli.ingest:ingest_hsc_cmd", "Ingest the high-speed video and the pressure recorded with it."),
    "ingest-ldv": ("vfcli.cli.ingest:ingest_ldv_cmd", "Ingest the scanning-vibrometer grid."),
    "sync": ("vfcli.cli.sync:sync_cmd", "Align the sequential LDV epochs to the video through the pressure."),
    "flow": ("vfcli.cli.flow:flow_cmd", "Gap mask, optical flow and the tri-variate surface velocity field."),
    "mesh": ("vfcli.cli.mesh:mesh_cmd", "Build and tetrahedralise the M5 model of both folds."),
    "optimize": ("vfcli.cli.optimize:optimize_cmd", "Fit the force field so the FEM model matches the recording."),
    "export": ("vfcli.cli.export:export_cmd", "Export the motion for ParaView, the model over the video, figures and tables."),
    "run": ("vfcli.cli.run:run_cmd", "Run every stage of a recording from its raw folder, only what is stale."),
    "synth": ("vfcli.cli.synth:synth_cmd", "Write a phantom recording (raw instrument files) with known truth."),
    "diagnose": ("vfcli.cli.diagnose:diagnose_cmd", "Locate the mismatch and name the missing physics."),
    "report": ("vfcli.cli.report:report_cmd", "Write a self-contained HTML report of a recording (or an index of many)."),
    "batch": ("vfcli.cli.batch:batch_cmd", "Run the pipeline over many recordings (Dask: local, a scheduler, SLURM/PBS)."),
    "config": ("vfcli.cli.config:config_cmd", "Store, update (--set) or show a recording's config."),
    "info": ("vfcli.cli.info:info_cmd", "Show a store's stages, provenance, sizes and staleness."),
    "share": ("vfcli.cli.share:share_cmd", "Copy a store with its video re-encoded (gzip) for HDFView/MATLAB users."),
    "schemas": ("vfcli.cli.schemas:schemas_cmd", "Write the config JSON Schemas (and, asked, the docs pages)."),
}


class VfcliGroup(click.Group):
    """A click group that loads a command's module only when the command is used, prints a
    :class:`VfcliError` as one line and exits with its code, and exits 130 on Ctrl-C."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(COMMANDS) | set(self.commands))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in self.commands and name in COMMANDS:
            self.add_command(_load(name), name)
        return self.commands.get(name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list with the summaries of :data:`COMMANDS` (no command module imported)."""
        rows = []
        for name in self.list_commands(ctx):
            if name in COMMANDS:
                rows.append((name, COMMANDS[name][1]))
            else:
                rows.append((name, self.commands[name].get_short_help_str(formatter.width)))
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):  # type: ignore[override]
        keep_freed_blocks()         # numpy's large temporaries from the heap, not a fresh mmap each (vfcli.allocator)
        try:
            return super().invoke(ctx)
        except VfcliError as exc:
            click.echo(f"vfcli {ctx.invoked_subcommand or 'vfcli'}: error: {exc}", err=True)
            ctx.exit(exc.exit_code)
        except (KeyboardInterrupt, Exception) as exc:
            # Ctrl-C, also when it came out wrapped in another error (compiled code calling back into Python,
            # vfcli.errors.interruption). The store is committed whole or not at all (vfcli.store.transaction), so
            # an interrupted command leaves the previous store; 130 = 128 + SIGINT, as shells use.
            stop = interruption(exc)
            if stop is None:
                raise
            if not isinstance(stop, KeyboardInterrupt):
                raise stop from exc                 # SIGTERM's exit, wrapped: exit as it would have
            click.echo(f"vfcli {ctx.invoked_subcommand or 'vfcli'}: interrupted (Ctrl-C)", err=True)
            ctx.exit(EXIT_INTERRUPTED)


@click.group(cls=VfcliGroup, epilog=EPILOG, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="vfcli")
def cli() -> None:
    """vfcli: 3D vocal-fold motion from high-speed video, vibrometry and subglottal pressure.

    Each command reads and writes one HDF5 store per recording (FILE). Run them in
    order: ingest-hsc, ingest-ldv, sync, flow, mesh, optimize, then diagnose, export and
    report (or all of them: vfcli run). Commands whose inputs and config are unchanged do
    nothing (use --force to rerun).
    """


def _load(name: str) -> click.Command:
    """The click command ``name`` of :data:`COMMANDS` (imports its module)."""
    target, summary = COMMANDS[name]
    if target is None:
        reads, writes = stage_io(name)
        return _not_built(name, reads, writes, summary)
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


def _not_built(name: str, reads: str, writes: str, summary: str) -> click.Command:
    @click.command(name, context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
                   help=f"{summary}\n\nReads: {reads}. Writes: {writes}.\n\nNOT IMPLEMENTED YET: exits with code 6.")
    @click.pass_context
    def cmd(ctx: click.Context) -> None:
        raise NotImplementedYet(f"`vfcli {name}` is not implemented yet")

    return cmd


def stage_io(command: str) -> tuple[str, str]:
    """('/a, /b', '/c') : the groups a command reads and writes, from the store layout."""
    from vfcli.store import layout

    written = [st for st in layout.STAGES.values() if st.written_by == command]
    writes = ", ".join(st.group_path("<run>") if st.has_runs else st.group_path() for st in written)
    reads = sorted({f"/{r}" for st in written for r in st.reads} - {f"/{st.name}" for st in written})
    return ", ".join(reads) or "raw files or nothing", writes or "no store group"


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="vfcli")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
