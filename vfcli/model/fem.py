"""Linear elasticity of the two folds with scikit-fem P2 tetrahedra.

Units
-----
Geometry in mm, Young's modulus, tractions and pressures in Pa, so the
stiffness is in Pa mm, load vectors in Pa mm^2 (= micronewton) and
displacements in mm.  Body forces are given in N/m^3 (scaled by 1e-3 to
Pa/mm).  The mass matrix is ``rho[kg/m^3] * 1e-6 * int(phi phi) dV[mm^3]``, so
``M a + K u = f`` holds with accelerations in mm/s^2 and time in s, and the
eigenvalues of ``(K, M)`` are omega^2 in (rad/s)^2.

Locking
-------
nu = 0.499 locks linear tetrahedra; quadratic tetrahedra (ElementTetP2) do not
(tests/test_fem.py: thick cylinder).  ``volumetric="reduced"`` integrates the
lambda div(u) div(v) term with one point per tet, which is the mixed P2-P0
(u-p) element with the pressure condensed out: still SPD, more accurate at
nu -> 1/2.

Structure
---------
The folds are separate bodies: each is its own scikit-fem mesh and basis, the
global DOF vector is ``[fold 0 DOFs, fold 1 DOFs]`` and K, M are
block-diagonal.  Each fold's free block is factorised separately; when fold 0
is the mirror image of fold 1 (no offsets or rotations), one factorisation
serves both (``K0 = (E0 / E1) S^T K1 S`` with S the mirror DOF map).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.model.elasticity import (
    BODY_FORCE_SCALE,
    facet_load_operator,
    lame_parameters,
    mass_matrix,
    stiffness_matrix,
)
from vfcli.model.mesh import SIDE_NONE, TAG_FIXTURE, FoldMesh
from vfcli.model.solver import Factorization, factorize, resolve_backend

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class FacetQuadrature:
    """Quadrature points on the boundary facets (all folds, facet-major order).

    Attributes
    ----------
    positions : (Q, 3) float64, mm (undeformed).
    weights : (Q,) float64, mm^2 (area weights: sum over a facet = its area).
    normals : (Q, 3) float64, outward unit normals.
    tag : (Q,) int8, face tag of the facet (vfcli.model.mesh TAG_*).
    fold : (Q,) int8.
    side : (Q,) int8, SIDE_INFERIOR / SIDE_SUPERIOR (0 on fixture facets).
    uv : (Q, 2) float64, (u, v) linearly interpolated from the facet's nodes
        (NaN on fixture facets).
    face : (Q,) int64, index of the facet in ``FoldMesh.faces``.
    """

    positions: np.ndarray
    weights: np.ndarray
    normals: np.ndarray
    tag: np.ndarray
    fold: np.ndarray
    side: np.ndarray
    uv: np.ndarray
    face: np.ndarray

    def select(self, mask: np.ndarray) -> FacetQuadrature:
        """The subset of points where ``mask`` (Q,) bool is true."""
        return FacetQuadrature(**{k: getattr(self, k)[mask] for k in self.__dataclass_fields__})

    def __len__(self) -> int:
        return len(self.weights)


class _Fold:
    """One fold: its skfem mesh, basis, matrices and DOF bookkeeping."""

    def __init__(self, mesh: FoldMesh, fold: int, element, youngs_pa: float, poisson: float,
                 volumetric: str, facet_intorder: int) -> None:
        from skfem import Basis, ElementVector, FacetBasis, MeshTet

        self.fold = fold
        self.nodes = mesh.fold_nodes(fold)  # global node ids, sorted
        local = np.full(mesh.n_nodes, -1, dtype=np.int64)
        local[self.nodes] = np.arange(len(self.nodes))
        tets = local[mesh.tets[mesh.tet_fold == fold]]
        self.skmesh = MeshTet(np.ascontiguousarray(mesh.nodes[self.nodes].T), np.ascontiguousarray(tets.T))
        self.element = element  # scalar
        self.basis = Basis(self.skmesh, ElementVector(element), intorder=2)
        self.n_dofs = self.basis.N
        if not np.array_equal(self.basis.nodal_dofs % 3, np.broadcast_to(np.arange(3)[:, None],
                                                                           self.basis.nodal_dofs.shape)):
            raise RuntimeError("scikit-fem vector DOFs are not interleaved (3 a + c): unsupported version")
        lam, mu = lame_parameters(youngs_pa, poisson)
        self.youngs_pa = youngs_pa
        self.stiffness = stiffness_matrix(self.skmesh, element, lam, mu, volumetric)

        # boundary faces of this fold -> skfem facet indices
        face_ids = np.flatnonzero(mesh.face_fold == fold)
        local_faces = np.sort(local[mesh.faces[face_ids]], axis=1)
        n = len(self.nodes)
        sk_keys = (self.skmesh.facets[0].astype(np.int64) * n + self.skmesh.facets[1]) * n + self.skmesh.facets[2]
        order = np.argsort(sk_keys)
        keys = (local_faces[:, 0] * n + local_faces[:, 1]) * n + local_faces[:, 2]
        pos = np.searchsorted(sk_keys[order], keys)
        if np.any(pos >= len(order)) or np.any(sk_keys[order][np.minimum(pos, len(order) - 1)] != keys):
            raise ValueError("FoldMesh.faces are not faces of the tetrahedra")
        facets = order[pos]
        self.face_ids = face_ids
        fixture = facets[mesh.face_tag[face_ids] == TAG_FIXTURE]
        self.fixed = np.unique(self.basis.get_dofs(facets=fixture).all())
        self.free = np.setdiff1d(np.arange(self.n_dofs), self.fixed)

        # facet quadrature over every boundary face of the fold (face order)
        fb = FacetBasis(self.skmesh, ElementVector(element), facets=facets, intorder=facet_intorder)
        self.facet_basis = fb
        self.load_operator = facet_load_operator(fb)
        n_fac, n_qp = fb.dx.shape
        x = np.asarray(fb.global_coordinates())  # (3, n_fac, n_qp)
        self.qp_positions = x.reshape(3, -1).T
        self.qp_weights = fb.dx.ravel()
        self.qp_normals = np.asarray(fb.normals).reshape(3, -1).T
        self.qp_face = np.repeat(face_ids, n_qp)
        # barycentric interpolation of the node (u, v) on each facet
        tri = mesh.faces[face_ids]
        a, b, c = (mesh.nodes[tri[:, k]] for k in range(3))
        v0, v1 = b - a, c - a
        v2 = np.moveaxis(x, 0, -1) - a[:, None, :]
        d00 = np.einsum("ij,ij->i", v0, v0)[:, None]
        d01 = np.einsum("ij,ij->i", v0, v1)[:, None]
        d11 = np.einsum("ij,ij->i", v1, v1)[:, None]
        d20 = np.einsum("ijk,ik->ij", v2, v0)
        d21 = np.einsum("ijk,ik->ij", v2, v1)
        den = d00 * d11 - d01 * d01
        lb = (d11 * d20 - d01 * d21) / den
        lc = (d00 * d21 - d01 * d20) / den
        la = 1.0 - lb - lc
        uvn = mesh.uv[tri]  # (n_fac, 3, 2)
        self.qp_uv = (la[..., None] * uvn[:, None, 0] + lb[..., None] * uvn[:, None, 1]
                      + lc[..., None] * uvn[:, None, 2]).reshape(-1, 2)

        # DOF bookkeeping for vertex displacements and mirroring
        self.vertex_dofs = self.basis.nodal_dofs  # (3, N_k)
        self.dof_component = np.arange(self.n_dofs) % 3
        self.dof_locations = self.basis.doflocs.T  # (n_dofs, 3)


class ElasticModel:
    """Static and modal linear elasticity of the two folds, factorised once.

    Parameters
    ----------
    mesh : FoldMesh.
    youngs_pa : E in Pa, one value or one per fold (2,). Default 4.4 kPa.
    poisson : nu (0.499).
    density_kg_m3 : rho for the mass matrix (1070).
    element : ``"P2"`` (quadratic tetrahedra, default) or ``"P1"`` (locks at
        nu -> 1/2; for comparison only).
    volumetric : ``"full"`` or ``"reduced"`` (see module docstring).
    backend : sparse solver, ``"auto"`` or a name in :data:`vfcli.model.solver.BACKENDS`.
    facet_intorder : quadrature order on boundary facets (2: 3 points per facet).
    reuse_mirror : reuse fold 1's factorisation for fold 0 when they are mirror
        images (checked on the DOF locations).

    Notes
    -----
    DOF vectors have length :attr:`n_dofs` = fold 0's DOFs followed by fold 1's;
    clamped (fixture) DOFs are zero in every solution.
    """

    def __init__(self, mesh: FoldMesh, youngs_pa: float | np.ndarray = 4400.0, poisson: float = 0.499,
                 density_kg_m3: float = 1070.0, element: str = "P2", volumetric: str = "full",
                 backend: str = "auto", facet_intorder: int = 2, reuse_mirror: bool = True) -> None:
        from skfem import ElementTetP1, ElementTetP2

        e_arr = np.asarray(youngs_pa, dtype=float).ravel()
        if e_arr.size == 1:
            e_arr = np.repeat(e_arr, 2)
        if e_arr.size != 2 or np.any(~np.isfinite(e_arr)) or np.any(e_arr <= 0):
            raise ValueError(f"youngs_pa must be one positive value or two (per fold), got {youngs_pa!r}")
        if not (-1.0 < poisson < 0.5):
            raise ValueError(f"poisson must be in (-1, 0.5), got {poisson!r}")
        if not density_kg_m3 > 0:
            raise ValueError(f"density_kg_m3 must be positive, got {density_kg_m3!r}")
        elements = {"P2": ElementTetP2, "P1": ElementTetP1}
        if element not in elements:
            raise ValueError(f"element must be 'P2' or 'P1', got {element!r}")
        self.mesh = mesh
        self.youngs_pa = e_arr
        self.poisson = float(poisson)
        self.density_kg_m3 = float(density_kg_m3)
        self.backend = resolve_backend(backend)
        scalar = elements[element]()
        self.folds = [_Fold(mesh, k, scalar, float(e_arr[k]), poisson, volumetric, facet_intorder) for k in (0, 1)]
        self.offsets = np.array([0, self.folds[0].n_dofs, self.folds[0].n_dofs + self.folds[1].n_dofs])
        self.n_dofs = int(self.offsets[-1])
        self._mirror = self._mirror_map() if reuse_mirror else None
        self._factors: list[Factorization | None] = [None, None]
        self._mass: sp.csr_matrix | None = None
        self._quad: FacetQuadrature | None = None
        self._load_op: sp.csr_matrix | None = None

    # ------------------------------------------------------------ structure
    def _mirror_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(perm, sign) with fold-0 DOF i = sign[i] * fold-1 DOF perm[i], or None."""
        from scipy.spatial import cKDTree

        f0, f1 = self.folds
        if f0.n_dofs != f1.n_dofs:
            return None
        loc0 = f0.dof_locations * np.array([1.0, -1.0, 1.0])
        scale = np.ptp(f1.dof_locations, axis=0).max()
        key1 = np.column_stack([f1.dof_locations, f1.dof_component * 10.0 * scale])
        key0 = np.column_stack([loc0, f0.dof_component * 10.0 * scale])
        dist, perm = cKDTree(key1).query(key0)
        if dist.max() > 1e-9 * scale or len(np.unique(perm)) != len(perm):
            return None
        sign = np.where(f0.dof_component == 1, -1.0, 1.0)
        fixed0 = np.zeros(f0.n_dofs, bool)
        fixed0[f0.fixed] = True
        fixed1 = np.zeros(f1.n_dofs, bool)
        fixed1[f1.fixed] = True
        if not np.array_equal(fixed0, fixed1[perm]):
            return None
        return perm, sign

    @property
    def is_mirrored(self) -> bool:
        """True if fold 0's system is solved with fold 1's factorisation."""
        return self._mirror is not None

    @property
    def mirror(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(perm, sign), fold-0 DOF i = sign[i] * fold-1 DOF perm[i] (both folds' full DOF numbering), when
        fold 0 is fold 1's mirror image and its solves reuse fold 1's factorisation; else None."""
        return self._mirror

    def fold1_from_fold0(self, v0: np.ndarray) -> np.ndarray:
        """(n_1, m) fold 0's full-size DOF vectors (n_0, m) as fold 1's, by :attr:`mirror` (which must be set)."""
        perm, sign = self._mirror
        out = np.zeros_like(v0)
        out[perm] = sign[:, None] * v0
        return out

    def fold0_from_fold1(self, v1: np.ndarray) -> np.ndarray:
        """(n_0, m) fold 1's full-size DOF vectors (n_1, m) as fold 0's, by :attr:`mirror` (which must be set)."""
        perm, sign = self._mirror
        return sign[:, None] * v1[perm]

    @property
    def stiffness(self) -> sp.csr_matrix:
        """(n_dofs, n_dofs) block-diagonal stiffness, Pa mm (no Dirichlet reduction)."""
        return sp.block_diag([f.stiffness for f in self.folds], format="csr")

    @property
    def mass(self) -> sp.csr_matrix:
        """(n_dofs, n_dofs) block-diagonal consistent mass matrix (internal units)."""
        if self._mass is None:
            self._mass = sp.block_diag([mass_matrix(f.skmesh, f.element, self.density_kg_m3)
                                        for f in self.folds], format="csr")
        return self._mass

    @property
    def free_dofs(self) -> np.ndarray:
        """(n_free,) int64 global indices of the unconstrained DOFs."""
        return np.concatenate([f.free + o for f, o in zip(self.folds, self.offsets)])

    @property
    def fixed_dofs(self) -> np.ndarray:
        """(n_fixed,) int64 global indices of the clamped (fixture) DOFs."""
        return np.concatenate([f.fixed + o for f, o in zip(self.folds, self.offsets)])

    def reduced_matrices(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """(K_ff, M_ff): stiffness and mass restricted to :attr:`free_dofs`."""
        free = self.free_dofs
        return self.stiffness[free][:, free].tocsr(), self.mass[free][:, free].tocsr()

    def __getstate__(self) -> dict:
        """Pickled without its factorisation (solver objects do not pickle): a process that
        unpickles the model (a pool's or a Dask worker's) factorises it on its first solve."""
        state = dict(self.__dict__)
        state["_factors"] = [None, None]
        return state

    # ------------------------------------------------------------ solving
    def factorize(self) -> None:
        """Factorise the free blocks (done lazily by :meth:`solve`)."""
        for k in (1, 0):
            if self._factors[k] is not None:
                continue
            if k == 0 and self._mirror is not None:
                continue
            f = self.folds[k]
            self._factors[k] = factorize(f.stiffness[f.free][:, f.free], self.backend)

    def _solve_fold(self, k: int, rhs: np.ndarray) -> np.ndarray:
        """Solve fold k's full-size system for rhs (n_k, m); zeros at fixed DOFs."""
        f = self.folds[k]
        out = np.zeros_like(rhs)
        if k == 0 and self._mirror is not None:
            mapped = self.fold1_from_fold0(rhs)
            f1 = self.folds[1]
            sol = np.zeros_like(rhs)
            sol[f1.free] = self._factors[1].solve(mapped[f1.free])
            scale = self.folds[1].youngs_pa / f.youngs_pa
            return scale * self.fold0_from_fold1(sol)
        out[f.free] = self._factors[k].solve(rhs[f.free])
        return out

    def solve(self, load: np.ndarray) -> np.ndarray:
        """Static displacements K^-1 F.

        Parameters
        ----------
        load : (n_dofs,) or (n_dofs, k) load vectors, Pa mm^2 (values at fixed
            DOFs are ignored).

        Returns
        -------
        Same shape as ``load``, displacement DOFs in mm (0 at fixed DOFs).
        """
        self.factorize()
        f = np.asarray(load, dtype=np.float64)
        if f.shape[0] != self.n_dofs or f.ndim not in (1, 2):
            raise ValueError(f"load must have shape ({self.n_dofs},) or ({self.n_dofs}, k), got {f.shape}")
        f2 = f.reshape(self.n_dofs, -1)
        out = np.concatenate([self._solve_fold(k, np.ascontiguousarray(f2[self.offsets[k]:self.offsets[k + 1]]))
                              for k in (0, 1)])
        return out.reshape(f.shape)

    def vertex_displacements(self, u: np.ndarray) -> np.ndarray:
        """Displacements at the mesh vertices.

        Parameters
        ----------
        u : (n_dofs,) or (n_dofs, k) solution DOFs, mm.

        Returns
        -------
        (N, 3) float64 mm for one solution, (k, N, 3) for k solutions; rows
        follow ``mesh.nodes``.
        """
        u = np.asarray(u)
        u2 = u.reshape(self.n_dofs, -1)
        out = np.zeros((u2.shape[1], self.mesh.n_nodes, 3))
        for f, o in zip(self.folds, self.offsets):
            dofs = f.vertex_dofs + o  # (3, N_k)
            out[:, f.nodes, :] = np.moveaxis(u2[dofs.T], -1, 0)
        return out[0] if u.ndim == 1 else out

    def vertex_operator(self) -> sp.csr_matrix:
        """(3 N, n_dofs) selection matrix: vertex displacements (row 3 i + c) from DOFs."""
        rows, cols = [], []
        for f, o in zip(self.folds, self.offsets):
            rows.append((3 * f.nodes[:, None] + np.arange(3)[None]).ravel())
            cols.append((f.vertex_dofs.T + o).ravel())
        r, c = np.concatenate(rows), np.concatenate(cols)
        return sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(3 * self.mesh.n_nodes, self.n_dofs))

    # ------------------------------------------------------------ loads
    @property
    def quadrature(self) -> FacetQuadrature:
        """Quadrature points of every boundary facet of both folds."""
        if self._quad is None:
            side = self.mesh.face_side
            pos = np.concatenate([f.qp_positions for f in self.folds])
            face = np.concatenate([f.qp_face for f in self.folds])
            self._quad = FacetQuadrature(
                positions=pos,
                weights=np.concatenate([f.qp_weights for f in self.folds]),
                normals=np.concatenate([f.qp_normals for f in self.folds]),
                tag=self.mesh.face_tag[face].copy(),
                fold=self.mesh.face_fold[face].copy(),
                side=side[face],
                uv=np.where((side[face] == SIDE_NONE)[:, None], np.nan,
                            np.concatenate([f.qp_uv for f in self.folds])),
                face=face,
            )
        return self._quad

    def _full_load_operator(self) -> sp.csr_matrix:
        if self._load_op is None:
            self._load_op = sp.block_diag([f.load_operator for f in self.folds], format="csr")
        return self._load_op

    def quadrature_mask(self, tags=None, folds=None, sides=None) -> np.ndarray:
        """(Q,) bool: quadrature points whose facet tag / fold / side is in the given sets."""
        q = self.quadrature
        mask = np.ones(len(q), bool)
        for values, arr in ((tags, q.tag), (folds, q.fold), (sides, q.side)):
            if values is not None:
                mask &= np.isin(arr, np.atleast_1d(values))
        return mask

    def traction_operator(self, mask: np.ndarray | None = None) -> sp.csr_matrix:
        """Load operator for tractions at the selected quadrature points.

        Parameters
        ----------
        mask : (Q,) bool selecting points of :attr:`quadrature` (all if None),
            e.g. ``model.quadrature_mask(tags=[TAG_INFERIOR, TAG_MEDIAL])``.

        Returns
        -------
        (n_dofs, 3 Q_sel) csr, mm^2: ``F = L @ t.ravel()`` with ``t`` (Q_sel, 3)
        tractions in Pa at ``quadrature.select(mask)``.
        """
        op = self._full_load_operator()
        if mask is None:
            return op
        cols = (3 * np.flatnonzero(mask)[:, None] + np.arange(3)[None]).ravel()
        return op[:, cols].tocsr()

    def pressure_operator(self, mask: np.ndarray | None = None) -> sp.csr_matrix:
        """Load operator for normal pressure (Pa, pushing into the body).

        Returns
        -------
        (n_dofs, Q_sel) csr: ``F = P @ p`` with ``p`` (Q_sel,) Pa; the traction
        is ``-p n`` with ``n`` the outward normal.
        """
        q = self.quadrature
        sel = np.arange(len(q)) if mask is None else np.flatnonzero(mask)
        n = q.normals[sel]
        rows = (3 * np.arange(len(sel))[:, None] + np.arange(3)[None]).ravel()
        cols = np.repeat(np.arange(len(sel)), 3)
        expand = sp.csr_matrix((-n.ravel(), (rows, cols)), shape=(3 * len(sel), len(sel)))
        return (self.traction_operator(mask) @ expand).tocsr()

    def body_force_vector(self, force_n_m3: np.ndarray) -> np.ndarray:
        """Load vector of a uniform body force.

        Parameters
        ----------
        force_n_m3 : (3,) N/m^3 for both folds, or (2, 3) per fold.

        Returns
        -------
        (n_dofs,) Pa mm^2.
        """
        from skfem import LinearForm, asm

        b = np.asarray(force_n_m3, dtype=float)
        b = np.broadcast_to(b, (2, 3)) * BODY_FORCE_SCALE
        parts = []
        for k, f in enumerate(self.folds):
            bk = b[k]

            @LinearForm
            def body(v, w, bk=bk):
                return bk[0] * v[0] + bk[1] * v[1] + bk[2] * v[2]

            parts.append(asm(body, f.basis))
        return np.concatenate(parts)

    # ------------------------------------------------------------ dynamics
    def modes(self, k: int = 6, fold: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Lowest eigenmodes of ``K phi = omega^2 M phi`` (clamped fixture).

        Parameters
        ----------
        k : number of modes.
        fold : 0 or 1 for one fold's modes only; None for the two-fold system
            (the union of both folds' spectra, lowest k).

        Returns
        -------
        freqs_hz : (k,) float64, ascending.
        shapes : (n_dofs, k) mass-normalised (phi^T M phi = 1), 0 at fixed DOFs.
        """
        from scipy.sparse.linalg import LinearOperator, eigsh

        self.factorize()
        folds = (0, 1) if fold is None else (fold,)
        freqs, shapes = [], []
        mass = self.mass
        for kk in folds:
            f = self.folds[kk]
            o = self.offsets[kk]
            m_ff = mass[o + f.free][:, o + f.free].tocsr()
            k_ff = f.stiffness[f.free][:, f.free].tocsr()

            def op(x, kk=kk, f=f):
                full = np.zeros((f.n_dofs, 1))
                full[f.free, 0] = np.ravel(x)
                return self._solve_fold(kk, full)[f.free, 0]

            n = len(f.free)
            opinv = LinearOperator((n, n), matvec=op, dtype=float)
            # a fixed start vector: ARPACK's own is random, and the modes (a diagnosis's modal reduction with
            # them) then differed between two runs of the same store at round-off (eigenvalues 1e-11 relative)
            v0 = np.random.default_rng(0).uniform(0.5, 1.5, n)
            vals, vecs = eigsh(k_ff, k=k, M=m_ff, sigma=0.0, which="LM", OPinv=opinv, v0=v0)
            full = np.zeros((self.n_dofs, k))
            full[o + f.free] = vecs
            freqs.append(np.sqrt(np.abs(vals)) / (2 * np.pi))
            shapes.append(full)
        fr = np.concatenate(freqs)
        sh = np.concatenate(shapes, axis=1)
        order = np.argsort(fr, kind="stable")[:k]
        return fr[order], sh[:, order]
