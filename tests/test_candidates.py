"""Candidate physics terms (vfcli.diagnose.candidates): their columns, identifiability, screening.

- the inertia and damping columns are the derivatives (density, retardation time) of the periodic
  steady state of the modal reduction, an independent computation (harmonics of f0 in the
  frequency domain against time derivatives of the load); inertia's also with sensor noise on the
  recorded pressure (the refit's own extension), and it says how far in density its linearisation
  reaches (the folds' lowest mode against f0);
- identifiability (the reference note "What superior-surface data can and cannot reveal"): under
  the pressure load model a stiffness asymmetry keeps exactly its antisymmetric half (the shared
  load makes only mirror-symmetric motion) and inertia and damping keep a residual, while free
  per-fold loads absorb asymmetry and damping to round-off;
- the score test finds an injected asymmetry and estimates it.
"""
from __future__ import annotations

import numpy as np
import pytest

from _candidates_case import force_field_case, pressure_case, reduced_inertia
from vfcli.diagnose.candidate import Baseline, Candidate
from vfcli.diagnose.candidates import CANDIDATES, Inertia, KelvinVoigtDamping, StiffnessAsymmetry
from vfcli.diagnose.candidates.identifiability import identifiability, load_basis
from vfcli.diagnose.candidates.blocks import screen_run
from vfcli.diagnose.candidates.screening import load_jacobian, screen_baseline
from vfcli.inverse.problem import Problem, synthesize_measurement
from vfcli.model.response.modal import ModalReduction


def test_every_candidate_follows_the_protocol_and_states_its_signature():
    for c in CANDIDATES:
        assert isinstance(c, Candidate)
        assert c.n_params == len(c.parameter_names) >= 1 and c.signature and c.name
    assert len({c.name for c in CANDIDATES}) == len(CANDIDATES)


def test_inertia_and_damping_columns_are_derivatives_of_the_modal_steady_state():
    base = pressure_case(time_degree=0)            # time basis [p_s / p_ref, 1]: periodic at f0
    inertia = Inertia(base.model)
    load = base.problem.response.load_model
    red = ModalReduction(base.model, load.spatial_loads(base.model), n_modes=4, n_ritz=4)
    delta = 1e-3
    for column, kw in ((inertia.displacement_jacobian(base)[..., 0], "density"),
                       (KelvinVoigtDamping().displacement_jacobian(base)[..., 0], "retardation_s")):
        scale = 1.0 if kw == "density" else 1e-3          # damping columns are per ms
        hi, lo = (inertia.steady_state(base, **({"density": s * delta, "loss": inertia.loss} if kw == "density"
                                                 else {"density": 0.0, "retardation_s": s * delta * scale}),
                                       reduction=red, n_harmonics=3) for s in (1, -1))
        fd = (hi - lo) / (2 * delta)
        err = np.linalg.norm(column - fd) / np.linalg.norm(fd)
        assert err < 5e-3, (kw, err)


def test_inertia_column_is_the_density_derivative_of_its_extension_with_a_noisy_recorded_pressure():
    """The screening's column and the refit's extension are the same model: the column is the derivative
    of the extension at rho = 0 even when the recorded pressure carries sensor noise (a recording's does;
    the loads are tied to it).  A second difference of that pressure at half a frame interval would
    turn its noise into most of the column."""
    base = pressure_case(12, 4, pressure_noise_pa=4.0)
    load = base.problem.response.load_model
    red = ModalReduction(base.model, load.spatial_loads(base.model), n_modes=4, n_ritz=4)

    class _Reduced(Inertia):                           # the Ritz reduction (exact moments at rho = 0), not the
        def reduction(self, baseline, n_harmonics=6, centre=1.0, map=None):  # complete expansion of this 2 mm mesh
            return red

    inertia = _Reduced(base.model)
    delta = 1e-4
    fd = (inertia.extension(base, [delta]) - inertia.extension(base, [-delta])) / (2 * delta)
    column = inertia.displacement_jacobian(base)[..., 0]
    err = np.linalg.norm(column - fd) / np.linalg.norm(fd)
    print(f"inertia column against the derivative of its extension: {err:.2e} relative")
    assert err < 1e-4, err


@pytest.mark.parametrize("d", [0.03, -0.02])
def test_inertia_mesh_part_of_a_uniformly_softer_fine_model_is_that_softening(d):
    """Inertia.mesh_shift (the mesh part of the stated sd is |theta shift|) against a "finer" model that is the fit mesh with E / (1 + d): every mode's omega^2
    falls by the same factor, which a density (1 + d) times the fit's puts back exactly (the loads' scale
    takes 1 / (1 + d)), so the mesh part is |theta d| to round-off whatever the harmonics and the modes
    they excite.  None without a finer model or without f0."""
    from dataclasses import replace
    from types import SimpleNamespace

    from vfcli.model.fem import ElasticModel

    base = pressure_case(12, 4, edge_mm=2.5)
    model = base.model
    soft = ElasticModel(model.mesh, float(np.unique(model.youngs_pa)[0]) / (1 + d), model.poisson,
                        model.density_kg_m3)
    base = replace(base, finer_model=lambda: soft)
    term = Inertia(model)
    term.mesh_modes = (30, 30)                   # exact with any modes: the full 240 cost 8 s a call here
    for theta in (1.0, 0.5):
        (shift,) = term.mesh_shift(base, [theta])
        part = abs(theta * shift)
        print(f"d {d}: theta {theta} mesh part {part:.6g}")
        assert part == pytest.approx(abs(theta * d), rel=1e-6)
    assert Inertia(model).mesh_shift(replace(base, finer_model=None), [1.0]) is None
    assert Inertia(model).mesh_shift(replace(base, f0_hz=float("nan")), [1.0]) is None
    assert Inertia(model).mesh_shift(SimpleNamespace(model=model), [1.0]) is None


def test_inertia_says_how_far_its_linearisation_reaches_in_density():
    """The score test sees densities near 0 only: beyond ``(f_1 / f0)^2`` (the folds' lowest mode f_1 below
    f0) the column does not predict the steady state's change, well inside it it does (harmonic k of f0
    reaches only ``(f_1 / (k f0))^2``: the load here has harmonics 1 and 2).  The screening line says so,
    with the reach computed from the lowest mode."""
    base = pressure_case(12, 0)
    inertia, red = reduced_inertia(base)
    f1 = float(np.sqrt(red.eigenvalues_.min()) / (2 * np.pi))
    reach = (f1 / base.f0_hz) ** 2
    assert abs(inertia.lowest_mode_hz(base) - f1) < 1e-6 * f1
    words = inertia.evidence(base)
    assert f"reaches density factors up to {reach:.2g} at f0" in words and "its profile (the loads refitted" in words, words
    assert words.endswith("(its own line, 'inertia: profile ...')"), words          # it ended "... 0.25, ..., 3) is"
    column = inertia.displacement_jacobian(base)[..., 0]
    off = {}
    for q in (0.02, 1.0 / reach):
        d = inertia.extension(base, [q * reach])
        off[q] = np.linalg.norm(d - q * reach * column) / np.linalg.norm(d)
    print(f"reach {reach:.3g} (f1 = {f1:.1f} Hz); linear prediction off by {off}")
    assert off[0.02] < 0.1 and off[1.0 / reach] > 0.5, off


@pytest.fixture(scope="module")
def fractions():
    out = {}
    for name, base in (("pressure", pressure_case()), ("free per fold", force_field_case())):
        q = load_basis(load_jacobian(base))
        out[name] = {c.name: identifiability(c.jacobian(base), q=q).residual_fraction for c in CANDIDATES}
    return out


@pytest.mark.slow
def test_pressure_model_cannot_absorb_asymmetry_inertia_or_damping(fractions):
    f = fractions["pressure"]
    assert abs(f["asymmetry"] - 0.5) < 0.02, f                    # the antisymmetric half; measured 0.496
    assert 0.005 < f["inertia"] < 0.05, f                          # measured 0.034 (steady-state column)
    assert 0.3 < f["damping"] < 0.95, f                            # tied to the measured p_s; measured 0.69


@pytest.mark.slow
def test_free_per_fold_loads_absorb_asymmetry_and_damping_to_round_off(fractions):
    f = fractions["free per fold"]
    assert f["asymmetry"] < 1e-20 and f["damping"] < 1e-20, f      # measured 6e-31, 3e-30
    assert 1e-5 < f["inertia"] < 1e-2, f                            # small but not absorbed; measured 3.3e-4


class _SofterLeft:
    """The pressure case's response with the left fold softer: its displacement / (1 - s)."""

    def __init__(self, response, left: np.ndarray, s: float) -> None:
        self.inner, self.scale = response, np.where(left, 1.0 / (1.0 - s), 1.0)[None, :, None]
        self.n_params, self.n_vertices = response.n_params, response.n_vertices

    def displacements(self, x, times):
        return self.inner.displacements(x, times) * self.scale

    def penalty_operator(self):
        return self.inner.penalty_operator()


def _noisy_baseline(s: float, seed: int) -> Baseline:
    """The pressure case's baseline (its controls) against data with the left fold softened by s,
    plus white velocity noise of 2 mm/s on every valid pixel."""
    base = pressure_case()
    p = base.problem
    left = np.zeros(p.mesh.n_nodes, bool)
    left[p.mesh.fold_nodes(0)] = True
    meas = synthesize_measurement(p.mesh, p.camera, _SofterLeft(p.response, left, s), p.meas.times, base.x,
                                  p.settings)
    noise = np.random.default_rng(seed).normal(scale=2.0, size=meas.velocity.shape) * meas.valid[..., None]
    meas = type(meas)(meas.times, meas.velocity + noise, meas.valid, meas.gap_lo, meas.gap_hi, meas.gap)
    return Baseline.at(Problem(p.mesh, p.camera, p.response, meas, p.settings), base.x, base.f0_hz)


@pytest.mark.slow
@pytest.mark.parametrize("screen", [screen_baseline, screen_run], ids=["dense", "gauss-newton-blocks"])
def test_score_test_finds_an_injected_asymmetry_and_estimates_it(screen):
    s = 0.1
    test = screen([StiffnessAsymmetry()], _noisy_baseline(s, seed=5))[0]
    assert test.p_value < 1e-6
    # U = U0 + theta U0|left with theta = s / (1 - s) exactly; the raster is frozen at the baseline
    theta = s / (1 - s)
    assert abs(test.estimate[0] - theta) < 0.1 * theta, test.estimate


@pytest.mark.slow
def test_screening_of_a_fit_the_ridge_holds_back_is_not_pulled_by_the_ridge():
    """Noise-only data (seed 6) fitted with a ridge strong enough to hold the loads back (weight 100 1/Pa^2,
    three Gauss-Newton steps to the penalised minimum): the ridge's gradient balances the data's there, and
    a score that kept it would let a candidate correlated with the loads take over what the ridge holds
    back (with it asymmetry read 0.078 +- 0.027, 2.9 sd from its truth 0).  Measured: every one-step estimate
    within 0.6 sd of 0, and within 0.11 sd of the calibration's own estimate ``A^T Omega r / A^T Omega A``
    on the efficient columns (vfcli.diagnose.calibrate_run; they differ by the gap rows' majoriser)."""
    from vfcli.diagnose.calibrate_run import row_weights
    from vfcli.diagnose.candidates.blocks import screen_run_columns
    from vfcli.inverse.linearization import gauss_newton_model

    noisy = _noisy_baseline(0.0, seed=6)
    p = noisy.problem.with_weights(ridge_weight=100.0)
    x = noisy.x.copy()
    for _ in range(3):
        b = Baseline.at(p, x, noisy.f0_hz)
        model = gauss_newton_model(p, x, b.frames, b.displacements)
        x = x - model.hessian.solve(model.grad)
    base = Baseline.at(p, x, noisy.f0_hz)
    cands = [c for c in CANDIDATES if c.name != "contact"]          # the folds never reach the midplane here
    tests, columns, _ = screen_run_columns(cands, base)
    omega, r = row_weights(base), base.residual_vector()
    for c, t, col in zip(cands, tests, columns):
        a = base.measure_linear(col)
        calibrated = np.linalg.pinv(a.T @ (omega[:, None] * a)) @ (a.T @ (omega * r))
        assert np.all(np.abs(t.estimate) < 2.0 * t.std), (c.name, t.estimate, t.std)
        assert np.all(np.abs(t.estimate - calibrated) < 0.2 * t.std), (c.name, t.estimate, calibrated, t.std)


@pytest.mark.slow
def test_gauss_newton_screening_raises_no_alarm_on_noise_only_and_agrees_on_identifiability(fractions):
    tests = screen_run(CANDIDATES, _noisy_baseline(0.0, seed=6))
    assert all(t.p_value > 0.05 / len(CANDIDATES) for t in tests), [t.p_value for t in tests]
    # the normal-equation shares (objective weights) against the dense projection (uniform weights):
    # measured within 2 %; contact does not act here (the folds never reach the midplane: a zero column)
    for c, t in zip(CANDIDATES, tests):
        if c.name == "contact":
            assert t.p_value == 1.0 and not t.identifiability.own_information.any() and fractions["pressure"][c.name] == 0
            continue
        dense = fractions["pressure"][c.name]
        assert abs(t.identifiability.residual_fraction / dense - 1) < 0.05, (c.name, t.identifiability, dense)


def test_damping_column_is_the_retardation_derivative_of_its_extension_with_a_noisy_recorded_pressure():
    """As inertia's: with sensor noise on the recorded pressure, damping's column is the derivative of
    its own extension at tau = 0 (a first difference of the response would differentiate the noise)."""
    base = pressure_case(12, 4, pressure_noise_pa=4.0)
    load = base.problem.response.load_model
    red = ModalReduction(base.model, load.spatial_loads(base.model), n_modes=4, n_ritz=4)
    damping = KelvinVoigtDamping(base.model)
    damping._modal.reduction = lambda baseline, n_harmonics=6, map=None: red
    delta = 1e-4                                       # ms
    fd = (damping.extension(base, [delta]) - damping.extension(base, [-delta])) / (2 * delta)
    column = damping.displacement_jacobian(base)[..., 0]
    err = np.linalg.norm(column - fd) / np.linalg.norm(fd)
    print(f"damping column against the derivative of its extension: {err:.2e} relative")
    assert err < 1e-4, err


def test_damping_states_its_extended_model_as_the_steady_state_of_the_modal_reduction():
    """The damping's response (what its refit fits the loads with) changes the baseline's displacements by
    the viscoelastic steady state minus the elastic one, computed independently from the reduction's own
    ``steady_state`` of the load's harmonics; at tau = 0 it changes nothing."""
    base = pressure_case(time_degree=0)
    load = base.problem.response.load_model
    red = ModalReduction(base.model, load.spatial_loads(base.model), n_modes=4, n_ritz=4)
    damping = KelvinVoigtDamping(base.model)
    damping._modal.reduction = lambda baseline, n_harmonics=6, map=None: red  # the small reduction, not the complete one
    tau_ms = 0.4
    got = damping.response(base, [tau_ms]).displacements(base.x, base.problem.sim_times) - base.displacements
    inertia = Inertia(base.model)
    ref = (inertia.steady_state(base, 0.0, red, retardation_s=tau_ms * 1e-3) - inertia.steady_state(base, 0.0, red))
    err = np.linalg.norm(got - ref) / np.linalg.norm(ref)
    assert np.linalg.norm(ref) > 1e-3 * np.linalg.norm(base.displacements) and err < 1e-9, err
    assert np.abs(damping.extension(base, [0.0])).max() == 0.0
