"""Inertia's confirmation refit on the small pressure case: the density from a quasi-static fit, the reduction
recentred on the estimate, and the mesh part of its interval against data made on a finer mesh (split from
tests/test_diagnose_refit.py so that the suite's two workers can share its longest tests)."""
from __future__ import annotations

import numpy as np

from _candidates_case import CAMERA, SETTINGS, pressure_case, reduced_inertia
from _forward_case import direct_transfer
from _refit_case import _Shown, case_with
from vfcli.diagnose.candidate import Baseline
from vfcli.diagnose.candidates import Inertia
from vfcli.diagnose.refit import joint_fit, refit
from vfcli.inverse.problem import Problem, synthesize_measurement


def test_inertia_refit_finds_the_tissue_density_from_a_quasi_static_fit():
    """Data with the folds' own mass (density factor 1: f0 = 170 Hz above their lowest modes, the steady
    state unlike the quasi-static motion); the baseline is the quasi-static fit of those data, as a run's
    is.  The refit must fit the loads with the mass switched on to find the density: loads fitted to the
    quasi-static model make every start density worse than none.  24 frames per cycle: the model's
    frame-time velocity (a central difference, vfcli.inverse.stencil) sees harmonic k of f0 at
    sin(2 pi k / n) / (2 pi k / n) of its size with n frames per cycle, none at all at n / 2, and with the
    12 frames of the other cases the refit stopped at density 0.61 (E 2.2 where the truth's is 0)."""
    b0 = pressure_case(24, 4)
    cand, _ = reduced_inertia(b0)                      # the data are simulated with the same reduction
    data = case_with(cand, (1.0,), n_frames=24)
    fitted = joint_fit(data.problem, data.x, None, data.f0_hz, max_iterations=10)
    base = Baseline.at(data.problem, fitted.x, data.f0_hz, model=b0.model)
    r = refit(base, cand, max_iterations=10)
    print("inertia refit: theta", r.history["theta"].ravel(), "E", r.history["total"])
    assert abs(r.theta[0] - 1.0) < 0.01
    assert r.history["total"][-1] < 1e-2 * fitted.history["total"][-1]


def _direct_steady_state(base, density: float, loss: float) -> np.ndarray:
    """(T, N, 3) periodic steady state of the case's load at ``density`` by a direct sparse solve per harmonic of
    f0 (:func:`_forward_case.direct_transfer`, the reference the modal reduction is checked against), mm.  At
    density 0 every harmonic has the same matrix: solved once."""
    import scipy.sparse as sp

    from vfcli.model.response.modal import harmonic_fit

    model, p = base.model, base.problem
    load, t = p.response.load_model, p.sim_times
    spec = harmonic_fit(load.time_basis(t) @ load.control_matrix(base.x).T, t, base.f0_hz, Inertia.n_harmonics)
    loads = load.spatial_loads(model)
    loads = loads.toarray() if sp.issparse(loads) else np.asarray(loads)
    w0 = 2 * np.pi * base.f0_hz
    out = np.zeros((len(t), model.mesh.n_nodes, 3))
    transfer = None
    for k in range(spec.shape[0]):
        if transfer is None or density:
            transfer = direct_transfer(model, loads, k * w0, density, 0.0, loss)      # (N, 3, S)
        out += np.real(np.exp(1j * k * w0 * t)[:, None, None] * (transfer @ spec[k])[None])
    return out


def test_inertia_refit_recentres_its_reduction_on_the_estimate(monkeypatch):
    """Data with twice the folds' density, made by a direct solve per harmonic (the pressure case on the
    2.5 mm mesh, 3480 free DOFs per fold, with the complete expansion's limit lowered below that so that
    inertia uses the Ritz reduction with shifted vectors at k f0 a 2 mm run mesh gets, exact at density 1
    only).  Undamped, that reduction misses the steady state at density 2 by 85 % (measured), the one
    re-centred there is exact (1e-11); the refit, re-centring once on its estimate (2.0037; 2.0017 since the
    reference is solved through ``direct_transfer``, session 33: its first step moves with the data's last
    digits), finds 1.9968 (1.9967) +- 0.0010 (measured): 0.16 % from the truth, the error the reduction centred
    0.3 % away leaves (within RECENTRE_TOL, so not re-centred again), which the refit's sd does not contain.  Here the
    refit kept at density 1 stays at its start value 2 (measured with ``recentre`` disabled; it fails the centre's
    assertion); on the 2 mm mesh (7029 free DOFs per fold, 4 times this test's time) it stopped at 2.080 +- 0.004
    and re-centred at 1.9995 +- 0.0008 (session 21)."""
    import vfcli.diagnose.candidates.inertia as inertia

    monkeypatch.setattr(inertia, "COMPLETE_MAX_DOFS", 3000)
    b0 = pressure_case(24, 4, edge_mm=2.5)
    assert not inertia.complete_expansion(b0.model)
    cand = Inertia(b0.model)
    direct = _direct_steady_state(b0, 2.0, 0.0)
    for centre, bound in ((1.0, None), (2.0, 1e-8)):
        red = cand.reduction(b0, cand.n_harmonics, centre)
        err = (np.linalg.norm(cand.steady_state(b0, 2.0, red, cand.n_harmonics) - direct)
               / np.linalg.norm(direct - direct.mean(0)))
        print(f"undamped steady state at density 2 from the reduction centred on {centre}: {err:.2e} relative")
        assert (err < bound) if bound else (err > 0.5)
    p = b0.problem
    disp = b0.displacements + _direct_steady_state(b0, 2.0, cand.loss) - _direct_steady_state(b0, 0.0, cand.loss)
    meas = synthesize_measurement(p.mesh, CAMERA, _Shown(p.response, disp, p.sim_times), p.meas.times, b0.x, SETTINGS)
    data = Baseline.at(Problem(p.mesh, CAMERA, p.response, meas, SETTINGS), b0.x, b0.f0_hz)
    fitted = joint_fit(data.problem, data.x, None, data.f0_hz, max_iterations=10)
    base = Baseline.at(data.problem, fitted.x, data.f0_hz, model=b0.model)
    cand = Inertia(b0.model)
    r = refit(base, cand, max_iterations=10)
    print("density", r.history["theta"].ravel(), "sd", r.sd, "centre", cand.centre(base))
    assert abs(r.theta[0] - 2.0) < 0.004 and r.sd[0] < 2e-3       # measured 1.9968 (1.9967) +- 0.0010
    assert cand.centre(base) != 1.0 and abs(np.sqrt(r.theta[0] / cand.centre(base)) - 1) < 0.01
    assert not cand.recentre(base, r.theta)                                 # stays where it is


def test_inertia_mesh_part_predicts_the_density_a_finer_meshs_data_move_the_refit_by():
    """Data made on the folds' 1.2 times finer mesh (vfcli.model.refine.finer_model; the pressure case's 2.5 mm
    mesh, density 1, the steady state by direct solves per harmonic) and fitted on the 2.5 mm mesh: the
    refitted density comes out high by the stiffness the coarser mesh adds (measured 1.0742 +- 0.0032), and the
    mesh part of its stated sd, |theta| times Inertia.mesh_shift, says how much: 0.0733 (0.99 of the shift; the lowest six
    modes' mean, the mesh part until session 67, said 0.023).  The mesh part predicts, from the two meshes'
    spectra, a refit on the finer mesh it does not run; corrected by it (the diagnosis's estimate since session
    68) the density is 1.0056."""
    from types import SimpleNamespace

    from vfcli.config import MeshConfig
    from vfcli.model.refine import finer_model
    from vfcli.model.response.quasi_static import QuasiStaticResponse

    b0 = pressure_case(24, 4, edge_mm=2.5)
    p = b0.problem
    fine = finer_model(MeshConfig(target_edge_mm=2.5), b0.model)
    cand = Inertia(b0.model)
    response = QuasiStaticResponse(fine, p.response.load_model)
    on_fine = SimpleNamespace(model=fine, problem=SimpleNamespace(response=response, sim_times=p.sim_times),
                              x=b0.x, f0_hz=b0.f0_hz)
    disp = (response.displacements(b0.x, p.sim_times) + _direct_steady_state(on_fine, 1.0, cand.loss)
            - _direct_steady_state(on_fine, 0.0, cand.loss))
    meas = synthesize_measurement(fine.mesh, CAMERA, _Shown(response, disp, p.sim_times), p.meas.times, b0.x,
                                  SETTINGS)
    problem = Problem(p.mesh, CAMERA, p.response, meas, SETTINGS)
    fitted = joint_fit(problem, b0.x, None, b0.f0_hz, max_iterations=10)
    base = Baseline.at(problem, fitted.x, b0.f0_hz, model=b0.model)
    base.finer_model = lambda: fine
    r = refit(base, cand, max_iterations=10)
    shift = r.theta[0] - 1.0
    (delta,) = cand.mesh_shift(base, r.theta, r.x)
    part = abs(r.theta[0] * delta)                                # the mesh part of the stated sd
    corrected = r.theta[0] / (1.0 + delta)                        # as the diagnosis states it (mesh_corrected)
    print(f"density {r.theta[0]:.4f} +- {r.sd[0]:.4f}: shift {shift:.4f}, mesh part {part:.4f} ({part / shift:.2f}), "
          f"corrected {corrected:.4f}")
    assert shift > 10 * r.sd[0]                                   # a mesh bias the noise-free refit's sd does not see
    assert 0.85 < part / shift < 1.15                             # measured 0.99
    assert abs(corrected - 1.0) < 0.15 * shift                    # measured 1.0056: 0.08 of the shift left
