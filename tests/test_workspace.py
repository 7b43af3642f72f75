"""A fit owns its work arrays: fits in threads of one process (as a Dask worker runs them) do not interfere."""
import threading

import numpy as np
import pytest

from vfcli.inverse.optimizers.base import FitOptions, fit
from vfcli.inverse.workspace import Workspace

try:
    from _forward_case import forward_case
except ModuleNotFoundError:
    from tests._forward_case import forward_case


def test_workspace_reuses_an_array_until_its_shape_changes():
    ws = Workspace()
    a = ws.array("a", (3, 4))
    assert ws.array("a", (3, 4)) is a
    assert ws.array("a", (4, 3)) is not a
    f = ws.array("a", (4, 3), order="F")
    assert f.flags.f_contiguous and ws.array("a", (4, 3), order="F") is f
    assert Workspace().array("a", (4, 3)) is not ws.array("a", (4, 3))


@pytest.fixture(scope="module")
def problems():
    case = forward_case(resolution=(2, 2, 3), sides=("inferior",), n_frames=8)
    # same shapes everywhere (same work array names and sizes), different data: the worst case for sharing
    return [case.problem, case.problem.with_weights(ridge_weight=1e-6, motion_weight=3e-4)]


def _fits(problems):
    return [fit(p, method="gauss-newton", max_iter=8, options=FitOptions(ftol=1e-12)) for p in problems]


def test_two_gauss_newton_fits_in_two_threads_equal_the_same_fits_run_one_after_the_other(problems):
    sequential = [_fits([p])[0] for p in problems]
    assert not np.array_equal(sequential[0].x, sequential[1].x)
    for _ in range(2):
        results = [None, None]
        barrier = threading.Barrier(2)

        def run(i):
            barrier.wait()
            results[i] = _fits([problems[i]])[0]

        threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for seq, par in zip(sequential, results):
            np.testing.assert_array_equal(par.x, seq.x)
            np.testing.assert_array_equal(par.history["total"], seq.history["total"])
            np.testing.assert_array_equal(par.history["n_evals"], seq.history["n_evals"])
