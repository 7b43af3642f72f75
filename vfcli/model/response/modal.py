"""Periodic steady state of the folds per harmonic of f0, through a modal/Ritz reduction computed once.

The dynamic model of the folds under a load ``F(t)`` (n_dofs, Pa mm^2), units as in
:mod:`vfcli.model.fem` (mm, Pa, s)::

    rho M u'' + K (1 + i eta) (u + tau u') = F

with ``rho`` a density factor (1: the model's own density, ``ElasticModel.density_kg_m3``),
``tau`` a Kelvin-Voigt retardation time (s) and ``eta`` a structural loss factor.  For one
harmonic ``F e^{i w t}`` the steady state is ``u = H(w) F`` with

    H(w) = (c K - rho w^2 M)^-1,        c = (1 + i eta) (1 + i w tau).

Reduction (computed once, then every (rho, tau, eta, w) costs a few small products)
-----------------------------------------------------------------------------------
The basis is the union of the lowest ``n_modes`` eigenmodes of each fold (``K phi = w^2 M phi``,
scipy's ``eigsh`` in shift-invert mode through the model's factorisation,
:meth:`vfcli.model.fem.ElasticModel.modes`), the load-dependent Ritz vectors of the loads
(the block Krylov space ``K^-1 F, (K^-1 M) K^-1 F, ...``, ``n_ritz`` blocks; Wilson, Yuan and
Dickens 1982) and, for each frequency of ``shifts_hz`` (the harmonics of f0 the steady state is
wanted at), the shifted Ritz vectors ``(K - w_s^2 M)^-1 F, ((K - w_s^2 M)^-1 M) (K - w_s^2 M)^-1 F``
(``n_shift_blocks`` blocks; a rational Krylov space, one sparse LU of the shifted matrix per fold
and shift).  The Ritz vectors contain the static response ``K^-1 F`` exactly, so the reduced
model is exact at ``w = 0`` and matches the first ``2 n_ritz`` moments of ``H(w) F`` in ``w^2``;
the shifted blocks make it exact at ``rho w^2 = w_s^2`` (undamped) and match moments there; the
modes carry the resonances.  Without shifts the Krylov space at 0 converges to the low end of the
spectrum only: 2.4e-4 relative error at 170 Hz but 7 % at 340 Hz and 13 % at 850 Hz on the 2 mm
test mesh (folds' lowest modes near 50 Hz; tests/test_modal.py).  The basis V (n_dofs, r) is diagonalised once by the small dense
eigenproblem ``V^T K V z = mu V^T M V z``; with the M-orthonormal reduced modes ``psi_j``::

    H(w) F ~= sum_j psi_j (psi_j^T F) / (c mu_j - rho w^2)

(tests/test_modal.py compares it with a full sparse complex solve).  The quasi-static response is
``rho = 0, tau = 0, eta = 0``.
"""
from __future__ import annotations

import builtins
import logging

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: largest number of free DOFs per fold for :meth:`ModalReduction.complete` (dense eigenproblem,
#: about 8 n^2 bytes per matrix: 0.13 GB at 4000)
COMPLETE_MAX_DOFS = 4000


def ritz_vectors(model, loads: np.ndarray, n_blocks: int) -> np.ndarray:
    """Orthonormal basis (n_dofs, <= n_blocks * S) of ``span{K^-1 F, (K^-1 M) K^-1 F, ...}``.

    Parameters
    ----------
    model : :class:`vfcli.model.fem.ElasticModel`.
    loads : (n_dofs, S) load vectors, Pa mm^2.
    n_blocks : number of Krylov blocks (>= 1).
    """
    mass = model.mass
    block = model.solve(np.asarray(loads, dtype=float))
    out: list[np.ndarray] = []
    for _ in range(int(n_blocks)):
        for _two_passes in range(2):
            for b in out:
                block = block - b @ (b.T @ block)
        q, r = np.linalg.qr(block)
        d = np.abs(np.diag(r))
        keep = d > 1e-10 * max(float(d.max(initial=0.0)), 1e-300)
        if not keep.any():
            break
        q = q[:, keep]
        out.append(q)
        block = model.solve(mass @ q)
    return np.hstack(out)


def shifted_ritz_vectors(model, loads: np.ndarray, shift_hz: float, n_blocks: int = 2) -> np.ndarray:
    """(n_dofs, <= 2 n_blocks S) block Krylov vectors of the loads about the shift ``w_s^2``.

    ``span{A^-1 F_k, (A^-1 M) A^-1 F_k, ...}``, ``A = K - w_s^2 M`` factorised once per fold
    (sparse LU, symmetric ordering: A is indefinite above the lowest resonance), F_k the loads restricted
    to fold k, 0 at the clamped DOFs.  Not orthonormalised (the caller orthonormalises the whole basis).

    Parameters
    ----------
    model : :class:`vfcli.model.fem.ElasticModel`.
    loads : (n_dofs, S) load vectors, Pa mm^2.
    shift_hz : shift frequency f_s, Hz (w_s = 2 pi f_s).
    n_blocks : Krylov blocks (>= 1).
    """
    sigma = (2 * np.pi * float(shift_hz)) ** 2
    mass = model.mass
    solvers = _shifted_solvers(model, sigma)
    out = []
    for k, fold in enumerate(model.folds):
        idx = model.offsets[k] + fold.free
        m_ff = mass[idx][:, idx]
        block = solvers[k](np.ascontiguousarray(loads[idx], dtype=float))
        for _ in range(int(n_blocks)):
            block, _r = np.linalg.qr(block)
            full = np.zeros((model.n_dofs, block.shape[1]))
            full[idx] = block
            out.append(full)
            block = solvers[k](np.ascontiguousarray(m_ff @ block))
    return np.hstack(out)


def _shifted_solvers(model, sigma: float) -> list:
    """Per fold, a solve of ``A_k = K_k - sigma M_k`` on its free DOFs, rhs (n_free_k, m).

    Each A_k is factorised by sparse LU with a symmetric ordering: A is symmetric and indefinite above the
    lowest resonance, so a symmetric fill-reducing ordering with diagonal pivots preferred (pivoting off
    the diagonal only below a tenth of the column's largest entry) halves the factor's fill and takes 1.8x
    less time than COLAMD (bench/bench_diagnose_kernels.py).  When fold 0 is the mirror image of fold 1
    with the same Young's modulus (:attr:`vfcli.model.fem.ElasticModel.is_mirrored`, the stiffness
    solves' own reuse), A_0 is A_1 mirrored and fold 1's factors solve fold 0's systems too.
    """
    from scipy.sparse.linalg import splu

    mass = model.mass

    def factor(k: int):
        fold = model.folds[k]
        idx = model.offsets[k] + fold.free
        a = (fold.stiffness[fold.free][:, fold.free] - sigma * mass[idx][:, idx]).tocsc()
        return splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1, options={"SymmetricMode": True}).solve

    f0, f1 = model.folds
    solve1 = factor(1)
    if model.mirror is None or f0.youngs_pa != f1.youngs_pa:
        return [factor(0), solve1]

    def solve0(rhs: np.ndarray) -> np.ndarray:
        full = np.zeros((f0.n_dofs, rhs.shape[1]))
        full[f0.free] = rhs
        mapped = model.fold1_from_fold0(full)
        sol = np.zeros_like(full)
        sol[f1.free] = solve1(np.ascontiguousarray(mapped[f1.free]))
        return model.fold0_from_fold1(sol)[f0.free]

    return [solve0, solve1]


class ModalReduction:
    """Diagonalised modal/Ritz reduction of the folds for a set of load patterns (module docstring).

    Parameters
    ----------
    model : :class:`vfcli.model.fem.ElasticModel` (its mass matrix is at ``rho = 1``).
    loads : (n_dofs, S) spatial load patterns, Pa mm^2 per unit control value (a load model's
        ``spatial_loads(model)``).
    n_modes : lowest eigenmodes per fold put into the basis (0: Ritz vectors only).
    n_ritz : Krylov blocks of load-dependent Ritz vectors (>= 1).
    shifts_hz : frequencies (Hz) at which shifted Ritz vectors are added (e.g. the harmonics
        ``k f0`` the steady state is evaluated at); empty: none.
    n_shift_blocks : Krylov blocks per shift (>= 1).
    map : runs the shifts' factorisations and Krylov blocks (independent pieces; an in-process map such as
        :func:`vfcli.parallel.local_map`: SuperLU releases the GIL), default one after the other; the same basis
        whatever the map.

    Attributes
    ----------
    eigenvalues_ : (r,) mu_j = w_j^2 of the reduced modes, (rad/s)^2, ascending.
    vertex_modes_ : (r, N, 3) vertex displacement of each M-orthonormal reduced mode, mm.
    modal_loads_ : (r, S) ``psi_j^T F_s``.
    fold_frequencies_hz_ : (2 n_modes,) the eigsh frequencies of the two folds (for reporting).
    """

    def __init__(self, model, loads, n_modes: int = 20, n_ritz: int = 10, shifts_hz=(),
                 n_shift_blocks: int = 2, map=None) -> None:
        f = loads.toarray() if sp.issparse(loads) else np.asarray(loads, dtype=float)
        if f.ndim != 2 or f.shape[0] != model.n_dofs:
            raise ValueError(f"loads must be (n_dofs={model.n_dofs}, S), got {f.shape}")
        if n_ritz < 1 or n_modes < 0:
            raise ValueError(f"need n_ritz >= 1 and n_modes >= 0, got {n_ritz}, {n_modes}")
        # Krylov blocks per fold (the folds are separate bodies): twice the columns, a richer space
        per_fold = np.zeros((model.n_dofs, 2 * f.shape[1]))
        for k in (0, 1):
            rows = slice(model.offsets[k], model.offsets[k + 1])
            per_fold[rows, k * f.shape[1]:(k + 1) * f.shape[1]] = f[rows]
        shifts = np.atleast_1d(np.asarray(shifts_hz, dtype=float))
        for shift in shifts:
            if not shift > 0:
                raise ValueError(f"shifts_hz must be positive frequencies, got {shift!r}")
        parts = [ritz_vectors(model, per_fold, n_ritz),
                 *(map or builtins.map)(lambda shift: shifted_ritz_vectors(model, f, shift, n_shift_blocks), shifts)]
        freqs = []
        if n_modes:
            for fold in (0, 1):
                fr, shapes = model.modes(n_modes, fold=fold)
                freqs.append(fr)
                parts.append(shapes)
        self.fold_frequencies_hz_ = np.concatenate(freqs) if freqs else np.zeros(0)
        self._project(model, np.hstack(parts), f)

    @classmethod
    def complete(cls, model, loads, max_dofs: int = None) -> "ModalReduction":
        """The complete modal expansion: every eigenmode of each fold (a dense generalised eigenproblem
        ``K_ff phi = mu M_ff phi`` per fold), exact at any frequency, density, retardation time and loss
        to round-off.  Costs O(n^3) per fold and O(n^2) memory (n free DOFs of a fold): for coarse meshes
        only (at most ``max_dofs`` per fold, default :data:`COMPLETE_MAX_DOFS`; ValueError above)."""
        f = loads.toarray() if sp.issparse(loads) else np.asarray(loads, dtype=float)
        limit = COMPLETE_MAX_DOFS if max_dofs is None else int(max_dofs)
        sizes = [len(fold.free) for fold in model.folds]
        if f.ndim != 2 or f.shape[0] != model.n_dofs or max(sizes) > limit:
            raise ValueError(f"complete modal expansion of loads {f.shape} with {sizes} free DOFs per fold "
                             f"(at most {limit})")
        out = cls.__new__(cls)
        mass = model.mass
        mus, verts, modal_loads = [], [], []
        mirror = model.mirror                                          # fold 0 the mirror image of fold 1
        solved = {}
        for k in (1, 0):
            fold = model.folds[k]
            idx = model.offsets[k] + fold.free
            if k == 0 and mirror is not None:
                mu, phi1 = solved[1]
                f1 = model.folds[1]
                mu = mu * (fold.youngs_pa / f1.youngs_pa)             # K_0 = (E_0 / E_1) K_1 mirrored, M_0 = M_1
                full1 = np.zeros((f1.n_dofs, len(mu)))
                full1[f1.free] = phi1
                phi = model.fold0_from_fold1(full1)[fold.free]
                del full1
            else:
                mu, phi = sla.eigh(fold.stiffness[fold.free][:, fold.free].toarray(), mass[idx][:, idx].toarray())
                solved[k] = (mu, phi)
            row = np.full(fold.n_dofs, -1)
            row[fold.free] = np.arange(len(fold.free))
            vert = np.zeros((len(mu), model.mesh.n_nodes, 3))
            for c in range(3):
                r = row[fold.vertex_dofs[c]]                      # (N_k,) row of each vertex's DOF, -1: clamped
                vert[:, fold.nodes[r >= 0], c] = phi[r[r >= 0]].T
            mus.append(mu)
            verts.append(vert)
            modal_loads.append(phi.T @ f[idx])
        mu = np.concatenate(mus)
        order = np.argsort(mu, kind="stable")
        out.eigenvalues_ = mu[order]
        out.vertex_modes_ = np.concatenate(verts)[order]
        out.modal_loads_ = np.concatenate(modal_loads)[order]
        out.fold_frequencies_hz_ = np.sqrt(np.maximum(out.eigenvalues_, 0.0)) / (2 * np.pi)
        out.n_vertices = int(model.mesh.n_nodes)
        out.n_spatial = int(f.shape[1])
        return out

    def _project(self, model, parts: np.ndarray, f: np.ndarray) -> None:
        """Rayleigh-Ritz on the span of ``parts`` (n_dofs, m): the reduced modes, M-orthonormal."""
        basis, _ = np.linalg.qr(parts)
        free = np.zeros(model.n_dofs, bool)
        free[model.free_dofs] = True
        basis[~free] = 0.0
        k_r = basis.T @ (model.stiffness @ basis)
        m_r = basis.T @ (model.mass @ basis)
        k_r, m_r = 0.5 * (k_r + k_r.T), 0.5 * (m_r + m_r.T)
        # drop directions the clamping removed (zero mass) before the dense eigenproblem
        w, v = np.linalg.eigh(m_r)
        keep = w > 1e-10 * w.max()
        t = v[:, keep] / np.sqrt(w[keep])
        mu, z = sla.eigh(t.T @ k_r @ t)
        self._finish(model, basis @ (t @ z), mu, f)                  # (n_dofs, r) M-orthonormal

    def _finish(self, model, psi: np.ndarray, mu: np.ndarray, f: np.ndarray) -> None:
        """Store the M-orthonormal modes psi (n_dofs, r) with eigenvalues mu (r,) for the loads f."""
        self.eigenvalues_ = mu
        self.vertex_modes_ = model.vertex_displacements(psi)          # (r, N, 3)
        self.modal_loads_ = psi.T @ f                                 # (r, S)
        self.n_vertices = int(model.mesh.n_nodes)
        self.n_spatial = int(f.shape[1])
        log.debug("modal reduction: %d reduced modes, %.1f..%.1f Hz", len(mu),
                  np.sqrt(max(mu[0], 0)) / (2 * np.pi), np.sqrt(max(mu[-1], 0)) / (2 * np.pi))

    def modal_factors(self, omega: float, density: float = 1.0, retardation_s: float = 0.0,
                      loss: float = 0.0) -> np.ndarray:
        """(r,) complex ``1 / (c mu_j - rho w^2)`` at angular frequency ``omega`` (rad/s)."""
        c = (1.0 + 1j * loss) * (1.0 + 1j * omega * retardation_s)
        return 1.0 / (c * self.eigenvalues_ - density * omega ** 2)

    def transfer(self, omega: float, density: float = 1.0, retardation_s: float = 0.0,
                 loss: float = 0.0) -> np.ndarray:
        """(N, 3, S) complex vertex displacement (mm) per unit load pattern at ``omega`` (rad/s)."""
        d = self.modal_factors(omega, density, retardation_s, loss)
        return np.einsum("jnc,j,js->ncs", self.vertex_modes_, d, self.modal_loads_)

    def steady_state(self, amplitudes: np.ndarray, f0_hz: float, times: np.ndarray, density: float = 1.0,
                     retardation_s: float = 0.0, loss: float = 0.0) -> np.ndarray:
        """Periodic steady state of periodic pattern amplitudes.

        Parameters
        ----------
        amplitudes : (n_harmonics + 1, S) complex one-sided harmonic amplitudes of the load pattern
            amplitudes (:func:`harmonic_fit`): ``a_s(t) = Re sum_k amplitudes[k, s] e^{i k w0 t}``.
        f0_hz : fundamental frequency, Hz.
        times : (T,) s.

        Returns
        -------
        (T, N, 3) float64 displacements, mm.
        """
        a = np.asarray(amplitudes)
        times = np.asarray(times, dtype=float)
        w0 = 2 * np.pi * float(f0_hz)
        out = np.zeros((len(times), self.n_vertices, 3))
        for k in range(a.shape[0]):
            d = self.modal_factors(k * w0, density, retardation_s, loss)
            q = d * (self.modal_loads_ @ a[k])                       # (r,) modal amplitudes
            u_k = np.tensordot(q, self.vertex_modes_, axes=(0, 0))     # (N, 3) complex
            phase = np.exp(1j * k * w0 * times)                        # (T,)
            out += np.real(phase[:, None, None] * u_k[None])
        return out


def harmonic_fit(samples: np.ndarray, times: np.ndarray, f0_hz: float, n_harmonics: int) -> np.ndarray:
    """Least-squares harmonics of f0 of sampled signals.

    Parameters
    ----------
    samples : (T,) or (T, S) signal values at ``times``.
    times : (T,) s; they should span at least one period.
    f0_hz : fundamental, Hz.
    n_harmonics : highest harmonic (>= 0); needs ``T >= 2 n_harmonics + 1``.

    Returns
    -------
    (n_harmonics + 1, S) complex one-sided amplitudes A with ``y(t) ~= Re sum_k A_k e^{i k w0 t}``
    (A_0 real: the mean).
    """
    y = np.asarray(samples, dtype=float)
    y2 = y.reshape(len(y), -1)
    t = np.asarray(times, dtype=float)
    if len(t) < 2 * n_harmonics + 1:
        raise ValueError(f"{len(t)} samples cannot fit {n_harmonics} harmonics")
    w0 = 2 * np.pi * float(f0_hz)
    cols = [np.ones_like(t)]
    for k in range(1, n_harmonics + 1):
        cols += [np.cos(k * w0 * t), np.sin(k * w0 * t)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), y2, rcond=None)
    out = np.zeros((n_harmonics + 1, y2.shape[1]), complex)
    out[0] = coef[0]
    for k in range(1, n_harmonics + 1):
        out[k] = coef[2 * k - 1] - 1j * coef[2 * k]                  # a cos + b sin = Re((a - i b) e^{i w t})
    return out
