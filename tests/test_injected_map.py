"""The basis solves of the quasi-static response (optimize's linearisation) take an injected
``map``: any map that runs the independent batches gives the same basis, bit for bit, as the
builtin map, including a Dask client's map over worker processes (the elastic model pickles
without its factorisation and is refactorised there). The map reaches optimize through
``run_recording(map=...)`` (the run context) and through `vfcli batch` (a recording alone on a
cluster with idle workers spreads its solves there): the stored /optimize run is the same, bit
for bit, as with the builtin map."""
from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.response.quasi_static import QuasiStaticResponse
from vfcli.stages.run import run_recording
from vfcli.store import Store
from vfcli.store.parts import copy_store

from _batch_phantoms import small_fit_raw

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


# ---------------------------------------------------------------- through optimize and vfcli batch

#: history entries that are clocks, not results
_CLOCKS = ("history_wall_time",)


@pytest.fixture(scope="module")
def meshed(tmp_path_factory) -> tuple[Path, Path]:
    """A tiny phantom's raw folder (small fit settings) and a store of it through mesh: a copy of
    the shared tiny phantom 43 (tests/test_batch.py's)."""
    base = tmp_path_factory.mktemp("map_run")
    raw = small_fit_raw(tmp_path_factory, 43, base / "raw" / "rec43")
    store = base / "mesh.h5"
    assert run_recording(store, raw, until="mesh").ok
    return raw, store


def _optimize_run(store: Path) -> tuple[dict[str, np.ndarray], dict]:
    """Every dataset of /optimize/default (but the wall clock) and its attributes."""
    with Store(store).read() as r:
        g = r.group("optimize", "default")
        data = {k: g[k][()] for k in g if k not in _CLOCKS}
        return data, r.attrs("optimize", "default")


def _assert_same_run(store: Path, reference: Path) -> None:
    got, got_attrs = _optimize_run(store)
    want, want_attrs = _optimize_run(reference)
    assert sorted(got) == sorted(want) and "controls" in got and "displacements" in got
    for key in want:
        if want[key].dtype == object:
            assert list(got[key]) == list(want[key]), key
        else:
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    assert got_attrs["converged"] == want_attrs["converged"] and got_attrs["message"] == want_attrs["message"]
    np.testing.assert_array_equal(got_attrs["camera_offset_px"], want_attrs["camera_offset_px"])


def _with_pid(func, item):
    return os.getpid(), func(item)


@pytest.mark.slow
@pytest.mark.timeout(2400)  # four small fits: 6-15 min under a load average of 20-40 on 2 cores
@pytest.mark.filterwarnings("ignore:Sending large graph:UserWarning")
def test_optimize_through_a_dask_map_stores_the_same_run_bit_for_bit(meshed, tmp_path):
    """The same store fitted in this process with the builtin map and with
    run_recording(map=client_map(client)) on a 2-worker LocalCluster (the pieces run in the
    worker processes): the same bits. And by `vfcli batch`'s engine with one recording on that
    cluster, without the spread and with it (inner_map=None: the auto rule spreads the solves
    of a recording alone on the cluster): the same bits."""
    import distributed

    from vfcli.batch.cluster import client_map
    from vfcli.batch.engine import run_batch
    from vfcli.batch.manifest import parse_manifest

    raw, meshed_store = meshed
    serial = copy_store(meshed_store, tmp_path / "serial.h5")
    summary = run_recording(serial, raw, until="optimize")
    assert [s.name for s in summary.stages if s.action == "ran"] == ["optimize"]

    pids: set[int] = set()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        dask_map = client_map(client)

        def watched_map(func, items):
            out = dask_map(functools.partial(_with_pid, func), items)
            pids.update(p for p, _ in out)
            return [r for _, r in out]

        spread = copy_store(meshed_store, tmp_path / "spread.h5")
        run_recording(spread, raw, until="optimize", map=watched_map)

        # in a batch, the recording runs in a worker process (Dask's nanny sets OMP_NUM_THREADS=1:
        # single-threaded BLAS sums in another order than this process), so the reference is the
        # same batch without the spread
        outcomes, streams = {}, {}
        for name, inner in (("batch_serial", False), ("batch_spread", None)):  # None: the auto rule
            store = copy_store(meshed_store, tmp_path / f"{name}.h5")
            manifest = parse_manifest(tmp_path / f"{name}.toml", f'[[recording]]\nraw = "{raw}"\nstore = "{store}"\n')
            with distributed.get_task_stream(client) as stream:
                outcomes[name] = run_batch(manifest, client, until="optimize", inner_map=inner).outcomes[0]
            streams[name] = [t["key"] if isinstance(t["key"], str) else t["key"][0] for t in stream.data]

    assert pids and os.getpid() not in pids  # the basis solves ran in the worker processes
    _assert_same_run(spread, serial)
    assert [(o["status"], o["inner_map"]) for o in outcomes.values()] == [("done", False), ("done", True)], outcomes
    ran = streams["batch_spread"]
    pieces = [k for k in ran if k.lstrip("_").startswith("call-")]  # the pieces the recording's task spread
    assert pieces and len(ran) == len(pieces) + 1 and any(k.startswith("vfcli-run-") for k in ran), ran
    assert not [k for k in streams["batch_serial"] if k.lstrip("_").startswith("call-")]
    _assert_same_run(tmp_path / "batch_spread.h5", tmp_path / "batch_serial.h5")
