"""Small fitted cases for the candidate tests: a coarse two-fold FEM, a superior camera, one cycle.

``pressure_case``: the pressure load model tied to a recorded subglottal pressure (two harmonics
of f0 over one cycle), the measurement its own forward simulation; ``force_field_case``: the
paper's free per-fold force field (tests/_forward_case.py).  Both return a
:class:`vfcli.diagnose.candidate.Baseline` at the true controls (the fit of the noise-free data).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from _forward_case import F0_HZ, elastic_model, true_controls
from vfcli.camera.camera import Camera
from vfcli.diagnose.candidate import Baseline
from vfcli.inverse.problem import ObjectiveSettings, Problem, synthesize_measurement
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.loads.pressure import PressureLoad
from vfcli.model.response.quasi_static import QuasiStaticResponse

#: a coarser view than tests/_forward_case.py's (4 px/mm): fewer rows, the same surface
CAMERA = Camera(px_per_mm=4, rotation_deg=0, offset_px=(2.0, 24.15), width=64, height=48)
SETTINGS = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, gap_length_mm=0.25)


def subglottal_pressure(t: np.ndarray) -> np.ndarray:
    """A recorded-like p_s(t), Pa: mean, fundamental and second harmonic of F0_HZ."""
    w = 2 * np.pi * F0_HZ
    return 800.0 + 500.0 * np.sin(w * t) + 150.0 * np.sin(2 * w * t + 0.7)


def pressure_controls(load: PressureLoad) -> np.ndarray:
    """Controls of an aerodynamic-like load: the inferior and medial mean shapes carry the measured
    pressure, a small free Bernstein correction on the medial shapes."""
    c = np.zeros((load.n_spatial, load.n_time))
    c[0, 0] = load.p_ref
    c[1, 0] = 0.6 * load.p_ref
    c[1 + load.medial_x, 0] = -0.2 * load.p_ref
    c[1, 1:] = np.linspace(-60.0, 60.0, load.n_time - 1)
    return c.ravel()


@lru_cache(maxsize=4)
def pressure_case(n_frames: int = 12, time_degree: int = 4, pressure_noise_pa: float = 0.0,
                  edge_mm: float = 2.0) -> Baseline:
    """pressure_noise_pa: white noise (Pa RMS, seed 0) on the recorded pressure, sampled at 100 kHz (the
    loads then carry it; the measurement is their own forward simulation).  edge_mm: the mesh's target
    edge (2 mm: 7029 free DOFs per fold; 2.5 mm: 3480)."""
    model = elastic_model(edge_mm)
    fps = n_frames * F0_HZ
    times = 0.002 + np.arange(n_frames) / fps
    sim = np.append(times, times[-1] + 1.0 / fps)
    tp = np.arange(0.0, 0.02, 1e-5)
    ps = subglottal_pressure(tp) + np.random.default_rng(0).normal(0.0, pressure_noise_pa, tp.shape)
    load = PressureLoad(tp, ps, (sim[0], sim[-1]), time_degree=time_degree)
    response = QuasiStaticResponse(model, load)
    x = pressure_controls(load)
    meas = synthesize_measurement(model.mesh, CAMERA, response, times, x, SETTINGS)
    problem = Problem(model.mesh, CAMERA, response, meas, SETTINGS)
    base = Baseline.at(problem, x, F0_HZ)
    base.model = model
    return base


@lru_cache(maxsize=2)
def force_field_case(n_frames: int = 12) -> Baseline:
    """The paper's free force field, independent per fold (inferior side, 2 x 2 x 5 per piece)."""
    model = elastic_model()
    fps = n_frames * F0_HZ
    times = 0.002 + np.arange(n_frames) / fps
    field = ForceField(ForceFieldSpec((2, 2, 5), ("inferior",)), (times[0], times[-1] + 1.0 / fps))
    response = QuasiStaticResponse(model, field)
    x = true_controls(field)
    meas = synthesize_measurement(model.mesh, CAMERA, response, times, x, SETTINGS)
    base = Baseline.at(Problem(model.mesh, CAMERA, response, meas, SETTINGS), x, F0_HZ)
    base.model = model
    return base


def reduced_inertia(case):
    """(an Inertia candidate on a Ritz reduction of ``case``'s model, that reduction): 8 modes and 6 Ritz
    vectors (the complete expansion of this 2 mm mesh takes minutes); data made with the candidate use
    the same reduction."""
    from vfcli.diagnose.candidates import Inertia
    from vfcli.model.response.modal import ModalReduction

    load = case.problem.response.load_model
    red = ModalReduction(case.model, load.spatial_loads(case.model), n_modes=8, n_ritz=6)

    class _Reduced(Inertia):
        def reduction(self, baseline, n_harmonics=6, centre=1.0, map=None):
            return red

    return _Reduced(case.model), red


def reduced_damping(case):
    """A KelvinVoigtDamping candidate on :func:`reduced_inertia`'s Ritz reduction of ``case``'s model
    (the complete expansion would take half a minute per case); data made with it use the same one."""
    from vfcli.diagnose.candidates import KelvinVoigtDamping

    return KelvinVoigtDamping(case.model, modal=reduced_inertia(case)[0])
