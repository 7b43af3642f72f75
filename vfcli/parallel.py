"""The injected map: how the independent pieces of work inside one recording are spread.

Some work of a recording is embarrassingly parallel: the basis solves of the quasi-static
response (one sparse solve per batch of load patterns, optimize), the diagnosis's bootstrap
replicates, its profile values and its refits. Such code takes a :class:`Mapper` (cooler's
``map=`` argument is the pattern) instead of starting a private pool: whoever runs the
recording decides where the pieces go, and nothing process-global is set.

- ``None`` (the default everywhere) or :func:`serial_map`: one after the other, in this process;
- a thread pool's ``map`` (``concurrent.futures.ThreadPoolExecutor(n).map``): work that
  releases the GIL (the factorisation's solves);
- a Dask client's map (:func:`vfcli.batch.cluster.client_map`, or
  :func:`vfcli.batch.cluster.worker_map` inside a task of a batch): the cluster's workers.

Pieces too large to travel (the diagnosis's whole fits, each holding the run's baseline) take a
second map, :attr:`vfcli.stages.base.RunContext.local_map`, whose workers share this process's memory:
children forked from it (:class:`vfcli.fork_map.ForkMap`) or its threads (:class:`ThreadMap`), chosen by
:func:`local_map` (the command line's ``--jobs``).

The contract: ``mapper(func, items)`` calls ``func`` once per item (in any order, anywhere)
and returns the results in the items' order. ``func`` and the items must pickle for a map that
leaves the process. The caller's result must not depend on the map: the same bits whatever
map ran the pieces (``tests/test_injected_map.py`` checks it for optimize).

A stage reads its map from :attr:`vfcli.stages.base.RunContext.map`; :func:`vfcli.stages.run.run_recording`
(``map=``) and the batch engine (:mod:`vfcli.batch.engine`) set it.
"""
from __future__ import annotations

from typing import Any, Callable, Iterable, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class Mapper(Protocol):
    """``mapper(func, items)`` -> the results of ``func`` over ``items``, in the items' order."""

    def __call__(self, func: Callable[[Any], Any], items: Iterable[Any], /) -> Iterable[Any]: ...


def serial_map(func: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """The builtin map, as a list: one after the other, in this process."""
    return [func(item) for item in items]


def available_cores() -> int:
    """The CPUs this process may run on (its affinity mask: a SLURM or cgroup allotment, not the
    machine's count), at least 1."""
    import os

    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:        # no affinity call (macOS)
        return max(os.cpu_count() or 1, 1)


class ThreadMap:
    """A :class:`Mapper` over ``n`` threads of this process, started per call, for pieces that release the GIL
    (numpy's large products, SuperLU's factorisations and solves); :func:`local_map`'s choice where there is no
    fork.  Daemon threads: a Ctrl-C while they run ends the command at once, the pieces running being abandoned
    with it (a pool's threads would be joined first, up to a whole refit later).  The first error of a piece (in
    the items' order) is raised once every piece has ended."""

    def __init__(self, n: int) -> None:
        self.n = int(n)

    def __call__(self, func: Callable[[T], R], items: Iterable[T]) -> list[R]:
        import threading

        todo = list(items)
        out: list[Any] = [None] * len(todo)
        errors: list[BaseException | None] = [None] * len(todo)
        order = iter(range(len(todo)))
        lock = threading.Lock()

        def work() -> None:
            while True:
                with lock:
                    i = next(order, None)
                if i is None:
                    return
                try:
                    out[i] = func(todo[i])
                except BaseException as exc:     # noqa: BLE001 - handed to the caller's thread below
                    errors[i] = exc

        workers = [threading.Thread(target=work, name=f"vfcli-piece-{k}", daemon=True)
                   for k in range(min(self.n, len(todo)))]
        for t in workers:
            t.start()
        for t in workers:
            t.join()
        first = next((e for e in errors if e is not None), None)
        if first is not None:
            raise first
        return out


def local_map(n: int | None) -> Mapper | None:
    """The in-process map of ``n`` workers (None: :func:`available_cores`) for the pieces of a recording that share
    its memory (:attr:`vfcli.stages.base.RunContext.local_map`, the command line's ``--jobs``): forked children
    on Linux (:class:`vfcli.fork_map.ForkMap`: the diagnosis's pieces hold the GIL in small numpy calls, so
    threads gain little), else threads (:class:`ThreadMap`); None (one after the other, in the caller) for one."""
    import sys

    n = available_cores() if n is None else int(n)
    if n < 1:
        raise ValueError(f"local_map: need at least 1 worker, got {n}")
    if n == 1:
        return None
    if sys.platform.startswith("linux"):
        from vfcli.fork_map import ForkMap

        return ForkMap(n)
    return ThreadMap(n)
