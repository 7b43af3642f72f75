"""The basis solves of the quasi-static response (optimize's linearisation) take an injected
``map``: any map that runs the independent batches gives the same basis, bit for bit, as the
builtin map, including a Dask client's map over worker processes (the elastic model pickles
without its factorisation and is refactorised there)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.response.quasi_static import QuasiStaticResponse

try:
    from _forward_case import elastic_model
except ModuleNotFoundError:
    from tests._forward_case import elastic_model


@pytest.fixture(scope="module")
def case():
    model = elastic_model()
    field = ForceField(ForceFieldSpec((2, 2, 6), ("inferior", "superior")), (0.0, 0.01))
    return model, field, QuasiStaticResponse(model, field, chunk=8).basis_


def _reversed_map(func, items):
    """Runs the batches last to first (as an unordered pool might), returns them in order."""
    items = list(items)
    done = {i: func(items[i]) for i in reversed(range(len(items)))}
    return [done[i] for i in range(len(items))]


def test_the_basis_is_the_same_whatever_the_map(case):
    model, field, reference = case
    calls = []

    def counting_map(func, items):
        items = list(items)
        calls.append(len(items))
        return map(func, items)

    assert np.abs(reference).max() > 0
    for mapper in (_reversed_map, counting_map):
        np.testing.assert_array_equal(QuasiStaticResponse(model, field, chunk=8, map=mapper).basis_, reference)
    assert calls == [field.n_spatial // 8]  # the map got every batch, in one call
    with ThreadPoolExecutor(2) as pool:
        np.testing.assert_array_equal(QuasiStaticResponse(model, field, chunk=8, map=pool.map).basis_, reference)


@pytest.mark.filterwarnings("ignore:Sending large graph:UserWarning")  # the model travels with each batch
def test_a_dask_client_map_over_worker_processes_gives_the_same_basis(case):
    import distributed
    model, field, reference = case
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        def client_map(func, items):
            return client.gather(client.map(func, list(items), pure=False))

        basis = QuasiStaticResponse(model, field, chunk=32, map=client_map).basis_
        pids = set(client.run(lambda: __import__("os").getpid()).values())
    np.testing.assert_array_equal(basis, reference)
    assert pids and __import__("os").getpid() not in pids
