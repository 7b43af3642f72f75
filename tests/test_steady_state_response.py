"""The steady-state response (vfcli/model/response/steady_state.py): a Response whose displacements are the
quasi-static ones plus the periodic steady-state change of the mass.

- without mass or damping it is the quasi-static response;
- it is linear in the controls: its linearisation applied to x gives its displacements, and its adjoint is
  the transpose of that linearisation (a dot-product test against independent random vectors);
- its change is the modal steady state of the harmonic fit of the loads (ModalReduction.steady_state, a
  different code path: per-harmonic amplitudes of the load instead of per-term transfers).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from _candidates_case import pressure_case
from vfcli.model.response.modal import ModalReduction, harmonic_fit
from vfcli.model.response.steady_state import SteadyStateResponse, change_transfers


@lru_cache(maxsize=1)
def _case():
    base = pressure_case(12, 4)
    load = base.problem.response.load_model
    red = ModalReduction(base.model, load.spatial_loads(base.model), n_modes=8, n_ritz=6)
    return base, red


def _response(density, loss=0.02, retardation_s=0.0):
    base, red = _case()
    p = base.problem
    return SteadyStateResponse(p.response, red, base.f0_hz, p.sim_times, density=density, loss=loss,
                               retardation_s=retardation_s)


def test_without_mass_or_damping_it_is_the_quasi_static_response():
    base, _ = _case()
    p = base.problem
    r = _response(0.0)
    np.testing.assert_allclose(r.displacements(base.x, p.sim_times), p.response.displacements(base.x, p.sim_times),
                               rtol=0, atol=1e-12 * np.abs(base.displacements).max())


def test_linearization_and_adjoint_are_exact_and_transposed():
    base, _ = _case()
    t = base.problem.sim_times
    r = _response(0.7, retardation_s=2e-4)
    rng = np.random.default_rng(3)
    x, dx = rng.normal(size=r.n_params), rng.normal(size=r.n_params)
    u = r.displacements(x, t)
    lin = r.linearize(x, t)
    assert len(lin.terms) == 2 + 2 * 6                 # quasi-static, k = 0, and (Re, Im) per harmonic 1..6
    np.testing.assert_allclose(lin.apply(x), u, rtol=0, atol=1e-10 * np.abs(u).max())
    g = rng.normal(size=u.shape)
    lhs = float(np.sum(g * lin.apply(dx)))
    rhs = float(r.adjoint(g, t, x) @ dx)
    assert abs(lhs - rhs) < 1e-10 * max(abs(lhs), 1.0), (lhs, rhs)
    # and the change is not small: at 0.7 times the tissue's density f0 = 170 Hz is above several modes
    u0 = r.base.displacements(x, t)
    assert np.linalg.norm(u - u0) > 0.1 * np.linalg.norm(u0 - u0.mean(0))


def test_change_is_the_modal_steady_state_of_the_loads_harmonics():
    base, red = _case()
    p = base.problem
    t = p.sim_times
    load = p.response.load_model
    rho, loss = 1.3, 0.02
    amp = harmonic_fit(load.time_basis(t) @ load.control_matrix(base.x).T, t, base.f0_hz, 6)
    want = (red.steady_state(amp, base.f0_hz, t, rho, 0.0, loss) - red.steady_state(amp, base.f0_hz, t, 0.0, 0.0, loss))
    got = _response(rho, loss).change(base.x, t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


def test_the_transfers_of_every_harmonic_in_one_product_are_the_reductions_own_per_frequency():
    """change_transfers (one product over every frequency, real and imaginary parts side by side) against the
    reduction's transfer (an einsum per frequency), with mass, damping and loss on, at f0's harmonics and 0."""
    base, red = _case()
    omegas = 2 * np.pi * base.f0_hz * np.arange(7)
    got = change_transfers(red, omegas, 1.7, 3e-4, 0.05)
    assert got.shape == (7, red.vertex_modes_.shape[1], 3, red.modal_loads_.shape[1])
    for k, w in enumerate(omegas):
        want = red.transfer(w, 1.7, 3e-4, 0.05) - red.transfer(w, 0.0, 0.0, 0.05)
        np.testing.assert_allclose(got[k], want, rtol=0, atol=1e-12 * np.abs(want).max() + 1e-300)
    assert np.abs(got[0]).max() == 0.0 and np.abs(got[3]).max() > 0.1 * np.abs(red.transfer(omegas[3], 0.0)).max()
