"""The modal/Ritz reduction of vfcli.model.response.modal against full sparse solves."""
from __future__ import annotations

import numpy as np
import pytest

from _forward_case import direct_transfer, elastic_model
from vfcli.model.mesh import TAG_INFERIOR, TAG_MEDIAL
from vfcli.model.response.modal import ModalReduction, harmonic_fit

F0_HZ = 170.0


def _loads(model) -> np.ndarray:
    """(n_dofs, 2) uniform pressure on the inferior and on the medial surfaces, 1 Pa."""
    cols = []
    for tag in (TAG_INFERIOR, TAG_MEDIAL):
        mask = model.quadrature_mask(tags=[tag])
        cols.append(model.pressure_operator(mask) @ np.ones(int(mask.sum())))
    return np.column_stack(cols)


@pytest.mark.slow
def test_reduction_is_exact_at_zero_frequency_and_close_at_f0_with_damping():
    model = elastic_model()
    loads = _loads(model)
    red = ModalReduction(model, loads)                              # 20 modes per fold, 10 Ritz blocks
    static = np.moveaxis(model.vertex_displacements(model.solve(loads)), 0, -1)
    assert np.linalg.norm(red.transfer(0.0, 1.0) - static) < 1e-10 * np.linalg.norm(static)
    w, tau, loss = 2 * np.pi * F0_HZ, 0.2 / (2 * np.pi * F0_HZ), 0.02
    right = model.folds[1].nodes          # the loads and folds are mirror images: the right fold suffices
    full = direct_transfer(model, loads, w, 1.0, tau, loss, folds=(1,))[right]
    err = np.linalg.norm(red.transfer(w, 1.0, tau, loss)[right] - full) / np.linalg.norm(full)
    assert 1e-4 < err < 5e-4, err        # measured 2.4e-4; with 6 modes per fold 4.6e-2: the modes carry it
    # the reduction's lowest frequencies are the folds' eigsh modes (a Rayleigh-Ritz space containing them)
    lowest = np.sqrt(red.eigenvalues_[:4]) / (2 * np.pi)
    assert np.allclose(lowest, np.sort(red.fold_frequencies_hz_)[:4], rtol=1e-8)


def test_shifted_ritz_vectors_of_mirror_folds_reuse_one_factorisation_and_match_two():
    """Fold 0 solved through fold 1's factors (its mirror image) gives the vectors of a factorisation per
    fold (the same mesh built with ``reuse_mirror=False``), below and above the lowest resonance; folds of
    different stiffness are not mirrored for the shifted matrix and still match."""
    from vfcli.model.fem import ElasticModel
    from vfcli.model.response.modal import shifted_ritz_vectors

    mirrored = elastic_model(2.5)
    both = ElasticModel(mirrored.mesh, reuse_mirror=False)
    assert mirrored.mirror is not None and both.mirror is None
    loads = np.random.default_rng(5).normal(size=(mirrored.n_dofs, 3))
    loads[mirrored.fixed_dofs] = 0.0
    for shift_hz in (120.0, 600.0):
        a, b = shifted_ritz_vectors(both, loads, shift_hz), shifted_ritz_vectors(mirrored, loads, shift_hz)
        assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()        # measured 5e-12 (2 mm mesh, 250 Hz)
    soft = ElasticModel(mirrored.mesh, youngs_pa=(3900.0, 4400.0))
    soft_both = ElasticModel(mirrored.mesh, youngs_pa=(3900.0, 4400.0), reuse_mirror=False)
    a, b = shifted_ritz_vectors(soft_both, loads, 300.0), shifted_ritz_vectors(soft, loads, 300.0)
    assert soft.mirror is not None and np.abs(a - b).max() <= 1e-9 * np.abs(a).max()


def test_the_complete_expansion_of_mirror_folds_of_different_stiffness_is_each_folds_own():
    """Folds that are mirror images with different E (``ElasticModel(youngs_pa=(E0, E1))``): the complete
    expansion reuses fold 1's mode shapes for fold 0 with its eigenvalues scaled by E0 / E1, and equals the
    expansion of both folds solved apart (before session 34 it reused fold 1's eigenvalues unscaled, 12.8 % =
    E1 / E0 - 1 off, and on a 3 mm mesh its transfer at 150 Hz was off by 4 times its own size)."""
    from vfcli.model.fem import ElasticModel
    from vfcli.model.mesh import build_mesh

    mesh = build_mesh(target_edge_mm=4.5)                                   # coarse: a dense eigenproblem per fold
    mirrored = ElasticModel(mesh, youngs_pa=(3900.0, 4400.0))
    apart = ElasticModel(mesh, youngs_pa=(3900.0, 4400.0), reuse_mirror=False)
    assert mirrored.mirror is not None and apart.mirror is None
    loads = np.random.default_rng(0).normal(size=(mirrored.n_dofs, 2))
    loads[mirrored.fixed_dofs] = 0.0
    a, b = ModalReduction.complete(mirrored, loads), ModalReduction.complete(apart, loads)
    np.testing.assert_allclose(a.eigenvalues_, b.eigenvalues_, rtol=1e-9)
    w = 2 * np.pi * 150.0
    ta, tb = a.transfer(w, 1.0), b.transfer(w, 1.0)
    assert np.abs(ta - tb).max() <= 1e-6 * np.abs(tb).max()


def test_harmonic_fit_recovers_harmonics_and_steady_state_is_quasi_static_without_mass():
    t = 0.001 + np.arange(24) / (24 * F0_HZ)
    w = 2 * np.pi * F0_HZ
    y = np.column_stack([3.0 + 2.0 * np.cos(w * t - 0.4), np.sin(2 * w * t)])
    spec = harmonic_fit(y, t, F0_HZ, 3)
    assert np.allclose(spec[:, 0], [3.0, 2.0 * np.exp(-0.4j), 0.0, 0.0], atol=1e-12)
    assert np.allclose(spec[:, 1], [0.0, 0.0, -1j, 0.0], atol=1e-12)
    model = elastic_model()
    loads = _loads(model)
    red = ModalReduction(model, loads, n_modes=2, n_ritz=2)
    static = model.vertex_displacements(model.solve(loads))        # (2, N, 3)
    u = red.steady_state(spec, F0_HZ, t, density=0.0)
    assert np.allclose(u, np.einsum("ts,snc->tnc", y, static), atol=1e-9 * np.abs(static).max())


@pytest.mark.slow
def test_the_complete_expansion_is_exact_and_shifts_make_the_ritz_reduction_exact_at_the_harmonics():
    """On the 3 mm mesh (2193 free DOFs per fold), against the full sparse solve at harmonics of f0:
    the complete modal expansion at any density and damping, the Ritz reduction with shifted blocks
    at the harmonics for the tissue's own density without damping; the plain Ritz reduction (20 modes
    per fold, 10 blocks) is far off above the fundamental (the folds' spectrum is dense above 50 Hz)."""
    model = elastic_model(3.0)
    loads = _loads(model)
    complete = ModalReduction.complete(model, loads)
    plain = ModalReduction(model, loads)
    shifted = ModalReduction(model, loads, shifts_hz=F0_HZ * np.arange(1, 7))
    tau = 0.2 / (2 * np.pi * F0_HZ)
    rel = lambda a, b: np.linalg.norm(a - b) / np.linalg.norm(b)  # noqa: E731
    for k, rho, ta, loss in ((2, 2.0, 0.0, 0.02), (4, 1.0, tau, 0.02), (6, 0.5, 0.0, 0.0), (3, 1.0, 0.0, 0.0)):
        w = 2 * np.pi * F0_HZ * k
        full = direct_transfer(model, loads, w, rho, ta, loss)
        err = rel(complete.transfer(w, rho, ta, loss), full)
        assert err < 1e-9, (k, rho, err)                                # measured 1e-12 .. 9e-12
    errs = []
    for k in range(1, 7):
        w = 2 * np.pi * F0_HZ * k
        full = direct_transfer(model, loads, w, 1.0, 0.0, 0.0)
        errs.append((rel(plain.transfer(w, 1.0), full), rel(shifted.transfer(w, 1.0), full)))
    errs = np.array(errs)
    print(errs)
    assert np.all(errs[:, 1] < 1e-8), errs                              # exact at its shifts
    assert np.max(errs[1:, 0]) > 1e-2, errs                             # plain: off above the fundamental


@pytest.mark.parametrize("side_by_side", ["ForkMap", "ThreadMap"])
def test_the_shifts_factorised_side_by_side_give_the_same_reduction_bit_for_bit(side_by_side):
    """The shifted Ritz blocks are independent pieces (a factorisation of ``K - w^2 M`` each): built through a
    map over two forked children (vfcli.fork_map.ForkMap, as `vfcli diagnose --jobs 2` builds them on Linux) or two
    threads (vfcli.parallel.ThreadMap, elsewhere) the reduction is the serial one to the bit, and the map received
    every shift."""
    from vfcli.fork_map import ForkMap
    from vfcli.parallel import ThreadMap

    model = elastic_model(3.0)
    loads = _loads(model)
    shifts = F0_HZ * np.arange(1, 4)
    seen = []

    def recorded(func, items):
        items = list(items)
        seen.extend(items)
        return {"ForkMap": ForkMap, "ThreadMap": ThreadMap}[side_by_side](2)(func, items)

    serial = ModalReduction(model, loads, n_modes=4, n_ritz=3, shifts_hz=shifts)
    threaded = ModalReduction(model, loads, n_modes=4, n_ritz=3, shifts_hz=shifts, map=recorded)
    assert np.array_equal(np.asarray(seen), shifts)
    for name in ("eigenvalues_", "vertex_modes_", "modal_loads_"):
        assert np.array_equal(getattr(threaded, name), getattr(serial, name)), name
