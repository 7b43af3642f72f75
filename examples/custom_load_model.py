"""A load model of your own, plugged into the fit: a harmonic subglottal pressure.

The optimiser sees a load model only through ``vfcli.model.loads.force_field.LoadModel``:
``spatial_loads`` (load vectors of the spatial patterns on the FEM model), ``time_basis``
(functions of time) and ``spatial_names``; the loads are ``F(t) = S @ C @ b(t)`` with the
control matrix C (n_spatial, n_time) the fitted parameters. Here: a uniform normal pressure
on each fold's inferior and medial surfaces (two spatial patterns, one per fold), varying in
time as a mean plus the first two harmonics of f0 (five time functions), so 10 parameters
instead of the paper's hundreds.

The example simulates what a superior-view camera records under a known pressure history
(mean 300 Pa, 1st harmonic 200 Pa), adds white noise (10 % of the RMS velocity), fits the 10
parameters from a zero start with Gauss-Newton, and compares the recovered pressures with the truth.

Run: ``python examples/custom_load_model.py`` (10-25 s). tests/test_examples.py checks
``PRESSURE_ERROR_REL`` (relative RMS error of the recovered pressure history).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.inverse.optimizers.base import fit
from vfcli.inverse.problem import ObjectiveSettings, Problem, synthesize_measurement
from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import LoadModel
from vfcli.model.mesh import TAG_INFERIOR, TAG_MEDIAL, build_mesh
from vfcli.model.response.quasi_static import QuasiStaticResponse


class HarmonicPressure(LoadModel):
    """Uniform pressure (Pa) on each fold's inferior and medial faces, mean + ``n_harmonics`` of f0.

    Parameters
    ----------
    f0_hz : fundamental frequency, Hz.
    n_harmonics : harmonics in the time basis (n_time = 1 + 2 n_harmonics: 1, cos, sin, ...).
    """

    def __init__(self, f0_hz: float, n_harmonics: int = 2) -> None:
        self.f0_hz, self.n_harmonics = float(f0_hz), int(n_harmonics)
        self.n_spatial = 2
        self.n_time = 1 + 2 * self.n_harmonics

    def spatial_loads(self, model) -> np.ndarray:
        """(n_dofs, 2) load of 1 Pa on fold 0's, and on fold 1's, inferior and medial faces (Pa mm^2)."""
        cols = []
        for fold in (0, 1):
            mask = model.quadrature_mask(tags=[TAG_INFERIOR, TAG_MEDIAL], folds=[fold])
            cols.append(model.pressure_operator(mask) @ np.ones(int(mask.sum())))
        return np.column_stack(cols)

    def time_basis(self, times: np.ndarray) -> np.ndarray:
        """(T, 1 + 2 n_harmonics): 1, cos(2 pi k f0 t), sin(2 pi k f0 t) for k = 1..n_harmonics."""
        w = 2 * np.pi * self.f0_hz * np.atleast_1d(np.asarray(times, float))[:, None] * np.arange(1, self.n_harmonics + 1)
        return np.column_stack([np.ones(len(w)), np.stack([np.cos(w), np.sin(w)], axis=-1).reshape(len(w), -1)])

    def spatial_names(self) -> list[str]:
        return ["fold0/pressure", "fold1/pressure"]


F0_HZ, N_FRAMES = 170.0, 10
camera = Camera(px_per_mm=8, rotation_deg=0, offset_px=(4.0, 48.3), width=128, height=96)
settings = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, gap_length_mm=0.25)

model = ElasticModel(build_mesh(target_edge_mm=2.0))
load = HarmonicPressure(F0_HZ)
response = QuasiStaticResponse(model, load)
times = 0.002 + np.arange(N_FRAMES) / (N_FRAMES * F0_HZ)   # one period

# the truth: both folds 300 Pa mean, 200 Pa first harmonic, a little second harmonic, fold 0 a bit weaker
c_true = np.array([[280.0, 150.0, 120.0, 30.0, -20.0],
                   [300.0, 160.0, 130.0, 25.0, -15.0]])
clean = synthesize_measurement(model.mesh, camera, response, times, c_true.ravel(), settings)
rng = np.random.default_rng(0)   # white noise, 10 % of the RMS velocity, on the visible surface
noise = 0.1 * np.sqrt(np.mean(clean.velocity[clean.valid] ** 2)) * rng.standard_normal(clean.velocity.shape)
problem = Problem(model.mesh, camera, response, replace(clean, velocity=clean.velocity + noise * clean.valid[..., None]),
                  settings)
result = fit(problem, method="gauss-newton", max_iter=30)

c_fit = load.control_matrix(result.x)
t_fine = np.linspace(times[0], times[-1], 200)
p_true, p_fit = c_true @ load.time_basis(t_fine).T, c_fit @ load.time_basis(t_fine).T   # (2, 200) Pa
PRESSURE_ERROR_REL = float(np.sqrt(np.mean((p_fit - p_true) ** 2) / np.mean(p_true ** 2)))

if __name__ == "__main__":
    print(f"E {result.history['total'][0]:.3g} -> {result.history['total'][-1]:.3g} in {result.state.iteration} iterations")
    for name, a, b in zip(load.parameter_names(), c_fit.ravel(), c_true.ravel()):
        print(f"  {name:>20s}: fitted {a:8.2f} Pa, true {b:8.2f} Pa")
    print(f"pressure history: relative RMS error {PRESSURE_ERROR_REL:.2e}")
