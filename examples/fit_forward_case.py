"""Forward case -> fit -> uncertainty, with the library alone (no store, no files).

A coarse M5 model (both folds, P2 elements), the paper's force field on the inferior surfaces
(2 x 2 control points in space, 3 in time), a known smooth control vector, and the measurement
it produces through a superior-view camera: velocity on the pixel grid and the gap silhouettes.
White noise (10 % of the RMS velocity) is added to the velocity; the Gauss-Newton fit (with a
weak ridge on the controls) then recovers them, and the Laplace posterior states how well: the
standard deviation of every vertex displacement. The camera never sees the inferior surface.

Run: ``python examples/fit_forward_case.py`` (10-25 s). tests/test_examples.py checks
``INFERIOR_ERROR_REL`` (relative RMS error of the inferior displacements).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.optimizers.base import fit
from vfcli.inverse.problem import ObjectiveSettings, Problem, synthesize_measurement
from vfcli.inverse.uncertainty import displacement_std, effective_sample_size, posterior
from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.mesh import SIDE_INFERIOR, build_mesh
from vfcli.model.response.quasi_static import QuasiStaticResponse

F0_HZ, N_FRAMES, NOISE, RIDGE = 170.0, 8, 0.10, 1e-11  # ridge: a weak Gaussian prior on the controls
camera = Camera(px_per_mm=8, rotation_deg=0, offset_px=(4.0, 48.3), width=128, height=96)
settings = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, gap_length_mm=0.25, ridge_weight=RIDGE)

model = ElasticModel(build_mesh(target_edge_mm=2.0))            # the M5 folds, 2 mm tetrahedra
fps = N_FRAMES * F0_HZ                                           # the frames cover one period
times = 0.002 + np.arange(N_FRAMES) / fps
field = ForceField(ForceFieldSpec((2, 2, 3), ("inferior",), False), (times[0], times[-1] + 1 / fps))
response = QuasiStaticResponse(model, field)

# known controls (Pa): random spatial amplitudes x sin(2 pi s), and a lateral pull opening the gap
rng = np.random.default_rng(0)
s = np.linspace(0.0, 1.0, field.n_time)
controls = np.outer(rng.uniform(-1, 1, field.n_spatial) * 250.0, np.sin(2 * np.pi * s))
for _, fold, _, comp, rows in field.blocks:
    if comp == "y":
        controls[rows] += (-250.0 if fold == "fold0" else 250.0) * np.sin(np.pi * s) ** 2
x_true = controls.ravel()

clean = synthesize_measurement(model.mesh, camera, response, times, x_true, settings)
rms_v = np.sqrt(np.mean(clean.velocity[clean.valid] ** 2))
noise = NOISE * rms_v * rng.standard_normal(clean.velocity.shape) * clean.valid[..., None]
problem = Problem(model.mesh, camera, response, replace(clean, velocity=clean.velocity + noise), settings)

result = fit(problem, method="gauss-newton", max_iter=20)
x = result.x

# Laplace posterior at the optimum, scaled by the motion residuals' own size and correlation
u = problem.displacements(x)
frames = problem.freeze(x, u)
model_gn = gauss_newton_model(problem, x, frames, u)
post = posterior(model_gn, effective_sample_size(problem.motion_residuals(x, frames)))
std = displacement_std(post.covariance, model_gn.linearization)  # (F + 1, N, 3) mm

inferior = model.mesh.node_side == SIDE_INFERIOR
u_true = problem.displacements(x_true)
err = (u - u_true)[:, inferior]
INFERIOR_ERROR_REL = float(np.sqrt(np.mean(err ** 2) / np.mean(u_true[:, inferior] ** 2)))
INFERIOR_STD_REL = float(np.sqrt(np.mean(std[:, inferior] ** 2) / np.mean(u_true[:, inferior] ** 2)))
COVERAGE_90 = float(np.mean(np.abs(err) <= 1.645 * std[:, inferior]))

if __name__ == "__main__":
    print(f"E {result.history['total'][0]:.3g} -> {result.history['total'][-1]:.3g} in {result.state.iteration} "
          f"Gauss-Newton iterations")
    print(f"inferior surface (unseen): error {100 * INFERIOR_ERROR_REL:.1f} %, stated std {100 * INFERIOR_STD_REL:.1f} %, "
          f"90 % intervals cover {100 * COVERAGE_90:.0f} % of the truth")
