"""`vfcli batch`: many recordings, one `vfcli run` each, on a Dask cluster.

- :mod:`vfcli.batch.manifest`: the manifest (TOML or CSV) of recordings;
- :mod:`vfcli.batch.ledger`: what became of each, beside the manifest, so a rerun resumes;
- :mod:`vfcli.batch.task`: one recording on a worker (returns a small JSON summary);
- :mod:`vfcli.batch.engine`: submits the tasks, collects outcomes, keeps the ledger;
- :mod:`vfcli.batch.cluster`: the Dask client (local cluster, running scheduler, SLURM/PBS).

Dask is imported only by :mod:`~vfcli.batch.cluster` and :mod:`~vfcli.batch.engine`, when a batch runs.
"""
