"""Force fields: layout, partition of unity on the surface, total load, C0 split, tied folds."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR

try:  # tests/ on sys.path (no tests/__init__.py)
    from _forward_case import elastic_model
except ModuleNotFoundError:  # tests/ is a package
    from tests._forward_case import elastic_model


@pytest.fixture(scope="module")
def model():
    return elastic_model()


@pytest.mark.parametrize("name, n_spatial, n_params", [
    ("3x3x10-one-sided", 2 * 39, 2 * 39 * 10),
    ("3x3x10-two-sided", 4 * 39, 4 * 39 * 10),
    ("5x5x15-two-sided", 4 * 115, 4 * 115 * 15),
])
def test_paper_setups_have_the_expected_number_of_control_values(name, n_spatial, n_params):
    ff = ForceField(ForceFieldSpec.from_name(name), (0.0, 1.0))
    assert (ff.n_spatial, ff.n_params) == (n_spatial, n_params)
    assert len(ff.parameter_names()) == n_params and len(set(ff.parameter_names())) == n_params
    tied = ForceField(ForceFieldSpec.from_name(name, tie_folds=True), (0.0, 1.0))
    assert tied.n_spatial == n_spatial // 2


@pytest.mark.parametrize("bad", ["3x3-two-sided", "3x3x10", "0x3x10-one-sided"])
def test_bad_setup_names_are_value_errors(bad):
    with pytest.raises(ValueError):
        ForceField(ForceFieldSpec.from_name(bad), (0.0, 1.0))


def test_unit_controls_give_unit_traction_on_their_side_only(model):
    ff = ForceField(ForceFieldSpec((3, 2, 4), ("inferior", "superior")), (0.0, 1.0))
    q = model.quadrature
    s = ff.spatial_basis(q)
    for name, fold, side, comp, sl in ff.blocks:
        c = np.zeros(ff.n_spatial)
        c[sl] = 1.0
        t = (s @ c).reshape(-1, 3)
        on = (q.fold == int(fold[-1])) & (q.side == {"inferior": SIDE_INFERIOR, "superior": SIDE_SUPERIOR}[side])
        k = "xyz".index(comp)
        np.testing.assert_allclose(t[on, k], 1.0, atol=1e-12)   # partition of unity of the pieces
        assert not np.any(t[~on]) and not np.any(np.delete(t[on], k, axis=1))


def test_total_load_equals_traction_integral(model):
    """Sum of the x-DOF loads of a unit x-traction = area of the side (P2 partition of unity)."""
    ff = ForceField(ForceFieldSpec((2, 2, 3), ("inferior",)), (0.0, 1.0))
    q = model.quadrature
    loads = ff.spatial_loads(model)
    _, _, _, _, sl = next(b for b in ff.blocks if b[0] == "fold1/inferior/x")
    comp = np.zeros(model.n_dofs, bool)
    for f, o in zip(model.folds, model.offsets):
        comp[o:o + f.n_dofs] = f.dof_component == 0
    total = loads[:, sl].sum(axis=1).A1[comp].sum()
    area = q.weights[(q.fold == 1) & (q.side == SIDE_INFERIOR)].sum()
    np.testing.assert_allclose(total, area, rtol=1e-10)


def test_split_fields_are_continuous_across_the_split_line():
    ff = ForceField(ForceFieldSpec((4, 3, 2)), (0.0, 1.0))
    rng = np.random.default_rng(3)
    v = rng.uniform(size=20)
    for comp, axis in (("x", 0), ("y", 1)):
        uv_l = np.column_stack([rng.uniform(size=20), v])
        uv_r = uv_l.copy()
        uv_l[:, axis], uv_r[:, axis] = 0.5 - 1e-10, 0.5 + 1e-10
        c = rng.normal(size=ff.scalar_basis(comp, uv_l).shape[1])
        np.testing.assert_allclose(ff.scalar_basis(comp, uv_l) @ c, ff.scalar_basis(comp, uv_r) @ c, atol=1e-8)


def test_tied_folds_mirror_the_traction(model):
    ff = ForceField(ForceFieldSpec((3, 3, 2), ("inferior", "superior"), tie_folds=True), (0.0, 1.0))
    q = model.quadrature
    c = np.random.default_rng(4).normal(size=ff.n_spatial)
    t = (ff.spatial_basis(q) @ c).reshape(-1, 3)
    i0 = np.flatnonzero((q.fold == 0) & (q.side > 0))
    i1 = np.flatnonzero((q.fold == 1) & (q.side > 0))
    dist, j = cKDTree(q.positions[i1] * [1, -1, 1]).query(q.positions[i0])
    assert dist.max() < 1e-9
    np.testing.assert_allclose(t[i0], t[i1[j]] * [1, -1, 1], atol=1e-12)
    assert np.abs(t[i0]).max() > 0.1


def test_time_basis_spans_the_time_range():
    ff = ForceField(ForceFieldSpec((2, 2, 5)), (0.01, 0.03))
    b = ff.time_basis(np.array([0.01, 0.02, 0.03]))
    np.testing.assert_allclose(b[0], np.eye(5)[0])
    np.testing.assert_allclose(b[2], np.eye(5)[4])
    np.testing.assert_allclose(b.sum(axis=1), 1.0)
    with pytest.raises(ValueError):
        ForceField(ForceFieldSpec((2, 2, 5)), (0.03, 0.01))


def test_penalty_operator_is_size_plus_squared_neighbour_differences():
    from vfcli.model.loads.force_field import ForceField, ForceFieldSpec

    field = ForceField(ForceFieldSpec((2, 3, 4), ("inferior",)), (0.0, 1.0))
    omega = field.penalty_operator().toarray()
    assert omega.shape == (field.n_params, field.n_params)
    np.testing.assert_allclose(omega, omega.T)
    assert np.linalg.eigvalsh(omega).min() >= 1.0 - 1e-12     # at least the size
    c = np.ones((field.n_spatial, field.n_time))              # constant fields: no differences
    np.testing.assert_allclose(c.ravel() @ omega @ c.ravel(), c.size)
    c2 = np.zeros_like(c)
    c2[0, 1] = 1.0                                            # one interior time value: two time differences
    _, _, _, comp, sl = field.blocks[0]
    a, b = field.component_shapes[comp]
    n_space_neighbours = 1 + (1 if b > 1 else 0)              # the (0, 0) control value of a grid >= 2 x 2
    assert c2.ravel() @ omega @ c2.ravel() == 1 + 2 + n_space_neighbours
