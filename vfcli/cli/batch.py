"""`vfcli batch MANIFEST`: every recording of a manifest through `vfcli run`, on Dask."""
from __future__ import annotations

import json

import click

from vfcli.cli.common import setup_logging
from vfcli.cli.run import STEP_NAMES
from vfcli.errors import ConfigError

EPILOG = """\b
Runs on an in-process Dask LocalCluster (--workers processes, one thread each) unless
--scheduler names a running scheduler or --slurm/--pbs (or [batch.slurm] in the manifest)
asks for dask-jobqueue jobs. Needs: pip install 'vfcli[batch]'.
Exit 0 when every recording ended done or up to date, else the largest exit code of the
failed ones (3 bad data, 4 store locked or damaged, ...), after all have run.
The ledger <MANIFEST>.ledger.json records each outcome; a rerun skips what is finished.
One batch of a manifest at a time: a second one exits 4 at once (the ledger's lock file).
--inner-map auto: when fewer recordings run than the cluster has worker threads, each spreads
its optimize basis solves over the idle workers (the stores end the same).
"""


@click.command("batch", epilog=EPILOG)
@click.argument("manifest", type=click.Path(dir_okay=False))
@click.option("--scheduler", metavar="ADDRESS", help="A running Dask scheduler (tcp://host:8786).")
@click.option("--workers", type=click.IntRange(1, 4096), help="Local worker processes (default: the manifest's, else 2).")
@click.option("--slurm", "slurm", multiple=True, metavar="KEY=VALUE",
              help="Run on SLURM jobs (dask-jobqueue SLURMCluster argument, e.g. queue=normal, memory=4GB, "
                   "walltime=01:00:00, jobs=8); repeatable, over [batch.slurm].")
@click.option("--pbs", "pbs", multiple=True, metavar="KEY=VALUE", help="The same for PBS (PBSCluster), over [batch.pbs].")
@click.option("--until", type=click.Choice(STEP_NAMES), help="Last step for every recording (over the manifest's).")
@click.option("--retries", type=click.IntRange(0, 100), help="Reruns of a recording whose worker died (default: the manifest's, else 2).")
@click.option("--fresh", is_flag=True, help="Ignore the ledger: run every recording (stages still run only when stale).")
@click.option("--job-script", is_flag=True, help="Print the SLURM/PBS job script one worker job runs (scheduler address "
              "as a placeholder) and exit; submits nothing.")
@click.option("--inner-map", type=click.Choice(["auto", "on", "off"]), default="off", show_default=True,
              help="Spread each recording's optimize basis solves over the cluster's workers (auto: when fewer "
                   "recordings run than there are worker threads); pays only for load models of thousands of "
                   "patterns (docs/cluster.md).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
@click.option("--quiet", "-q", is_flag=True, help="Print errors only.")
@click.option("-v", "--verbose", count=True, help="More logging (-vv for debug).")
def batch_cmd(manifest, scheduler, workers, slurm, pbs, until, retries, fresh, job_script, inner_map, as_json,  # type: ignore[no-untyped-def]
              quiet, verbose):
    """Run the pipeline over every recording listed in MANIFEST (TOML or CSV)."""
    from vfcli.batch.cluster import job_script as make_job_script, jobqueue_choice, open_client, require
    from vfcli.batch.engine import run_batch
    from vfcli.batch.ledger import Ledger
    from vfcli.batch.manifest import read_manifest

    setup_logging(verbose, quiet)
    require("distributed")
    m = read_manifest(manifest)
    jobqueue = None if scheduler else jobqueue_choice(m.slurm, m.pbs, slurm, pbs)
    if job_script:
        if jobqueue is None:
            raise ConfigError("--job-script: no SLURM or PBS settings (--slurm/--pbs or [batch.slurm]/[batch.pbs])")
        click.echo(make_job_script(*jobqueue), nl=False)
        return

    def progress(outcome):  # type: ignore[no-untyped-def]
        if not (quiet or as_json):
            err = f": {outcome['error']}" if outcome.get("error") else ""
            resumed = " (ledger)" if outcome.get("resumed") else ""
            click.echo(f"{outcome['name']}: {outcome['status']}{resumed}{err}", err=True)

    n_retries = m.retries if retries is None else retries
    # the ledger's lock first: a second batch of this manifest stops before it starts a cluster
    with Ledger(m.ledger_path, m.path).hold(), open_client(scheduler=scheduler, workers=workers or m.workers,
                                                           jobqueue=jobqueue, allowed_failures=n_retries) as client:
        summary = run_batch(m, client, until=until, fresh=fresh, retries=n_retries, on_outcome=progress,
                            hold_ledger=False, inner_map={"auto": None, "on": True, "off": False}[inner_map])
    if as_json:
        click.echo(json.dumps(summary.to_json(), indent=2, default=str))
    elif not quiet:
        click.echo(summary.table())
    if summary.exit_code:
        click.get_current_context().exit(summary.exit_code)
