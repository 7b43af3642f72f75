"""## Identifiability of the candidate physics terms under each load model (docs/diagnose.md).

For a forward-simulated fitted baseline (coarse two-fold P2 mesh, 2 mm; a superior camera at
4 px/mm; one cycle of f0 = 170 Hz in 12 frames; the measurement is the baseline's own forward
simulation), each candidate's Jacobian of the predicted measurement (motion and gap rows) is
projected off the load model's Jacobian columns; printed is the share of the candidate's signal
the loads cannot absorb, in its least visible direction (vfcli/diagnose/candidates/identifiability.py;
0 to round-off = "not identifiable with this load model").

Load models:

* ``pressure``: shared normal pressure on the inferior and medial surfaces, tied in time to the
  recorded subglottal pressure, plus a degree-4 Bernstein correction (vfcli/model/loads/pressure.py);
* ``pressure, free time``: the same shapes with a free time profile (the Bernstein basis only, no
  tie to the recorded pressure);
* ``free per fold``: the paper's force field, independent per fold (inferior side, 2 x 2 x 5).

Contact acts only where the baseline's folds cross the midplane: its share is computed on the same
load model with the folds pressed together (:func:`pressed`: a medial suction on the pressure
shapes, a medial pull over mid-window on the force field).

Reproduce::

    .venv/bin/python bench/bench_identifiability.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.camera.camera import Camera  # noqa: E402
from vfcli.diagnose.candidate import Baseline  # noqa: E402
from vfcli.diagnose.candidates import CANDIDATES  # noqa: E402
from vfcli.diagnose.candidates.identifiability import identifiability, load_basis  # noqa: E402
from vfcli.diagnose.candidates.screening import load_jacobian  # noqa: E402
from vfcli.inverse.problem import ObjectiveSettings, Problem, synthesize_measurement  # noqa: E402
from vfcli.model.fem import ElasticModel  # noqa: E402
from vfcli.model.loads.bernstein import bernstein  # noqa: E402
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec  # noqa: E402
from vfcli.model.loads.pressure import PressureLoad  # noqa: E402
from vfcli.model.mesh import build_mesh  # noqa: E402
from vfcli.model.response.quasi_static import QuasiStaticResponse  # noqa: E402

F0_HZ = 170.0
N_FRAMES = 12
CAMERA = Camera(px_per_mm=4, rotation_deg=0, offset_px=(2.0, 24.15), width=64, height=48)
SETTINGS = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, gap_length_mm=0.25)


class FreeTimePressure(PressureLoad):
    """The pressure shapes with a free Bernstein time profile (no column tied to the recorded pressure)."""

    measured_time_basis = False          # a free polynomial time basis: the inertia column by differences

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.n_time = self.time_degree + 1

    def time_basis(self, times):
        t1, t2 = self.t_range
        return bernstein(self.time_degree, (np.atleast_1d(np.asarray(times, float)) - t1) / (t2 - t1))

    def parameter_names(self):
        return [f"{s}@t{k}" for s in self.spatial_names() for k in range(self.n_time)]

    def penalty_operator(self):
        import scipy.sparse as sp
        return sp.identity(self.n_params, format="csr")


def _pressure(t):
    w = 2 * np.pi * F0_HZ
    return 800.0 + 500.0 * np.sin(w * t) + 150.0 * np.sin(2 * w * t + 0.7)


def pressed(load, x: np.ndarray) -> np.ndarray:
    """The controls x with the folds pressed together past the midplane for part of the cycle (the
    contact column is zero where the folds never reach it): a medial suction on the pressure shapes,
    a medial pull (sin^2 over the window, largest mid-window) on the per-fold force field."""
    c = load.control_matrix(x).copy()
    if isinstance(load, ForceField):
        s = np.linspace(0.0, 1.0, load.n_time)
        for _, fold, _, comp, sl in load.blocks:
            if comp == "y":
                c[sl] += (1.0 if fold == "fold0" else -1.0) * 400.0 * np.sin(np.pi * s) ** 2
    else:
        c[1] = -0.6 * c[0]
    return c.ravel()


def baselines(model, press: bool = False):
    fps = N_FRAMES * F0_HZ
    times = 0.002 + np.arange(N_FRAMES) / fps
    window = (times[0], times[-1] + 1.0 / fps)
    tp = np.arange(0.0, 0.02, 1e-5)
    rng = np.random.default_rng(0)
    out = {}
    for name in ("pressure", "pressure, free time", "free per fold"):
        if name == "free per fold":
            load = ForceField(ForceFieldSpec((2, 2, 5), ("inferior",)), window)
            s = np.linspace(0.0, 1.0, load.n_time)
            x = np.outer(rng.uniform(-1, 1, load.n_spatial) * 250.0, np.sin(2 * np.pi * s)).ravel()
        else:
            cls = PressureLoad if name == "pressure" else FreeTimePressure
            load = cls(tp, _pressure(tp), window, time_degree=4)
            c = np.zeros((load.n_spatial, load.n_time))
            if name == "pressure":
                c[0, 0], c[1, 0], c[1 + load.medial_x, 0] = load.p_ref, 0.6 * load.p_ref, -0.2 * load.p_ref
                c[1, 1:] = np.linspace(-60.0, 60.0, load.n_time - 1)
            else:   # the same aerodynamic-like load, its time course as a free polynomial
                c[0] = 800.0 + 500.0 * np.sin(np.linspace(0, 2 * np.pi, load.n_time))
                c[1] = 0.6 * c[0]
            x = c.ravel()
        if press:
            x = pressed(load, x)
        response = QuasiStaticResponse(model, load)
        meas = synthesize_measurement(model.mesh, CAMERA, response, times, x, SETTINGS)
        base = Baseline.at(Problem(model.mesh, CAMERA, response, meas, SETTINGS), x, F0_HZ)
        base.model = model
        out[name] = base
    return out


def main() -> None:
    t0 = time.perf_counter()
    model = ElasticModel(build_mesh(target_edge_mm=2.0))
    rows = {}
    pressed_bases = baselines(model, press=True)
    for name, base in baselines(model).items():
        q = load_basis(load_jacobian(base))
        rows[name] = {c.name: identifiability(c.jacobian(base), q=q) for c in CANDIDATES if c.name != "contact"}
        print(f"{name}: {base.problem.n_params} load parameters, {len(base.residual_vector())} rows", flush=True)
        # contact acts only where the folds cross the midplane: its share on the pressed baseline
        contact = next(c for c in CANDIDATES if c.name == "contact")
        other = pressed_bases[name]
        rows[name]["contact"] = identifiability(contact.jacobian(other), q=load_basis(load_jacobian(other)))
        print(f"  pressed: the folds cross the midplane by up to {contact.overlap(other).max():.2g} mm "
              f"in {int(np.sum(contact.overlap(other) > 0))} of {N_FRAMES + 1} times", flush=True)
    names = [c.name for c in CANDIDATES]
    print("\n| load model | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for name, r in rows.items():
        cells = [f"{r[n].residual_fraction:.2g}" + ("" if r[n].identifiable else " (absorbed)") for n in names]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
