"""The baseline carries the run's own elastic model: a stiffer material gives the inertia column it
should (the density derivative of the frequency-domain steady state of *that* model), not the
default material's.

A store's /mesh is written by the real `vfcli mesh` with E = 8.8 kPa (twice the default);
:func:`vfcli.store.fit.run_model` reads the model back, a pressure-load baseline is built on it.
"""
from __future__ import annotations

import numpy as np
import pytest

from _candidates_case import CAMERA, SETTINGS, pressure_controls, subglottal_pressure
from _forward_case import F0_HZ
from conftest import run_vfcli
from vfcli.diagnose.candidate import Baseline
from vfcli.diagnose.candidates import Inertia
from vfcli.inverse.problem import Problem, synthesize_measurement
from vfcli.model.loads.pressure import PressureLoad
from vfcli.model.response.modal import ModalReduction
from vfcli.model.response.quasi_static import QuasiStaticResponse
from vfcli.store import Store
from vfcli.store.fit import run_model

E_RUN = 8800.0


@pytest.fixture(scope="module")
def stiff_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "rec.h5"
    res = run_vfcli("mesh", path, "--set", f"mesh.youngs_modulus_pa={E_RUN}", "--set", "mesh.target_edge_mm=2.0",
                    "--set", "mesh.density_kg_m3=1100")
    assert res.returncode == 0, res.stderr
    return path


def _baseline(model, with_model: bool) -> Baseline:
    n_frames = 12
    times = 0.002 + np.arange(n_frames) / (n_frames * F0_HZ)
    sim = np.append(times, times[-1] + 1.0 / (n_frames * F0_HZ))
    tp = np.arange(0.0, 0.02, 1e-5)
    load = PressureLoad(tp, subglottal_pressure(tp), (sim[0], sim[-1]), time_degree=0)   # periodic at f0
    response = QuasiStaticResponse(model, load)
    x = pressure_controls(load)
    meas = synthesize_measurement(model.mesh, CAMERA, response, times, x, SETTINGS)
    return Baseline.at(Problem(model.mesh, CAMERA, response, meas, SETTINGS), x, F0_HZ,
                       model=model if with_model else None)


def test_the_run_model_has_the_stored_material_and_gives_the_inertia_column_of_that_material(stiff_store):
    with Store(stiff_store).read() as reader:
        model = run_model(reader)
    assert np.allclose(model.youngs_pa, E_RUN) and model.density_kg_m3 == 1100.0 and model.poisson == 0.499
    base = _baseline(model, with_model=True)
    column = Inertia().displacement_jacobian(base)[..., 0]
    # the density derivative of the periodic steady state of the run's model, per harmonic of f0
    load = base.problem.response.load_model
    red = ModalReduction(model, load.spatial_loads(model), n_modes=4, n_ritz=4)
    delta = 1e-3
    hi, lo = (Inertia(model).steady_state(base, s * delta, reduction=red, n_harmonics=3, loss=Inertia.loss)
              for s in (1, -1))
    fd = (hi - lo) / (2 * delta)
    err = np.linalg.norm(column - fd) / np.linalg.norm(fd)
    assert err < 5e-3, err
    # without the run's model the column is the default material's (E = 4.4 kPa, 1070 kg/m^3):
    # the column K^-1 M K^-1 L C b'' (same controls C) has K^-1 twice and M once: off by 4 * 1070 / 1100
    default = Inertia().displacement_jacobian(_baseline(model, with_model=False))[..., 0]
    ratio = np.linalg.norm(default) / np.linalg.norm(column)
    assert abs(ratio - 4 * 1070.0 / 1100.0) < 1e-6, ratio
