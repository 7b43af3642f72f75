"""The Gauss-Newton model of E: exact for the motion term, a majoriser's curvature for the gap term."""
import numpy as np
import pytest

from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.terms.gap import gap_rows
from vfcli.inverse.problem import ObjectiveSettings, Problem

try:
    from _forward_case import CAMERA, forward_case
except ModuleNotFoundError:
    from tests._forward_case import CAMERA, forward_case


@pytest.fixture(scope="module")
def case():
    return forward_case(resolution=(2, 2, 4), sides=("inferior", "superior"), n_frames=8)


def _problem(case, motion, gap, ridge=0.0, components=(1.0, 1.0, 1.0), outside="paper", slide=False):
    return Problem(case.model.mesh, CAMERA, case.response, case.measurement,
                   ObjectiveSettings(motion_weight=motion, gap_weight=gap, ridge_weight=ridge,
                                     component_weights=components, outside=outside, motion_slide=slide))


def _x0(case):
    rng = np.random.default_rng(3)
    return 0.6 * case.x_true + rng.normal(0, 40.0, case.x_true.size)


@pytest.mark.parametrize("components,outside,slide", [
    ((1.0, 1.0, 1.0), "paper", False), ((1.0, 1.0, 0.0), "paper", False), ((0.0, 0.0, 1.0), "paper", False),
    ((0.3, 2.0, 0.7), "paper", False), ((1.0, 1.0, 1.0), "symmetric", False),
    ((1.0, 1.0, 1.0), "paper", True), ((0.3, 2.0, 0.7), "symmetric", True), ((0.0, 0.0, 1.0), "paper", True)])
def test_motion_and_ridge_hessian_equal_the_derivative_of_the_exact_gradient(case, components, outside, slide):
    """For a frozen raster the motion term is quadratic: H is its exact Hessian (central differences of g),
    with any weights of the velocity components (one instrument's data only), either charge of the
    pixels only one side sees, and with the surface sliding under the pixels (still linear in U)."""
    p = _problem(case, 1e-4, 0.0, ridge=1e-6, components=components, outside=outside, slide=slide)
    x0 = _x0(case)
    frames = p.freeze(x0)
    model = gauss_newton_model(p, x0, frames)
    rng = np.random.default_rng(0)
    for d in rng.normal(size=(6, p.n_params)):
        h = 1.0
        fd = (p.frozen_value_and_grad(x0 + h * d, frames)[1] - p.frozen_value_and_grad(x0 - h * d, frames)[1]) / (2 * h)
        np.testing.assert_allclose(model.hessian @ d, fd, rtol=1e-7, atol=1e-9 * np.abs(fd).max())
    # and the quadratic model predicts the frozen E exactly
    s = rng.normal(0, 20.0, p.n_params)
    pred = model.terms.total + model.grad @ s + 0.5 * s @ (model.hessian @ s)
    assert pred == pytest.approx(p.frozen_value(x0 + s, frames).total, rel=1e-9)


def test_gap_rows_are_the_derivative_of_the_silhouette_distances(case):
    p = _problem(case, 0.0, 1.0)
    x0 = _x0(case)
    u = p.displacements(x0)
    frames = p.freeze(x0, u)
    basis = p.response.basis_
    f = 3
    q_rows, dist = gap_rows(p, p.mesh.nodes + u[f], frames[f].sil, basis)
    assert len(dist) > 10
    rng = np.random.default_rng(1)
    dc = rng.normal(0, 1.0, basis.shape[2])           # a spatial control direction
    du = basis @ dc                                    # (N, 3) displacement per unit step
    h = 1e-3
    _, dp = gap_rows(p, p.mesh.nodes + u[f] + h * du, frames[f].sil, basis)
    _, dm = gap_rows(p, p.mesh.nodes + u[f] - h * du, frames[f].sil, basis)
    np.testing.assert_allclose(q_rows @ dc, (dp - dm) / (2 * h), rtol=1e-6, atol=1e-9)


def test_gap_hessian_is_the_curvature_of_a_majoriser(case):
    """Along any direction, the quadratic model bounds the frozen gap term from above (up to the
    linearisation of the crossing point), and matches its value and slope at x."""
    p = _problem(case, 0.0, 1.0)
    x0 = _x0(case)
    frames = p.freeze(x0)
    model = gauss_newton_model(p, x0, frames)
    h = model.hessian.dense()
    assert np.all(np.linalg.eigvalsh(h) > -1e-12 * np.abs(h).max())
    rng = np.random.default_rng(2)
    for d in rng.normal(size=(5, p.n_params)):
        d *= 30.0 / np.linalg.norm(d) * np.sqrt(p.n_params)   # steps of ~30 Pa per control value
        for t in (0.1, 0.3, 1.0):
            s = t * d
            quad = model.terms.total + model.grad @ s + 0.5 * s @ (model.hessian @ s)
            assert p.frozen_value(x0 + s, frames).total <= quad * (1 + 1e-3) + 1e-9


def test_hessian_is_symmetric_and_data_part_excludes_the_ridge(case):
    p = _problem(case, 1e-4, 1.0, ridge=1e-6)
    model = gauss_newton_model(p, _x0(case))
    h = model.hessian.dense()
    np.testing.assert_allclose(h, h.T, rtol=0, atol=1e-12 * np.abs(h).max())
    omega = case.field.penalty_operator().toarray()
    np.testing.assert_allclose(h - model.data_hessian.dense(), omega * 2e-6 / p.n_params, atol=1e-18)
    assert len(model.hessian.blocks) == 2          # independent folds: one block per fold


def test_tied_folds_give_one_block_and_the_same_hessian_as_dense_assembly():
    tied = forward_case(resolution=(2, 2, 3), sides=("inferior",), n_frames=6, tie_folds=True)
    model = gauss_newton_model(tied.problem, tied.x_true * 0.5)
    assert len(model.hessian.blocks) == 1
    rng = np.random.default_rng(4)
    d = rng.normal(size=tied.problem.n_params)
    np.testing.assert_allclose(model.hessian @ d, model.hessian.dense() @ d, rtol=1e-12)
    assert model.n_motion > 0



def test_motion_blocks_of_several_terms_are_each_pairs_weighted_gram_product():
    """Every (j, k) block of :func:`motion_blocks` against the dense ``sum_c w_c R_j,c^T M^T M R_k,c`` over
    the moved vertices only, on random interpolation rows and three terms of different values."""
    import scipy.sparse as sp

    from vfcli.inverse.terms.motion import motion_blocks, seen_vertex_gram

    rng = np.random.default_rng(5)
    n_vert, n_pix, n_s = 40, 60, 4
    m = sp.random(n_pix, n_vert, density=0.08, random_state=7, format="csr")
    bases = [rng.normal(size=(n_vert, 3, n_s)) for _ in range(3)]
    moved = rng.random(n_vert) < 0.7
    weights = (0.3, 2.0, 0.7)
    seen, gram = seen_vertex_gram(m)
    got = motion_blocks(seen, gram, bases, moved, weights)
    dense = m.toarray() * moved[None, :]                       # rows of the moved vertices only
    assert got.shape == (3, 3, n_s, n_s)
    for j in range(3):
        for k in range(3):
            want = sum(w * (dense @ bases[j][:, c, :]).T @ (dense @ bases[k][:, c, :]) for c, w in enumerate(weights))
            np.testing.assert_allclose(got[j, k], want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert np.allclose(got[0, 1], got[1, 0].T) and not np.allclose(got[0, 1], got[0, 2])


def test_slide_blocks_are_each_pairs_weighted_gram_product_of_the_residuals_two_parts():
    """Every block of :func:`motion_slide_blocks` against the dense products of the 2J residual parts
    ``X_j = M R_j / dt`` and ``Y_j = -K (M R_j)[:, :2]`` over the moved vertices, on random raster rows (several
    pixels per triangle, K per triangle), random slide gradients and three terms."""
    import scipy.sparse as sp

    from vfcli.inverse.terms.motion import Slide, motion_slide_blocks

    rng = np.random.default_rng(6)
    n_vert, n_tri, n_pix, n_s, dt = 40, 25, 90, 4, 1e-4
    tris = np.stack([rng.choice(n_vert, 3, replace=False) for _ in range(n_tri)])
    triangle = rng.integers(0, n_tri, n_pix)
    bary = rng.dirichlet(np.ones(3), n_pix)
    m = sp.csr_matrix((bary.ravel(), tris[triangle].ravel(), np.arange(0, 3 * n_pix + 1, 3)), shape=(n_pix, n_vert))
    slide = Slide(rng.normal(size=(n_tri, 3, 2)) * 500.0, triangle, np.zeros((n_pix, 2)))
    bases = [rng.normal(size=(n_vert, 3, n_s)) for _ in range(3)]
    moved = rng.random(n_vert) < 0.7
    weights = (0.3, 2.0, 0.7)
    got = motion_slide_blocks(m, slide, bases, moved, weights, dt)
    dense = m.toarray() * moved[None, :]
    k_pix = slide.gradient[triangle]
    mr = [np.stack([dense @ b[:, c, :] for c in range(3)], axis=1) for b in bases]     # (n_pix, 3, S)
    parts = [x / dt for x in mr] + [-np.einsum("pcd,pds->pcs", k_pix, x[:, :2]) for x in mr]
    assert got.shape == (6, 6, n_s, n_s)
    for a in range(6):
        for b in range(6):
            want = sum(w * parts[a][:, c].T @ parts[b][:, c] for c, w in enumerate(weights))
            np.testing.assert_allclose(got[a, b], want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
