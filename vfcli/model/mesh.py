"""Tetrahedral mesh of the two M5 folds (tetgen), with boundary tags and (u, v) maps.

One fold is meshed in the profile frame of :mod:`vfcli.model.m5` (a straight prism of
the profile along x in [0, L]) and placed twice: fold 0 (left, y < 0) is the
mirror image of fold 1 (right, y > 0), node for node (node ``i`` of fold 0 and
node ``i + N/2`` of fold 1 are mirror images), then each fold gets its own
offset and rotation.

Boundary tags (by geometry: the contour segment a face lies on)
-----------------------------------------------------------------
- ``TAG_SUPERIOR`` (2): flat superior surface and exit arc (outward normal n_z >= 0);
- ``TAG_MEDIAL`` (3): straight medial surface (normal along y, towards the midplane);
- ``TAG_INFERIOR`` (1): entrance arc and inferior slope (n_z < 0);
- ``TAG_FIXTURE`` (4): lateral wall, anterior face x = 0 and posterior face x = L
  (glued: clamped in the FEM).

Sides and (u, v) maps (for the force fields)
--------------------------------------------
The free contour (everything but the lateral wall) is parameterised by its
polyline arc length ``a`` from the superior-lateral corner and split in the
middle of the medial straight (``z = -(R_O + T)/2``):

- superior side (``node_side == 2``): flat superior + exit arc + upper half of the
  medial surface, ``v = a / a_split`` (0 at the lateral wall, 1 at the split);
- inferior side (``node_side == 1``): lower half of the medial surface + entrance
  arc + inferior slope, ``v = (a_free - a) / (a_free - a_split)`` (0 at the lateral
  wall, 1 at the split);
- ``u = x / L`` on both sides (0 anterior, 1 posterior).

Nodes on the split line have ``v = 1`` in both maps and are given to the
superior side (``node_side == 2``).  A free face belongs to the inferior side
if any of its nodes has ``node_side == 1`` and to the superior side otherwise
(:attr:`FoldMesh.face_side`); no face crosses the split because the split is a
line of mesh edges.  Nodes on no free face (interior nodes, and nodes only on
fixture faces) have ``uv = NaN`` and ``node_side == 0``.
"""
from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial import Delaunay

from vfcli.errors import ConfigError
from vfcli.model.m5 import SEGMENTS, M5Params

log = logging.getLogger(__name__)

TAG_INFERIOR = 1
TAG_SUPERIOR = 2
TAG_MEDIAL = 3
TAG_FIXTURE = 4
TAG_NAMES = {TAG_INFERIOR: "inferior", TAG_SUPERIOR: "superior", TAG_MEDIAL: "medial", TAG_FIXTURE: "fixture"}

SIDE_NONE = 0
SIDE_INFERIOR = 1
SIDE_SUPERIOR = 2

#: default target edge length (mm), chosen with bench/bench_fem.py (docs/benchmarks.md)
DEFAULT_EDGE_MM = 1.5
DEFAULT_MIN_RATIO = 1.5
DEFAULT_MIN_DIHEDRAL_DEG = 15.0
#: largest tetgen minimum dihedral angle target (degrees, the config's bound too): on the M5 prism
#: tetgen's quality refinement ran without end from 21 (target edge 0.7 mm), 21.5 (1.0 mm) and
#: 22 degrees (1.5 mm) on; at 20 it already doubled the mesh at 0.4-0.5 mm, at 18 it adds ~20 %
MAX_MIN_DIHEDRAL_DEG = 18.0
#: tetgen may add at most this many points per max-volume tet of the fold and per surface point
#: (``-S``), so that a refinement that does not end stops instead of filling the memory; meshes
#: within the bounds add at most 0.35 per max-volume tet
_MAX_ADDED_PER_TET = 4

# outward faces of a positively oriented tet (p0, p1, p2, p3)
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
_SEGMENT_TAG = {
    "superior": TAG_SUPERIOR, "exit_arc": TAG_SUPERIOR, "medial": TAG_MEDIAL,
    "entrance_arc": TAG_INFERIOR, "inferior": TAG_INFERIOR, "lateral": TAG_FIXTURE,
}


@dataclass(frozen=True, eq=False)
class FoldMesh:
    """Linear tetrahedral mesh of both folds (plain arrays; ``FoldMesh(**arrays)``).

    Attributes
    ----------
    nodes : (N, 3) float64, model-frame positions, mm.
    tets : (M, 4) int64 node indices, positively oriented.
    tet_fold : (M,) int8, 0 (left) or 1 (right).
    faces : (K, 3) int64 boundary triangles, counter-clockwise seen from outside.
    face_tag : (K,) int8, one of TAG_INFERIOR, TAG_SUPERIOR, TAG_MEDIAL, TAG_FIXTURE.
    face_fold : (K,) int8.
    uv : (N, 2) float64 in [0, 1]^2 for nodes on free faces, NaN elsewhere.
    node_side : (N,) int8, SIDE_NONE, SIDE_INFERIOR or SIDE_SUPERIOR.
    """

    nodes: np.ndarray
    tets: np.ndarray
    tet_fold: np.ndarray
    faces: np.ndarray
    face_tag: np.ndarray
    face_fold: np.ndarray
    uv: np.ndarray
    node_side: np.ndarray

    def __post_init__(self) -> None:
        spec = {
            "nodes": (np.float64, 3), "tets": (np.int64, 4), "tet_fold": (np.int8, None),
            "faces": (np.int64, 3), "face_tag": (np.int8, None), "face_fold": (np.int8, None),
            "uv": (np.float64, 2), "node_side": (np.int8, None),
        }
        for name, (dtype, ncol) in spec.items():
            arr = np.ascontiguousarray(getattr(self, name), dtype=dtype)
            if ncol is not None and (arr.ndim != 2 or arr.shape[1] != ncol):
                raise ValueError(f"FoldMesh.{name} must have shape (n, {ncol}), got {arr.shape}")
            if ncol is None and arr.ndim != 1:
                raise ValueError(f"FoldMesh.{name} must be one-dimensional, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        n = len(self.nodes)
        if len(self.uv) != n or len(self.node_side) != n:
            raise ValueError("FoldMesh.uv and node_side must have one row per node")
        if len(self.tet_fold) != len(self.tets) or len(self.face_tag) != len(self.faces) \
                or len(self.face_fold) != len(self.faces):
            raise ValueError("FoldMesh per-tet / per-face arrays do not match tets / faces")
        if self.tets.size and (self.tets.min() < 0 or self.tets.max() >= n):
            raise ValueError("FoldMesh.tets refers to nodes that do not exist")

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The eight arrays by name (what the store saves under /mesh)."""
        return {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def face_side(self) -> np.ndarray:
        """(K,) int8 side of each boundary face: 1 inferior, 2 superior, 0 fixture."""
        ns = self.node_side[self.faces]
        side = np.where(np.any(ns == SIDE_INFERIOR, axis=1), SIDE_INFERIOR, SIDE_SUPERIOR).astype(np.int8)
        side[self.face_tag == TAG_FIXTURE] = SIDE_NONE
        return side

    def fold_nodes(self, fold: int) -> np.ndarray:
        """Sorted indices of the nodes of one fold, (N_k,) int64."""
        return np.unique(self.tets[self.tet_fold == fold])

    def tet_volumes(self) -> np.ndarray:
        """(M,) float64 signed volumes of the tets, mm^3 (positive)."""
        p = self.nodes[self.tets]
        return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0

    def fold_volume(self, fold: int) -> float:
        """Volume of one fold, mm^3."""
        return float(self.tet_volumes()[self.tet_fold == fold].sum())

    def min_dihedral_deg(self) -> float:
        """Smallest dihedral angle over all tets, degrees."""
        return float(dihedral_angles_deg(self.nodes, self.tets).min())


def dihedral_angles_deg(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(M, 6) interior dihedral angles of tets, degrees."""
    p = nodes[tets]
    normals = []
    for f in _TET_FACES:  # 4 faces, vectorised over tets
        a, b, c = p[:, f[0]], p[:, f[1]], p[:, f[2]]
        n = np.cross(b - a, c - a)
        normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    cos = np.stack([np.einsum("ij,ij->i", normals[i], normals[j]) for i, j in pairs], axis=1)
    return 180.0 - np.degrees(np.arccos(np.clip(cos, -1, 1)))


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """(K, 3) boundary triangles of a positively oriented tet mesh, outward."""
    all_faces = tets[:, _TET_FACES].reshape(-1, 3)
    key = np.sort(all_faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return all_faces[counts[inv.ravel()] == 1]


# ---------------------------------------------------------------- surface mesh
def _cap_triangulation(contour: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Delaunay triangulation of the (convex) profile with interior lattice points.

    Returns the (Q, 2) interior points and (T, 3) triangles indexing
    ``[contour; interior]``, counter-clockwise in (s, z).
    """
    lo, hi = contour.min(axis=0), contour.max(axis=0)
    dz = h * math.sqrt(3) / 2
    rows = np.arange(lo[1] + dz / 2, hi[1], dz)
    grid = [np.column_stack([np.arange(lo[0] + (0.5 + 0.5 * (k % 2)) * h, hi[0], h),
                             np.full(len(np.arange(lo[0] + (0.5 + 0.5 * (k % 2)) * h, hi[0], h)), z)])
            for k, z in enumerate(rows)]
    cand = np.concatenate(grid) if grid else np.zeros((0, 2))
    a = contour
    b = np.roll(contour, -1, axis=0)
    e = b - a
    rel = cand[:, None, :] - a[None]
    cross = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]
    t = np.clip(np.einsum("pek,ek->pe", rel, e) / np.einsum("ek,ek->e", e, e), 0, 1)
    dist = np.linalg.norm(rel - t[..., None] * e[None], axis=2).min(axis=1)
    inner = cand[np.all(cross > 0, axis=1) & (dist > 0.55 * h)]
    pts = np.concatenate([contour, inner])
    tri = Delaunay(pts).simplices
    p = pts[tri]
    area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                  - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    tri = np.where((area < 0)[:, None], tri[:, [0, 2, 1]], tri)
    tri = tri[np.abs(area) > 1e-12 * h * h]
    # the boundary of the triangulation must be the contour polyline
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    n_c = len(contour)
    expect = np.sort(np.column_stack([np.arange(n_c), (np.arange(n_c) + 1) % n_c]), axis=1)
    if not np.array_equal(np.unique(expect, axis=0), uniq[counts == 1]):
        raise RuntimeError("cap triangulation does not follow the M5 contour (non-convex profile?)")
    return inner, tri


def _prism_surface(params: M5Params, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed triangulated surface of one fold in the profile frame (x, s, z)."""
    contour, seg = params.contour(h)
    n_c = len(contour)
    n_x = max(1, math.ceil(params.length_mm / h - 1e-9))
    xs = np.linspace(0.0, params.length_mm, n_x + 1)
    side_pts = np.column_stack([np.repeat(xs, n_c), np.tile(contour, (n_x + 1, 1))])
    i = np.arange(n_c)
    ip = (i + 1) % n_c
    j = np.arange(n_x)
    a = (j[:, None] * n_c + i[None]).ravel()
    b = (j[:, None] * n_c + ip[None]).ravel()
    c = a + n_c
    d = b + n_c
    side_tris = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    inner, cap = _cap_triangulation(contour, h)
    n_side = len(side_pts)
    n_in = len(inner)

    def cap_index(k: np.ndarray, x_layer: int, offset: int) -> np.ndarray:
        return np.where(k < n_c, x_layer * n_c + k, offset + k - n_c)

    cap0 = cap_index(cap, 0, n_side)
    cap1 = cap_index(cap, n_x, n_side + n_in)
    pts = np.concatenate([
        side_pts,
        np.column_stack([np.zeros(n_in), inner]),
        np.column_stack([np.full(n_in, params.length_mm), inner]),
    ])
    tris = np.concatenate([side_tris, cap0, cap1])
    return pts, tris, contour, seg


# ---------------------------------------------------------------- (u, v) maps
def _contour_arclength(points_sz: np.ndarray, contour: np.ndarray) -> np.ndarray:
    """Polyline arc length (from contour point 0) of the nearest point on the contour."""
    a = contour
    e = np.roll(contour, -1, axis=0) - a
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(e, axis=1))])
    rel = points_sz[:, None, :] - a[None]
    t = np.clip(np.einsum("pek,ek->pe", rel, e) / np.einsum("ek,ek->e", e, e), 0, 1)
    dist = np.linalg.norm(rel - t[..., None] * e[None], axis=2)
    k = np.argmin(dist, axis=1)
    return cum[k] + t[np.arange(len(k)), k] * np.linalg.norm(e[k], axis=1)


def _tag_and_uv(params: M5Params, ref_nodes: np.ndarray, faces: np.ndarray, contour: np.ndarray,
                seg: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tags of the boundary faces and (u, v, side) of the nodes, in the profile frame."""
    tol = 1e-6 * max(1.0, h)
    cen = ref_nodes[faces].mean(axis=1)
    e = np.roll(contour, -1, axis=0) - contour
    rel = cen[:, None, 1:] - contour[None]
    t = np.clip(np.einsum("pek,ek->pe", rel, e) / np.einsum("ek,ek->e", e, e), 0, 1)
    nearest = np.argmin(np.linalg.norm(rel - t[..., None] * e[None], axis=2), axis=1)
    seg_tag = np.array([_SEGMENT_TAG[name] for name in SEGMENTS], dtype=np.int8)
    tag = seg_tag[seg[nearest]]
    on_end = (np.abs(cen[:, 0]) < tol) | (np.abs(cen[:, 0] - params.length_mm) < tol)
    tag[on_end] = TAG_FIXTURE

    n = len(ref_nodes)
    uv = np.full((n, 2), np.nan)
    side = np.zeros(n, dtype=np.int8)
    free = np.unique(faces[tag != TAG_FIXTURE])
    arc = _contour_arclength(ref_nodes[free, 1:], contour)
    edge_len = np.linalg.norm(e, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(edge_len)])
    lateral_start = int(np.flatnonzero(seg == SEGMENTS.index("lateral"))[0])
    a_free = cum[lateral_start]
    split_idx = int(np.argmin(np.abs(contour[:, 1] - params.split_z_mm) + np.abs(contour[:, 0])))
    a_split = cum[split_idx]
    sup = arc <= a_split + tol
    v = np.where(sup, arc / a_split, (a_free - arc) / (a_free - a_split))
    uv[free, 0] = ref_nodes[free, 0] / params.length_mm
    uv[free, 1] = np.clip(v, 0.0, 1.0)
    side[free] = np.where(sup, SIDE_SUPERIOR, SIDE_INFERIOR)
    return tag, uv, side


# ---------------------------------------------------------------- build
@contextlib.contextmanager
def _quiet_stdout():
    """Silence C-level writes to stdout (tetgen prints 'parsing switches')."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # captured stream without a descriptor
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(saved)


def build_mesh(params: M5Params | None = None, target_edge_mm: float = DEFAULT_EDGE_MM,
               min_ratio: float = DEFAULT_MIN_RATIO,
               min_dihedral_deg: float = DEFAULT_MIN_DIHEDRAL_DEG) -> FoldMesh:
    """Mesh both M5 folds with tetgen.

    Parameters
    ----------
    params : M5 shape and placement (defaults: :class:`M5Params()`).
    target_edge_mm : target edge length (mm) of the surface triangulation; the
        interior tets are limited to the volume of a regular tet of this edge.
    min_ratio : tetgen radius-edge ratio bound (``-q`` first value, > 1).
    min_dihedral_deg : tetgen minimum dihedral angle (``-q`` second value), degrees, at most
        :data:`MAX_MIN_DIHEDRAL_DEG`; a target, not a guarantee (see :meth:`FoldMesh.min_dihedral_deg`).

    Returns
    -------
    FoldMesh with fold 0 (nodes ``[0, N/2)``) the mirror image of fold 1
    (nodes ``[N/2, N)``) before offsets and rotations.

    Raises
    ------
    ValueError : sizes out of range (the config validates them first).
    ConfigError : tetgen fails on these switches, or its quality refinement does not end within
        its bound on added points (change mesh.min_ratio or mesh.min_dihedral_deg).
    """
    import tetgen

    params = M5Params() if params is None else params
    h = float(target_edge_mm)
    if not (math.isfinite(h) and 0.05 <= h <= 5.0):
        raise ValueError(f"mesh target_edge_mm must be in [0.05, 5] mm, got {target_edge_mm!r}")
    if not (min_ratio > 1.0):
        raise ValueError(f"mesh min_ratio must be > 1, got {min_ratio!r}")
    if not (0.0 <= min_dihedral_deg <= MAX_MIN_DIHEDRAL_DEG):
        raise ValueError(f"mesh min_dihedral_deg must be in [0, {MAX_MIN_DIHEDRAL_DEG:g}], got {min_dihedral_deg!r}")

    pts, tris, contour, seg = _prism_surface(params, h)
    max_vol = h ** 3 / (6 * math.sqrt(2))
    max_added = _MAX_ADDED_PER_TET * (math.ceil(params.volume_mm3() / max_vol) + len(pts))
    switches = f"pYq{min_ratio:g}/{min_dihedral_deg:g}a{max_vol:.6g}S{max_added}Q"
    tg = tetgen.TetGen(pts.astype(np.float64), tris.astype(np.int32))
    try:
        with _quiet_stdout():
            nodes, elems, *_ = tg.tetrahedralize(switches=switches)
    except RuntimeError as exc:  # pragma: no cover - tetgen failure
        raise ConfigError(f"tetgen failed with switches {switches!r}: {exc}") from exc
    if len(nodes) - len(pts) >= max_added:
        raise ConfigError(f"tetgen's quality refinement did not end within {max_added} added points (mesh.min_ratio "
                          f"{min_ratio:g}, mesh.min_dihedral_deg {min_dihedral_deg:g}): raise min_ratio or lower "
                          f"min_dihedral_deg")
    nodes = np.asarray(nodes, dtype=np.float64)
    tets = np.asarray(elems, dtype=np.int64)[:, :4]
    used = np.unique(tets)
    if len(used) != len(nodes):  # drop unused points
        remap = np.full(len(nodes), -1)
        remap[used] = np.arange(len(used))
        nodes, tets = nodes[used], remap[tets]
    p = nodes[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    tets = np.where((vol < 0)[:, None], tets[:, [0, 2, 1, 3]], tets)
    faces = boundary_faces(tets)
    tag, uv, side = _tag_and_uv(params, nodes, faces, contour, seg, h)

    n = len(nodes)
    flip = [0, 2, 1]
    fold_nodes = [params.place(nodes, 0), params.place(nodes, 1)]
    return FoldMesh(
        nodes=np.concatenate(fold_nodes),
        tets=np.concatenate([tets[:, [0, 2, 1, 3]], tets + n]),
        tet_fold=np.repeat(np.array([0, 1], dtype=np.int8), len(tets)),
        faces=np.concatenate([faces[:, flip], faces + n]),
        face_tag=np.concatenate([tag, tag]),
        face_fold=np.repeat(np.array([0, 1], dtype=np.int8), len(faces)),
        uv=np.concatenate([uv, uv]),
        node_side=np.concatenate([side, side]),
    )
