"""`vfcli diagnose`."""
from __future__ import annotations

import click

from vfcli.cli.common import jobs_option, store_command


@click.command("diagnose")
@store_command
@click.option("--run", "run_name", default="default", show_default=True, help="The fitted run to diagnose (/optimize/<run>).")
@click.option("--alpha", type=float, default=0.05, show_default=True,
              help="Family-wise false-alarm rate: a part of the residual is reported above the noise floor when its "
                   "Holm-adjusted p-value is at most this.")
@click.option("--harmonics", "n_harmonics", type=int, default=5, show_default=True, help="Harmonics of f0 tested.")
@click.option("--map", "map_path", type=click.Path(dir_okay=False), help="Write the residual map to this PNG.")
@click.option("--refit", "refit", default="auto", show_default=True, metavar="auto|none|NAME",
              help="Confirm by refit: 'auto' refits the leads in turn (calibrated leads first, then profile leads; "
                   "at most 3 refits; a lead whose fit does not show its term's signature, such as contact's crossing "
                   "of the midplane at closure, is not refitted and its line says why) and names the confirmed one "
                   "whose refit predicts held-out data best, 'none' never refits, a candidate's name (inertia, "
                   "damping, asymmetry, offset, contact) refits that one.")
@jobs_option
def diagnose_cmd(ctx, run_name, alpha, n_harmonics, map_path, refit, jobs):  # type: ignore[no-untyped-def]
    """Locate where a fitted run disagrees with its recording, and name the missing physics.

    Reads: /optimize/<run>, /mesh, /fields, /flow (/hsc's pressure for the pressure loads; /ldv and
    /sync for the vibrometer's noise). Writes: /diagnose/<run> (the residual by where, when, component
    and harmonic of f0 against a noise floor from the recording itself, the hotspots ranked, p-values).
    A refit of a candidate (--refit) is stored as the run /optimize/<run>+<candidate> with its
    parameter and interval, the held-out errors before and after in /diagnose/<run>, and writes
    before/after residual maps and velocity-at-point plots (PNG) beside --map (or beside the store).
    Prints the findings in plain words.
    """
    from vfcli.cli.outputs import PICTURE_FORMATS, check_output_file
    from vfcli.parallel import local_map
    from vfcli.stages.diagnose import run_diagnose

    check_output_file(map_path, "--map", PICTURE_FORMATS)

    ctx.local_map = local_map(jobs)
    result = run_diagnose(ctx, run_name, alpha, n_harmonics, map_path, refit)
    click_ctx = click.get_current_context()
    if not click_ctx.params.get("as_json") and not click_ctx.params.get("quiet"):
        for line in result.summary.get("lines", []):
            click.echo(line)
    return result
