"""`vfcli optimize`."""
from __future__ import annotations

import click

from vfcli.cli.choices import OPTIMIZE_LOADS, OPTIMIZE_METHODS, OPTIMIZE_SETUPS
from vfcli.cli.common import store_command


@click.command("optimize")
@store_command
@click.option("--run", "run_name", default="default", show_default=True, help="Name of the run (/optimize/<run>).")
@click.option("--setup", type=click.Choice(OPTIMIZE_SETUPS),
              help="Fit the paper's free force field with this setup (sets optimize.loads='free'); "
                   "default: the pressure load model tied to the measured subglottal pressure.")
@click.option("--loads", type=click.Choice(OPTIMIZE_LOADS),
              help="Load model (overrides optimize.loads; with --setup, 'free-regularised' bounds the paper's field).")
@click.option("--method", type=click.Choice(OPTIMIZE_METHODS), help="Optimiser (overrides optimize.method).")
@click.option("--resume", "resume_run", is_flag=True, help="Continue an interrupted run from its checkpoint.")
@click.option("--plot", type=click.Path(dir_okay=False), help="Write the convergence plot to this PNG.")
@click.option("--uncertainty-map", "uncertainty_plot", type=click.Path(dir_okay=False),
              help="Write a map of the inferior surface's stated uncertainty to this PNG.")
def optimize_cmd(ctx, run_name, setup, loads, method, resume_run, plot, uncertainty_plot):  # type: ignore[no-untyped-def]
    """Fit the force field so the simulated superior surface and gap match the recording.

    Reads: /mesh, /fields, /flow (and /hsc's pressure for the pressure loads). Writes:
    /optimize/<run> (control values, history of every iteration, reconstructed vertex
    displacements and their standard deviations). Config section [optimize].
    """
    from vfcli.cli.outputs import PICTURE_FORMATS, check_output_file
    from vfcli.errors import ConfigError
    from vfcli.config import RecordingConfig
    from vfcli.overrides import apply_overrides
    from vfcli.stages.optimize import run_optimize

    check_output_file(plot, "--plot", PICTURE_FORMATS)
    check_output_file(uncertainty_plot, "--uncertainty-map", PICTURE_FORMATS)

    if setup and loads == "pressure":
        # --loads after --setup made the fit the pressure model's, --setup silently dropped
        raise ConfigError(f"--setup {setup} fits the paper's free force field, --loads pressure the pressure load "
                          "model, which has no setup: give one of them (with --setup, --loads free or "
                          "free-regularised)")
    # a --setup names one of the paper's free force fields
    sets = ([f"optimize.setup={setup!r}", "optimize.loads='free'"] if setup else [])
    sets += [f"optimize.loads={loads!r}"] if loads else []
    sets += [f"optimize.method={method!r}"] if method else []
    if sets:
        ctx.config = RecordingConfig.model_validate(apply_overrides(ctx.config.model_dump(mode="json"), sets))
    return run_optimize(ctx, run_name, resume_run, plot, uncertainty_plot)
