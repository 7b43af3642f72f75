"""Load models: surface force fields parameterised by control values (paper, section 3.3).

A load model maps a control matrix ``C`` (n_spatial, n_time) to a load history
``F(t) = spatial_loads(model) @ C @ time_basis(t)`` (loads in Pa mm^2 on the FEM
DOFs).  The parameter vector of an optimisation is ``x = C.ravel()`` (C order:
spatial index major, time index minor).  The optimiser only sees this
interface (:class:`LoadModel`), so other load models (e.g. a shared normal
pressure tied in time to the measured subglottal pressure) plug in by
implementing ``spatial_loads``, ``time_basis`` and ``spatial_names``.

The paper's force field (:class:`ForceField`)
---------------------------------------------
Per fold and per side (inferior, superior; the mesh's ``node_side`` maps, (u, v)
in [0, 1]^2 with u = x / L longitudinal and v from the lateral wall (0) to the
middle of the medial surface (1)), five scalar fields give the traction (Pa) in
the model frame:

- ``x`` (longitudinal traction): two pieces split along u at 0.5 (anterior and
  posterior halves, :func:`vfcli.model.loads.bernstein.piecewise_bernstein` in u, Bernstein in v);
- ``y`` (lateral traction): two pieces split along v at 0.5 (lateral and medial
  halves, Bernstein in u, piecewise in v);
- ``z`` (vertical traction): one piece over the whole side.

This is our reading of the paper's figure 5 ("split in the lateral and
longitudinal direction into two pieces with C0 continuity"): each piece is its
own Bernstein patch with ``n_u x n_v`` control values over its half, and the two
pieces share the control values on the split line, so each field is continuous
but may kink there.  Hence per (fold, side, time) ``(2 n_u - 1) n_v`` x-values,
``n_u (2 n_v - 1)`` y-values and ``n_u n_v`` z-values.  Time is a Bernstein basis
of ``n_t`` control values (degree n_t - 1) over ``[t1, t2]``.

Folds are independent by default; ``tie_folds=True`` makes fold 0's traction the
mirror image of fold 1's (same x, z; negated y) at the same (u, v), with one set
of control values.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.model.loads.bernstein import bernstein, piecewise_bernstein, tensor_basis
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR

SIDES = {"inferior": SIDE_INFERIOR, "superior": SIDE_SUPERIOR}
COMPONENTS = ("x", "y", "z")


class LoadModel:
    """Interface of a load model linear in its control values (subclass it).

    Attributes
    ----------
    n_spatial : number of spatial load patterns (rows of C).
    n_time : number of time basis functions (columns of C).
    """

    n_spatial: int
    n_time: int

    @property
    def n_params(self) -> int:
        """Length of the parameter vector ``x = C.ravel()``."""
        return self.n_spatial * self.n_time

    def spatial_loads(self, model) -> sp.csr_matrix | np.ndarray:
        """(n_dofs, n_spatial) load vectors (Pa mm^2) of the spatial patterns on ``model``."""
        raise NotImplementedError

    def time_basis(self, times: np.ndarray) -> np.ndarray:
        """(T, n_time) time basis at ``times`` (s)."""
        raise NotImplementedError

    def spatial_names(self) -> list[str]:
        """n_spatial readable names of the spatial patterns."""
        raise NotImplementedError

    def parameter_names(self) -> list[str]:
        """n_params names, ``"<spatial name>@t<k>"`` in the order of ``x``."""
        return [f"{s}@t{k}" for s in self.spatial_names() for k in range(self.n_time)]

    def penalty_operator(self) -> sp.csr_matrix:
        """(n_params, n_params) PSD matrix Omega of the ridge term ``x^T Omega x`` (identity: the size)."""
        return sp.identity(self.n_params, format="csr")

    def control_matrix(self, x: np.ndarray) -> np.ndarray:
        """(n_spatial, n_time) view of a parameter vector (n_params,)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_params,):
            raise ValueError(f"control vector must have shape ({self.n_params},), got {x.shape}")
        return x.reshape(self.n_spatial, self.n_time)


@dataclass(frozen=True)
class ForceFieldSpec:
    """Layout of the paper's force field.

    Parameters
    ----------
    resolution : (n_u, n_v, n_t) control values per piece (each >= 1; n_t >= 1).
    sides : sides that carry forces: ("inferior",) is the paper's one-sided setup.
    tie_folds : fold 0 mirrors fold 1 (one set of control values).
    """

    resolution: tuple[int, int, int] = (3, 3, 10)
    sides: tuple[str, ...] = ("inferior", "superior")
    tie_folds: bool = False

    def __post_init__(self) -> None:
        res = tuple(int(r) for r in self.resolution)
        if len(res) != 3 or any(r < 1 for r in res) or any(r != rr for r, rr in zip(res, self.resolution)):
            raise ValueError(f"force field resolution must be three integers >= 1, got {self.resolution!r}")
        object.__setattr__(self, "resolution", res)
        sides = tuple(self.sides)
        if not sides or any(s not in SIDES for s in sides) or len(set(sides)) != len(sides):
            raise ValueError(f"force field sides must be a non-empty subset of {tuple(SIDES)}, got {self.sides!r}")
        object.__setattr__(self, "sides", tuple(s for s in SIDES if s in sides))

    @classmethod
    def from_name(cls, name: str, tie_folds: bool = False) -> ForceFieldSpec:
        """Parse ``"<n_u>x<n_v>x<n_t>-one-sided"`` (inferior only) or ``"...-two-sided"``."""
        m = re.fullmatch(r"(\d+)x(\d+)x(\d+)-(one|two)-sided", str(name).strip())
        if m is None:
            raise ValueError(f"force field setup must look like '3x3x10-two-sided', got {name!r}")
        sides = ("inferior",) if m.group(4) == "one" else ("inferior", "superior")
        return cls(tuple(int(m.group(k)) for k in (1, 2, 3)), sides, tie_folds)


class ForceField(LoadModel):
    """The paper's piecewise Bernstein surface traction field (see module docstring).

    Parameters
    ----------
    spec : layout.
    t_range : (t1, t2) time interval of the Bernstein time basis, s (t1 < t2).
    """

    def __init__(self, spec: ForceFieldSpec, t_range: tuple[float, float]) -> None:
        t1, t2 = (float(v) for v in t_range)
        if not (np.isfinite(t1) and np.isfinite(t2) and t2 > t1):
            raise ValueError(f"force field time range must be t1 < t2, got {t_range!r}")
        self.spec = spec
        self.t_range = (t1, t2)
        n_u, n_v, n_t = spec.resolution
        self.component_shapes = {"x": (2 * n_u - 1, n_v), "y": (n_u, 2 * n_v - 1), "z": (n_u, n_v)}
        folds = ("tied",) if spec.tie_folds else ("fold0", "fold1")
        #: blocks: (name, fold label, side name, component, slice of the spatial index)
        self.blocks: list[tuple[str, str, str, str, slice]] = []
        start = 0
        for fold in folds:
            for side in spec.sides:
                for comp in COMPONENTS:
                    size = int(np.prod(self.component_shapes[comp]))
                    self.blocks.append((f"{fold}/{side}/{comp}", fold, side, comp, slice(start, start + size)))
                    start += size
        self.n_spatial = start
        self.n_time = n_t

    def spatial_names(self) -> list[str]:
        names = []
        for name, _, _, comp, _ in self.blocks:
            a, b = self.component_shapes[comp]
            names += [f"{name}[{i},{j}]" for i in range(a) for j in range(b)]
        return names

    def scalar_basis(self, component: str, uv: np.ndarray) -> np.ndarray:
        """(P, n_block) basis of one component's scalar field at (u, v) points (P, 2)."""
        n_u, n_v, _ = self.spec.resolution
        u, v = uv[:, 0], uv[:, 1]
        bu = piecewise_bernstein(n_u - 1, u) if component == "x" else bernstein(n_u - 1, u)
        bv = piecewise_bernstein(n_v - 1, v) if component == "y" else bernstein(n_v - 1, v)
        return tensor_basis([bu, bv])

    def spatial_basis(self, quadrature) -> sp.csr_matrix:
        """Tractions at the quadrature points per unit spatial control value.

        Parameters
        ----------
        quadrature : :class:`vfcli.model.fem.FacetQuadrature` (Q points), e.g. ``model.quadrature``.

        Returns
        -------
        (3 Q, n_spatial) csr, Pa per unit control value; row ``3 q + c`` is the
        model-frame component c of the traction at point q.
        """
        rows, cols, vals = [], [], []
        for _, fold, side, comp, sl in self.blocks:
            c = COMPONENTS.index(comp)
            targets = [(0, 1.0), (1, 1.0)] if fold == "tied" else [(int(fold[-1]), 1.0)]
            if fold == "tied" and comp == "y":
                targets = [(0, -1.0), (1, 1.0)]
            for k, sign in targets:
                pts = np.flatnonzero((quadrature.fold == k) & (quadrature.side == SIDES[side]))
                if pts.size == 0:
                    continue
                b = self.scalar_basis(comp, quadrature.uv[pts])  # (P, n_block)
                r, j = np.nonzero(b)
                rows.append(3 * pts[r] + c)
                cols.append(sl.start + j)
                vals.append(sign * b[r, j])
        q = len(quadrature.weights)
        if not rows:
            return sp.csr_matrix((3 * q, self.n_spatial))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * q, self.n_spatial))

    def spatial_loads(self, model) -> sp.csr_matrix:
        """(n_dofs, n_spatial) FEM loads, Pa mm^2: ``model.traction_operator() @ S``."""
        return (model.traction_operator() @ self.spatial_basis(model.quadrature)).tocsr()

    def penalty_operator(self) -> sp.csr_matrix:
        """(n_params, n_params) Tikhonov matrix ``Omega = I + D_s^T D_s + D_t^T D_t``, dimensionless.

        ``x^T Omega x`` is the size of the control values plus the squared first
        differences between neighbouring control values of each scalar field in u, v
        (within its control grid) and in time (Pa^2): the bound the regularised free
        fields put on the loads (``optimize.loads = "free-regularised"``).
        """
        n_t = self.n_time
        rows = []
        for _, _, _, comp, sl in self.blocks:
            a, b = self.component_shapes[comp]
            grid = np.arange(sl.start, sl.stop).reshape(a, b)
            for lo, hi in ((grid[:-1, :], grid[1:, :]), (grid[:, :-1], grid[:, 1:])):
                rows.append(np.column_stack([lo.ravel(), hi.ravel()]))
        pairs = np.concatenate(rows) if rows else np.zeros((0, 2), int)
        d_space = sp.csr_matrix((np.tile([-1.0, 1.0], len(pairs)), (np.repeat(np.arange(len(pairs)), 2), pairs.ravel())),
                                shape=(len(pairs), self.n_spatial))
        d_time = sp.diags([-np.ones(n_t - 1), np.ones(n_t - 1)], [0, 1], shape=(n_t - 1, n_t))
        d_s = sp.kron(d_space, sp.identity(n_t))
        d_t = sp.kron(sp.identity(self.n_spatial), d_time)
        return (sp.identity(self.n_params) + d_s.T @ d_s + d_t.T @ d_t).tocsr()

    def time_basis(self, times: np.ndarray) -> np.ndarray:
        """(T, n_t) Bernstein basis of degree n_t - 1 in ``(t - t1) / (t2 - t1)``."""
        t1, t2 = self.t_range
        return bernstein(self.n_time - 1, (np.asarray(times, dtype=float) - t1) / (t2 - t1))

    def tractions(self, model, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, Q, 3) tractions (Pa) at ``model.quadrature`` points for parameters ``x``."""
        s = self.spatial_basis(model.quadrature)
        vals = s @ (self.control_matrix(x) @ self.time_basis(times).T)  # (3Q, T)
        return vals.T.reshape(len(np.atleast_1d(times)), -1, 3)
