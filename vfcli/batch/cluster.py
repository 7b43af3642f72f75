"""Where a batch runs: a Dask distributed client on a local cluster, a running scheduler, or
SLURM / PBS jobs through dask-jobqueue.

Dask is optional (the ``batch`` extra, and dask-jobqueue for SLURM/PBS): every import of it
happens in these functions, and a missing one is a :class:`vfcli.errors.ConfigError` that
says what to install (exit 2).
"""
from __future__ import annotations

import logging
from contextlib import ExitStack, contextmanager
from typing import Any, Iterator, Mapping

from vfcli.errors import ConfigError
from vfcli.parallel import Mapper

log = logging.getLogger(__name__)

#: Placeholder scheduler address of the job script :func:`job_script` writes (the real one
#: is the address of the scheduler ``SLURMCluster`` starts).
SCHEDULER_PLACEHOLDER = "tcp://SCHEDULER:8786"
#: SLURM/PBS job settings vfcli uses unless the manifest or --slurm/--pbs say otherwise: one
#: recording per worker process, one thread (vfcli's stages use their own threads where
#: they pay), a nanny that restarts a killed worker.
JOB_DEFAULTS: dict[str, Any] = {"cores": 1, "processes": 1, "memory": "4GB", "name": "vfcli-worker"}
#: Keys of a [batch.slurm] / [batch.pbs] table that are vfcli's, not dask-jobqueue's.
_VFCLI_JOB_KEYS = ("jobs",)


def require(module: str, extra: str = "batch") -> Any:
    """Import ``module`` (dask, distributed, dask_jobqueue) or say which extra installs it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        package = {"dask_jobqueue": "dask-jobqueue"}.get(module, "dask[distributed]")
        raise ConfigError(f"`vfcli batch` needs {package}: pip install 'vfcli[{extra}]'") from None


def parse_options(items: list[str] | tuple[str, ...], where: str) -> dict[str, Any]:
    """``["queue=normal", "cores=2"]`` -> ``{"queue": "normal", "cores": 2}`` (values as TOML
    literals when they parse as one, else text)."""
    from vfcli.overrides import parse_value

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{where} {item!r}: expected KEY=VALUE (e.g. queue=normal, memory=4GB, jobs=8)")
        out[key.strip()] = parse_value(value.strip())
    return out


def jobqueue_choice(manifest_slurm: Mapping[str, Any], manifest_pbs: Mapping[str, Any],
                    slurm_items: list[str] | tuple[str, ...] = (), pbs_items: list[str] | tuple[str, ...] = ()
                    ) -> tuple[str, dict[str, Any]] | None:
    """("slurm" | "pbs", options) from the manifest's ``[batch.slurm]``/``[batch.pbs]`` and the
    ``--slurm``/``--pbs`` items (which win, key by key, and choose the kind); None: neither."""
    if slurm_items and pbs_items:
        raise ConfigError("--slurm and --pbs: choose one")
    if slurm_items or (manifest_slurm and not pbs_items):
        return "slurm", {**manifest_slurm, **parse_options(slurm_items, "--slurm")}
    if pbs_items or manifest_pbs:
        return "pbs", {**manifest_pbs, **parse_options(pbs_items, "--pbs")}
    return None


def job_kwargs(options: Mapping[str, Any]) -> dict[str, Any]:
    """dask-jobqueue keyword arguments: :data:`JOB_DEFAULTS` overridden by ``options``, less
    vfcli's own keys (``jobs``)."""
    merged = {**JOB_DEFAULTS, **dict(options)}
    for key in _VFCLI_JOB_KEYS:
        merged.pop(key, None)
    return merged


def job_script(kind: str, options: Mapping[str, Any]) -> str:
    """The batch script one worker job runs, as ``SLURMCluster(**options).job_script()``
    (``PBSCluster``) writes it, with :data:`SCHEDULER_PLACEHOLDER` as the scheduler's address.
    Starts no scheduler and submits nothing."""
    jq = require("dask_jobqueue")
    job_cls = {"slurm": jq.slurm.SLURMJob, "pbs": jq.pbs.PBSJob}[kind]
    try:
        return job_cls(scheduler=SCHEDULER_PLACEHOLDER, **job_kwargs(options)).job_script()
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"[batch.{kind}] / --{kind}: {exc}") from None


def _call(item: Any, fn: Any) -> Any:
    return fn(item)


def _scattered_map(client: Any, func: Any, items: Any, wait: Any) -> list[Any]:
    """``func`` over ``items`` on ``client``'s workers: ``func`` (with what it holds, e.g. the
    elastic model) is sent to each worker once, not with every item; ``wait`` gathers."""
    items = list(items)
    if not items:
        return []
    [shared] = client.scatter([func], broadcast=True, hash=False)
    futures = client.map(_call, items, fn=shared, pure=False)
    try:
        return wait(futures)
    finally:
        client.cancel([shared, *futures])


def client_map(client: Any) -> Mapper:
    """A :class:`vfcli.parallel.Mapper` that runs the pieces on ``client``'s workers (a
    ``distributed.Client`` this process holds: a script's, a notebook's)."""
    return lambda func, items: _scattered_map(client, func, items, client.gather)


def worker_map() -> Mapper:
    """A :class:`vfcli.parallel.Mapper` for code running inside a Dask task (a batch's
    recording): the pieces go to the cluster the task runs on, and the task leaves its worker
    thread while it waits for them (``secede``/``rejoin``), so the pieces can run there too."""
    from distributed import get_client, rejoin, secede

    def wait(futures: Any) -> Any:
        client = get_client()
        secede()
        try:
            return client.gather(futures)
        finally:
            rejoin()

    return lambda func, items: _scattered_map(get_client(), func, items, wait)


@contextmanager
def open_client(
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    jobqueue: tuple[str, Mapping[str, Any]] | None = None,
    allowed_failures: int = 2,
) -> Iterator[Any]:
    """A ``distributed.Client`` for a batch, closed (with any cluster it started) on exit.

    Parameters
    ----------
    scheduler : address of a running scheduler (``tcp://host:8786``); wins over the rest.
    workers : processes of the local cluster (default 2), one thread each.
    jobqueue : ("slurm" | "pbs", dask-jobqueue cluster options) (:func:`jobqueue_choice`; a
        ``jobs`` key: jobs to scale to, default ``workers`` or 1): starts a SLURMCluster / PBSCluster.
    allowed_failures : times a task is rescheduled after its worker died before the task ends
        with ``KilledWorker`` (the scheduler's ``distributed.scheduler.allowed-failures``; for
        a running scheduler, its own setting holds).
    """
    dask = require("dask")
    distributed = require("distributed")
    if not log.isEnabledFor(logging.INFO):  # dask's own INFO lines (scheduler, nannies) only with -v
        logging.getLogger("distributed").setLevel(logging.WARNING)
    with ExitStack() as stack:
        stack.enter_context(dask.config.set({"distributed.scheduler.allowed-failures": allowed_failures}))
        if scheduler:
            try:
                client = distributed.Client(scheduler, timeout="20s")
            except OSError as exc:
                raise ConfigError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
        elif jobqueue:
            kind, options = jobqueue
            jq = require("dask_jobqueue")
            cls = jq.SLURMCluster if kind == "slurm" else jq.PBSCluster
            try:
                cluster = stack.enter_context(cls(**job_kwargs(options)))
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"[batch.{kind}] / --{kind}: {exc}") from None
            cluster.scale(jobs=int(options.get("jobs", workers or 1)))
            log.info("batch: %s jobs submitted; job script:\n%s", kind, cluster.job_script())
            client = distributed.Client(cluster)
        else:
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=workers or 2, threads_per_worker=1, processes=True, dashboard_address=":0",
                silence_logs=logging.ERROR))
            client = distributed.Client(cluster)
        stack.enter_context(client)
        yield client
