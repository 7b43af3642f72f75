"""A forward-simulated fitting case with known control values (no phantom files).

Used by ``tests/test_objective.py`` and ``tests/test_optimizer.py``.  A coarse
two-fold mesh, a P2 elastic model, a superior-view camera, the paper's force
field with a known smooth control vector (random spatial amplitudes times one
period of a sine in time, plus a lateral pull that opens and closes the gap),
and the measurement it produces (velocity on the pixel grid, gap silhouettes).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.mesh import build_mesh
from vfcli.inverse.problem import Measurement, ObjectiveSettings, Problem, synthesize_measurement
from vfcli.model.response.quasi_static import QuasiStaticResponse

CAMERA = Camera(px_per_mm=8, rotation_deg=0, offset_px=(4.0, 48.3), width=128, height=96)
F0_HZ = 170.0
SETTINGS = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, gap_length_mm=0.25)


@lru_cache(maxsize=2)
def elastic_model(edge_mm: float = 2.0) -> ElasticModel:
    model = ElasticModel(build_mesh(target_edge_mm=edge_mm))
    model.factorize()
    return model


def direct_transfer(model: ElasticModel, loads: np.ndarray, omega: float, density: float, tau: float, loss: float,
                    folds: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """(N, 3, S) complex: ((1 + i loss)(1 + i omega tau) K - density omega^2 M)^-1 F, the reference the
    modal reduction and the inertia refit are checked against (tests/test_modal.py, tests/test_diagnose_refit_inertia.py).

    loads : (n_dofs, S) load vectors F, Pa mm^2.  omega : rad/s.  density : factor on the mass matrix.
    A complex sparse LU (scipy's SuperLU with its symmetric ordering: the matrix is complex symmetric), fold by
    fold (the folds are separate bodies; a fold left out is 0).  Before session 33 the equivalent real system
    ``[[A, -B], [B, A]]`` or the two folds' matrix together, with SuperLU's default ordering: the same transfer,
    several times the factorisation's time.  Where fold 0 is fold 1's mirror image with the same modulus
    (:attr:`vfcli.model.fem.ElasticModel.mirror`, as the model's own static solves use it), fold 0's loads are
    mirrored onto fold 1 and solved with fold 1's factorisation: one factorisation instead of two."""
    import scipy.sparse.linalg as spl

    c = (1 + 1j * loss) * (1 + 1j * omega * tau)
    loads = np.asarray(loads, complex)
    u = np.zeros(loads.shape, complex)
    share = (model.is_mirrored and set(folds) == {0, 1}
             and np.array_equal(model.folds[0].youngs_pa, model.folds[1].youngs_pa))
    span = [slice(model.offsets[k], model.offsets[k + 1]) for k in (0, 1)]
    for k in ((1,) if share else folds):
        fold = model.folds[k]
        idx = model.offsets[k] + fold.free
        a = (c * fold.stiffness[fold.free][:, fold.free] - density * omega ** 2 * model.mass[idx][:, idx]).tocsc()
        lu = spl.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1, options={"SymmetricMode": True})
        if not share:
            u[idx] = lu.solve(loads[idx])
            continue
        rhs = np.concatenate([loads[span[1]], model.fold1_from_fold0(loads[span[0]])], axis=1)
        sol = np.zeros_like(rhs)
        sol[fold.free] = lu.solve(rhs[fold.free])
        m = loads.shape[1]
        u[span[1]], u[span[0]] = sol[:, :m], model.fold0_from_fold1(sol[:, m:])
    re, im = model.vertex_displacements(u.real), model.vertex_displacements(u.imag)
    return np.moveaxis(re + 1j * im, 0, -1)


@dataclass
class Case:
    model: ElasticModel
    field: ForceField
    response: QuasiStaticResponse
    measurement: Measurement
    problem: Problem
    x_true: np.ndarray


def true_controls(field: ForceField, seed: int = 0, amplitude_pa: float = 250.0) -> np.ndarray:
    """Smooth known control values: random spatial amplitudes x sin(2 pi s), plus a lateral pull."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, field.n_time)
    c = np.outer(rng.uniform(-1, 1, field.n_spatial) * amplitude_pa, np.sin(2 * np.pi * s))
    for name, fold, _, comp, sl in field.blocks:
        if comp == "y":
            sign = -1.0 if fold == "fold0" else 1.0
            c[sl] += sign * amplitude_pa * np.sin(np.pi * s) ** 2
    return c.ravel()


def forward_case(resolution=(2, 2, 6), sides=("inferior",), n_frames: int = 12, tie_folds: bool = False,
                 settings: ObjectiveSettings = SETTINGS, seed: int = 0) -> Case:
    model = elastic_model()
    fps = n_frames * F0_HZ  # the frames cover one period
    times = 0.002 + np.arange(n_frames) / fps
    field = ForceField(ForceFieldSpec(resolution, sides, tie_folds), (times[0], times[-1] + 1.0 / fps))
    response = QuasiStaticResponse(model, field)
    x_true = true_controls(field, seed)
    meas = synthesize_measurement(model.mesh, CAMERA, response, times, x_true, settings)
    problem = Problem(model.mesh, CAMERA, response, meas, settings)
    return Case(model, field, response, meas, problem, x_true)
