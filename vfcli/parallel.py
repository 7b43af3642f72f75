"""The injected map: how the independent pieces of work inside one recording are spread.

Some work of a recording is embarrassingly parallel: the basis solves of the quasi-static
response (one sparse solve per batch of load patterns, optimize), and later the diagnose
candidates' screening and bootstrap replicates. Such code takes a :class:`Mapper` (cooler's
``map=`` argument is the pattern) instead of starting a private pool: whoever runs the
recording decides where the pieces go, and nothing process-global is set.

- ``None`` (the default everywhere) or :func:`serial_map`: one after the other, in this process;
- a thread pool's ``map`` (``concurrent.futures.ThreadPoolExecutor(n).map``): work that
  releases the GIL (the factorisation's solves);
- a Dask client's map (:func:`vfcli.batch.cluster.client_map`, or
  :func:`vfcli.batch.cluster.worker_map` inside a task of a batch): the cluster's workers.

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
