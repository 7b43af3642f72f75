"""The pressure load model: resultants, fold mirror symmetry, exact gradients, recovery of the inferior surface."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from vfcli.errors import ConfigError, InputDataError
from vfcli.model.loads.pressure import PressureLoad
from vfcli.model.mesh import TAG_INFERIOR, TAG_MEDIAL
from vfcli.inverse.problem import ObjectiveSettings, Problem, synthesize_measurement
from vfcli.inverse.optimizers.base import FitOptions, fit
from vfcli.model.response.quasi_static import QuasiStaticResponse

try:  # tests/ on sys.path (no tests/__init__.py)
    from _forward_case import CAMERA, F0_HZ, SETTINGS, elastic_model
except ModuleNotFoundError:  # tests/ is a package
    from tests._forward_case import CAMERA, F0_HZ, SETTINGS, elastic_model

N_FRAMES = 12
FPS = N_FRAMES * F0_HZ
TIMES = 0.002 + np.arange(N_FRAMES) / FPS
T_RANGE = (TIMES[0], TIMES[-1] + 1.0 / FPS)


def subglottal_pressure(fs_hz: float = 50000.0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth periodic subglottal pressure record (Pa) covering the test window."""
    t = np.arange(0.0, 0.012, 1.0 / fs_hz)
    ph = 2 * np.pi * F0_HZ * t
    return t, 1000.0 + 550.0 * np.sin(ph + 0.3) + 150.0 * np.sin(2 * ph - 1.0)


@pytest.fixture(scope="module")
def load():
    t, p = subglottal_pressure()
    return PressureLoad(t, p, T_RANGE, time_degree=3)


@pytest.fixture(scope="module")
def response(load):
    return QuasiStaticResponse(elastic_model(), load)


def dof_components(model) -> np.ndarray:
    return np.concatenate([f.dof_component for f in model.folds])


def dof_folds(model) -> np.ndarray:
    return np.concatenate([np.full(f.n_dofs, k) for k, f in enumerate(model.folds)])


def test_uniform_pressure_resultant_is_pressure_times_projected_area(load):
    """Vertical resultant of 1 Pa on the inferior surface = its area projected on the xy plane (mesh triangles)."""
    model = elastic_model()
    f = load.spatial_loads(model)[:, 0].toarray().ravel() * 800.0  # 800 Pa uniform on the inferior surface
    comp, fold = dof_components(model), dof_folds(model)
    mesh = model.mesh
    for k in (0, 1):
        tri = mesh.nodes[mesh.faces[(mesh.face_tag == TAG_INFERIOR) & (mesh.face_fold == k)]]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        projected = 0.5 * np.abs(cross[:, 2]).sum()         # mm^2, from the mesh itself
        fz = f[(comp == 2) & (fold == k)].sum()             # P2 shape functions sum to one
        assert fz == pytest.approx(800.0 * projected, rel=1e-10)
        # the whole resultant against the FEM quadrature: -p sum(w n) over the fold's inferior points
        q = model.quadrature
        sel = (q.tag == TAG_INFERIOR) & (q.fold == k)
        expected = -800.0 * (q.weights[sel, None] * q.normals[sel]).sum(axis=0)
        got = np.array([f[(comp == c) & (fold == k)].sum() for c in range(3)])
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-9 * np.abs(expected).max())
        assert abs(expected[1]) > 0.1 * abs(expected[2])   # the inferior slope also pushes medially


def test_medial_shapes_load_only_the_medial_surface_and_vanish_on_average(load):
    model = elastic_model()
    q = model.quadrature
    mask, values = load.shape_values(q)
    tags = q.tag[mask]
    assert set(np.unique(tags)) == {TAG_INFERIOR, TAG_MEDIAL}
    assert np.all(values[tags == TAG_MEDIAL, 0] == 0) and np.all(values[tags == TAG_INFERIOR, 1:] == 0)
    w = q.weights[mask][tags == TAG_MEDIAL]
    means = (w[:, None] * values[tags == TAG_MEDIAL, 1:]).sum(axis=0) / w.sum()
    assert means[0] == pytest.approx(1.0)                       # P0 P0
    # higher Legendre shapes average about zero (P2 in z within the few quadrature rows of this coarse mesh)
    assert np.all(np.abs(means[[1, 2, 3, 5]]) < 1e-3) and abs(means[4]) < 0.3
    assert load.n_spatial == 7 and load.n_time == 5 and len(load.parameter_names()) == 35


def test_loads_and_responses_are_mirror_images_between_the_folds(load, response):
    model = elastic_model()
    f = load.spatial_loads(model).toarray()
    comp, fold = dof_components(model), dof_folds(model)
    for c, sign in ((0, 1.0), (1, -1.0), (2, 1.0)):
        r0 = f[(comp == c) & (fold == 0)].sum(axis=0)
        r1 = f[(comp == c) & (fold == 1)].sum(axis=0)
        np.testing.assert_allclose(r0, sign * r1, rtol=1e-9, atol=1e-9 * np.abs(f).sum())
    mesh = model.mesh
    n0, n1 = mesh.fold_nodes(0), mesh.fold_nodes(1)
    dist, j = cKDTree(mesh.nodes[n1] * [1, -1, 1]).query(mesh.nodes[n0])
    assert dist.max() < 1e-9
    u = response.basis_  # (N, 3, n_spatial)
    np.testing.assert_allclose(u[n0], u[n1[j]] * np.array([1, -1, 1])[:, None], atol=1e-9 * np.abs(u).max())


def test_time_basis_is_the_normalised_pressure_then_bernstein(load):
    b = load.time_basis(TIMES)
    t, p = subglottal_pressure()
    np.testing.assert_allclose(b[:, 0] * load.p_ref, np.interp(TIMES, t, p), rtol=1e-12)
    np.testing.assert_allclose(b[:, 1:].sum(axis=1), 1.0, rtol=1e-12)
    with pytest.raises(ConfigError, match="covers.*optimize.first_frame"):  # the user's window: exit 2
        PressureLoad(t, p, (0.0, 0.02))
    with pytest.raises(InputDataError, match="zero"):  # the recording: exit 3
        PressureLoad(t, np.zeros_like(p), (TIMES[0], TIMES[-1]))
    with pytest.raises(ValueError, match="t1 < t2"):  # a broken caller: exit 1 with a traceback
        PressureLoad(t, p, (TIMES[-1], TIMES[0]))


def true_controls(load: PressureLoad, seed: int = 3) -> np.ndarray:
    """Inferior gain p_ref, medial gains of a few hundred Pa, corrections of tens of Pa."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-30.0, 30.0, (load.n_spatial, load.n_time))
    c[0, 0] = load.p_ref
    c[1:, 0] = rng.uniform(-300.0, 300.0, load.n_spatial - 1)
    c[1, 0] = 0.6 * load.p_ref
    return c.ravel()


@pytest.fixture(scope="module")
def problem(load, response):
    model = elastic_model()
    x_true = true_controls(load)
    meas = synthesize_measurement(model.mesh, CAMERA, response, TIMES, x_true, SETTINGS)
    return Problem(model.mesh, CAMERA, response, meas, SETTINGS), x_true


def test_exact_gradient_matches_central_differences_for_a_frozen_raster(problem):
    p, x_true = problem
    settings = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, ridge_weight=1e-6)
    p = Problem(p.mesh, p.camera, p.response, p.meas, settings)
    rng = np.random.default_rng(5)
    x0 = 0.7 * x_true + rng.normal(0, 30.0, x_true.size)
    frozen = p.freeze(x0)
    terms, grad = p.frozen_value_and_grad(x0, frozen)
    assert terms.motion > 1e-3 and terms.gap > 1e-4 and terms.ridge > 0
    h = 0.05
    d = np.eye(len(x0))
    fd = np.array([(p.frozen_value(x0 + h * e, frozen).total - p.frozen_value(x0 - h * e, frozen).total) / (2 * h)
                   for e in d])
    assert np.linalg.norm(fd - grad) / np.linalg.norm(grad) < 1e-5


@pytest.mark.slow
def test_fit_recovers_the_unobserved_inferior_surface(problem):
    """From zero loads, the superior-surface velocity and the gap fix the inferior surface within 5%."""
    p, x_true = problem
    settings = ObjectiveSettings(motion_weight=1e-4, gap_weight=1.0, ridge_weight=1e-9)
    p = Problem(p.mesh, p.camera, p.response, p.meas, settings)
    res = fit(p, method="lbfgs", max_iter=80, options=FitOptions(initial_step=100.0))
    mesh = p.mesh
    inf = np.unique(mesh.faces[mesh.face_tag == TAG_INFERIOR])
    true, got = p.displacements(x_true)[:, inf], p.displacements(res.x)[:, inf]
    err = np.sqrt(np.mean((got - true) ** 2)) / np.sqrt(np.mean(true ** 2))
    assert res.terms.total < 1e-2 * p.evaluate(np.zeros_like(x_true)).total
    assert err < 0.05, err


def test_the_recorded_pressure_is_band_limited_to_its_harmonics_without_delay_or_edge_transients():
    """Five harmonics of f0 (up to the 8th) plus white sensor noise of 50 Pa at 50 kHz, low-passed at 10 f0: the
    harmonics come back within 3 Pa everywhere, the record's ends included (measured 2.1-3.0 Pa; odd-reflected ends
    were 8-40 Pa off), with no delay; the noise left is the band's share, 50 sqrt(1200 / 25000) = 11 Pa
    (measured 10.2-10.6 Pa on seeds 0-2).  No f0, or a cutoff above 0.45 fs: the record as it is."""
    from vfcli.model.loads.pressure import band_limited

    fs = 50000.0
    for f0, duration in ((120.0, 0.1), (117.3, 0.0537)):
        t = 0.013 + np.arange(0.0, duration, 1.0 / fs)
        clean = 1000.0 + sum(a * np.sin(2 * np.pi * k * f0 * t + ph)
                             for k, a, ph in ((1, 500, 0.3), (2, 150, 1.0), (3, 60, 2.0), (5, 20, 0.5), (8, 10, 1.5)))
        assert np.abs(band_limited(t, clean, f0, 10) - clean).max() < 3.5
        for seed in range(3):
            noisy = clean + np.random.default_rng(seed).normal(0.0, 50.0, t.shape)
            assert 9.0 < np.std(band_limited(t, noisy, f0, 10) - clean) < 12.0
    np.testing.assert_array_equal(band_limited(t, noisy, float("nan"), 10), noisy)
    np.testing.assert_array_equal(band_limited(t, noisy, f0, 200), noisy)        # 23 kHz: above 0.45 fs
