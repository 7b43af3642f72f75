"""Options every store command shares, and turning a library result into output."""
from __future__ import annotations

import functools
import json
import logging
import shlex
import sys
import warnings
from typing import TYPE_CHECKING, Any, Callable

import click

if TYPE_CHECKING:  # imported when a command runs (`vfcli --help` stays light)
    from vfcli.stages.base import StageResult


#: libraries whose INFO lines ``-v`` leaves out (``-vv`` shows them): scikit-fem logs every assembly
NOISY_LIBRARIES = ("skfem",)


def setup_logging(verbose: int, quiet: bool) -> None:
    """Log to stderr: warnings and errors (-v vfcli's info, -vv everyone's debug); ``quiet``: errors only.

    At ``-v`` the INFO lines of :data:`NOISY_LIBRARIES` (scikit-fem logs every assembly: thousands of
    lines in a diagnosis) stay out; ``-vv`` shows them.  ``quiet`` also silences Python warnings (numpy's, a
    library's deprecations), which bypass logging.
    """
    level = logging.WARNING - 10 * verbose if not quiet else logging.ERROR
    logging.basicConfig(level=max(level, logging.DEBUG), format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    for name in NOISY_LIBRARIES:
        logging.getLogger(name).setLevel(logging.NOTSET if verbose >= 2 else logging.WARNING)
    if quiet:
        warnings.simplefilter("ignore")


def run_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """--config, --set, --force, --quiet, --json, -v: the options every command that runs work shares."""
    for option in reversed([
        click.option("--config", "config_path", type=click.Path(dir_okay=False), help="recording.toml; stored with the recording (replaces the stored config)."),
        click.option("--set", "overrides", multiple=True, metavar="SECTION.FIELD=VALUE", help="Override one config value for this run (repeatable; null unsets a field that may be unset)."),
        click.option("--force", is_flag=True, help="Rerun even when inputs and config are unchanged."),
        click.option("--quiet", "-q", is_flag=True, help="Print errors only (no progress bars, summary or warnings)."),
        click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary (JSON) on stdout."),
        click.option("-v", "--verbose", count=True, help="More logging (-vv for debug)."),
    ]):
        func = option(func)
    return func


def jobs_option(func: Callable[..., Any]) -> Callable[..., Any]:
    """--jobs N: the workers a command spreads a recording's in-process pieces over (``jobs``, None: the cores;
    :func:`vfcli.parallel.local_map`)."""
    return click.option(
        "--jobs", "-j", "jobs", type=click.IntRange(min=1), default=None, metavar="N",
        help="Processes for the diagnosis's independent pieces (its profile values, its modal reduction's "
             "factorisations, its refits or a single refit's held-out fits), forked from this one (threads where "
             "there is no fork); default: the cores this process may use, e.g. a SLURM allotment; 1: one after the "
             "other. The results are the same whatever N; each piece running beside another holds its own working "
             "memory.")(func)


def store_command(func: Callable[..., Any]) -> Callable[..., Any]:
    """Add FILE and the :func:`run_options`; pass a RunContext as ``ctx``."""

    @click.argument("file", type=click.Path(dir_okay=False))
    @run_options
    @functools.wraps(func)
    def wrapper(file: str, config_path: str | None, overrides: tuple[str, ...], force: bool, quiet: bool, as_json: bool, verbose: int, **kwargs: Any) -> None:
        from vfcli.progress import make_progress
        from vfcli.stages.base import RunContext

        setup_logging(verbose, quiet)
        ctx = RunContext.open(
            file,
            config_path,
            list(overrides),
            command=" ".join(shlex.quote(a) for a in ["vfcli", *sys.argv[1:]]),
            force=force,
            progress=make_progress(False if quiet else None),
        )
        result = func(ctx=ctx, **kwargs)
        report(result, as_json, quiet)

    return wrapper


def report(result: StageResult | list[StageResult], as_json: bool, quiet: bool | None = None) -> None:
    """Print what a command did: one line per stage, or JSON (``--json``, even with ``quiet``);
    nothing when ``quiet`` (None: the running command's ``--quiet``)."""
    if quiet is None:
        ctx = click.get_current_context(silent=True)
        quiet = bool(ctx and ctx.params.get("quiet"))
    results = result if isinstance(result, list) else [result]
    if as_json:
        payload = [r.to_json() for r in results]
        click.echo(json.dumps(payload[0] if len(payload) == 1 else payload, indent=2, default=str))
        return
    if quiet:
        return
    for r in results:
        if r.status == "up-to-date":
            click.echo(f"{r.stage}: up to date (inputs and config unchanged; --force reruns)")
        else:
            extras = ", ".join(f"{k}={v}" for k, v in r.summary.items() if not isinstance(v, (dict, list)))
            click.echo(f"{r.stage}: written" + (f" ({extras})" if extras else ""))
