"""Assembly of linear elasticity with scikit-fem: stiffness, mass, facet load operators.

Pure functions over scikit-fem meshes and bases (units: see :mod:`vfcli.model.fem`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


#: mass-matrix scale: rho [kg/m^3] -> internal units (see the vfcli.model.fem docstring)
MASS_SCALE = 1e-6
#: body-force scale: N/m^3 -> Pa/mm
BODY_FORCE_SCALE = 1e-3


def lame_parameters(youngs_pa: float, poisson: float) -> tuple[float, float]:
    """Lame constants (lambda, mu) in Pa from E (Pa) and nu."""
    lam = youngs_pa * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = youngs_pa / (2 * (1 + poisson))
    return lam, mu


def _gradient_products(basis) -> dict[tuple[int, int], sp.csr_matrix]:
    """D[p, q][a, b] = int d_p phi_a d_q phi_b dV for a scalar basis (9 matrices)."""
    from skfem import BilinearForm, asm

    out: dict[tuple[int, int], sp.csr_matrix] = {}
    for p in range(3):
        for q in range(p, 3):
            @BilinearForm
            def form(u, v, w, p=p, q=q):
                return v.grad[p] * u.grad[q]

            out[p, q] = asm(form, basis).tocsr()
    for p in range(3):
        for q in range(p):
            out[p, q] = out[q, p].T.tocsr()
    return out


def interleave(blocked: sp.spmatrix, n_scalar: int) -> sp.csr_matrix:
    """Reorder a component-blocked (3 n, 3 n) matrix (index c n + a) to skfem's
    interleaved vector numbering (index 3 a + c)."""
    perm = (3 * np.arange(n_scalar)[None, :] + np.arange(3)[:, None]).ravel()
    p = sp.csr_matrix((np.ones(3 * n_scalar), (perm, np.arange(3 * n_scalar))), shape=(3 * n_scalar,) * 2)
    return (p @ blocked @ p.T).tocsr()


def stiffness_matrix(mesh, element, lam: float, mu: float, volumetric: str = "full") -> sp.csr_matrix:
    """Assemble the linear-elastic stiffness matrix with scikit-fem.

    The 3 x 3 blocks ``A_ij = mu delta_ij sum_p D_pp + mu D_ji + lam D_ij`` are
    built from the six scalar matrices ``D_pq = int d_p phi_a d_q phi_b``
    (about 8x faster than the vector form ``ddot(C(sym_grad u), sym_grad v)``,
    identical to round-off; tests/test_fem.py).

    Parameters
    ----------
    mesh : skfem MeshTet (mm).
    element : scalar skfem element (``ElementTetP2()`` or ``ElementTetP1()``);
        the result uses the numbering of ``ElementVector(element)``.
    lam, mu : Lame constants, Pa.
    volumetric : ``"full"`` (exact quadrature) or ``"reduced"`` (one point per
        cell for the lambda term: the condensed P2-P0 mixed element).

    Returns
    -------
    (3 n, 3 n) csr_matrix, Pa mm.
    """
    from skfem import Basis

    if volumetric not in ("full", "reduced"):
        raise ValueError(f"volumetric must be 'full' or 'reduced', got {volumetric!r}")
    order = max(2 * (element.maxdeg - 1), 1)
    basis = Basis(mesh, element, intorder=order)
    d = _gradient_products(basis)
    dv = d if volumetric == "full" else _gradient_products(Basis(mesh, element, intorder=1))
    lap = d[0, 0] + d[1, 1] + d[2, 2]
    blocks = [[(mu * lap if i == j else 0 * lap) + mu * d[j, i] + lam * dv[i, j] for j in range(3)]
              for i in range(3)]
    return interleave(sp.bmat(blocks, format="csr"), basis.N)


def mass_matrix(mesh, element, density_kg_m3: float) -> sp.csr_matrix:
    """Consistent mass matrix (internal units, see the vfcli.model.fem docstring).

    Parameters
    ----------
    element : scalar skfem element; the result uses ``ElementVector(element)``'s numbering.

    Returns
    -------
    (3 n, 3 n) csr_matrix.
    """
    from skfem import Basis, BilinearForm, asm

    @BilinearForm
    def mass(u, v, w):
        return u * v

    basis = Basis(mesh, element, intorder=2 * element.maxdeg)
    m = asm(mass, basis).tocsr() * (density_kg_m3 * MASS_SCALE)
    return interleave(sp.block_diag([m, m, m], format="csr"), basis.N)


def facet_load_operator(facet_basis) -> sp.csr_matrix:
    """Operator from traction values at facet quadrature points to the load vector.

    Parameters
    ----------
    facet_basis : skfem FacetBasis of a vector element.

    Returns
    -------
    (n_dofs, 3 Q) csr_matrix, mm^2: column ``3 q + c`` is component ``c`` of the
    traction at quadrature point ``q`` (facet-major: ``q = f * n_qp + i``), so
    ``F = L @ t.ravel()`` with ``t`` (Q, 3) in Pa gives F in Pa mm^2.
    """
    fb = facet_basis
    n_fac, n_qp = fb.dx.shape
    q = np.arange(n_fac * n_qp).reshape(n_fac, n_qp)
    rows, cols, vals = [], [], []
    for i in range(fb.Nbfun):  # local basis functions: each vectorised over all facets
        phi = np.asarray(fb.basis[i][0])  # (3, n_fac, n_qp)
        for c in range(3):
            val = phi[c] * fb.dx
            nz = val != 0.0
            if not nz.any():
                continue
            rows.append(np.broadcast_to(fb.element_dofs[i][:, None], (n_fac, n_qp))[nz])
            cols.append(3 * q[nz] + c)
            vals.append(val[nz])
    rows_a = np.concatenate(rows) if rows else np.zeros(0, int)
    cols_a = np.concatenate(cols) if cols else np.zeros(0, int)
    vals_a = np.concatenate(vals) if vals else np.zeros(0)
    return sp.csr_matrix((vals_a, (rows_a, cols_a)), shape=(fb.N, 3 * n_fac * n_qp))
