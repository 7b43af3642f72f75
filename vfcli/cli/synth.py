"""`vfcli synth OUTDIR`: a phantom recording."""
from __future__ import annotations

import click

from vfcli.cli.choices import SYNTH_EFFECTS
from vfcli.cli.common import report, run_options, setup_logging


@click.command("synth")
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--effect", type=click.Choice(SYNTH_EFFECTS), help="Hidden physics effect (default: none); 'random' names it only in truth.h5.")
@click.option("--strength", type=float, help="Effect strength (see `synth.strength` in schemas/synth.schema.json).")
@click.option("--seed", type=int, help="Random seed: the same seed writes the same bytes.")
@run_options
def synth_cmd(outdir, effect, strength, seed, config_path, overrides, force, quiet, as_json, verbose):  # type: ignore[no-untyped-def]
    """Write a phantom recording into OUTDIR: the instruments' raw files and truth.h5.

    Reads: nothing (config file: [synth] and [mesh] sections; --force replaces an OUTDIR
    that holds other files). Writes: OUTDIR with video.mraw + video.cihx,
    video.tif, video_pressure.tdms/.csv, scan.uff/.csv, recording.toml and truth.h5
    (which no other command reads).
    """
    from vfcli.cli.outputs import check_output_folder
    from vfcli.config import load_config
    from vfcli.progress import make_progress
    from vfcli.stages.synth import run_synth

    setup_logging(verbose, quiet)
    check_output_folder(outdir, "OUTDIR")
    sets = list(overrides)
    sets += [f"synth.effect={effect!r}"] if effect else []
    sets += [f"synth.strength={strength}"] if strength is not None else []
    sets += [f"synth.seed={seed}"] if seed is not None else []
    _, cfg = load_config(config_path, None, sets)
    report(run_synth(outdir, cfg, force=force, progress=make_progress(False if quiet else None)), as_json)
