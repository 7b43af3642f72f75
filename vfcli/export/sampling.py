"""Sampling the model and the video at screen points and along lines (numpy in, numpy out)."""
from __future__ import annotations

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.camera.raster import interpolate, rasterize
from vfcli.model.mesh import SIDE_SUPERIOR, FoldMesh

FOLD_NAMES = ("left", "right")  # /mesh tet_fold: 0 left, 1 right


def nearest_frames(frame_time: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(T,) index of the frame (frame_time (F,) s, increasing) nearest each time (T,) s."""
    i = np.clip(np.searchsorted(frame_time, times), 1, len(frame_time) - 1)
    return np.where(np.abs(frame_time[i - 1] - times) <= np.abs(frame_time[i] - times), i - 1, i)


def surface_velocity_at(camera: Camera, mesh: FoldMesh, displacements: np.ndarray, times: np.ndarray,
                        pixels: np.ndarray) -> np.ndarray:
    """Velocity (model frame) of the model's surface point seen at each pixel.

    displacements : (T, N, 3) mm at ``times`` (T,) s; pixels : (P, 2) (col, row).
    Returns (T, P, 3) mm/s (central differences in time), NaN where the surface does not cover the pixel.
    """
    d = np.asarray(displacements, dtype=float)
    vel = np.gradient(d, np.asarray(times, float), axis=0)
    px = np.round(np.asarray(pixels, float)).astype(int)
    inside = (px[:, 0] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    out = np.full((len(times), len(px), 3), np.nan)
    for k in range(len(times)):
        img = interpolate(rasterize(camera, mesh.nodes + d[k], mesh.faces), vel[k])
        out[k, inside] = img[px[inside, 1], px[inside, 0]]
    return out


def screen_points(camera: Camera, mesh: FoldMesh) -> tuple[np.ndarray, list[str]]:
    """One screen point per fold: the superior-surface node nearest (u, v) = (0.5, 0.5); (P, 2) (col, row) and labels."""
    pts, labels = [], []
    for k in (0, 1):
        nodes = np.intersect1d(mesh.fold_nodes(k), np.flatnonzero(mesh.node_side == SIDE_SUPERIOR))
        if nodes.size == 0:
            continue
        n = nodes[np.argmin(np.sum((mesh.uv[nodes] - 0.5) ** 2, axis=1))]
        p = camera.project(mesh.nodes[n])
        pts.append(p)
        labels.append(f"{FOLD_NAMES[k]} fold, mid superior surface (px {p[0]:.0f}, {p[1]:.0f})")
    return np.array(pts), labels


def glottis_lines(gap_counts: np.ndarray, px_per_mm: float, left_px: np.ndarray | None = None,
                  fractions: tuple[float, ...] = (0.25, 0.5, 0.75), half_width_mm: float = 2.0,
                  n_samples: int = 96) -> tuple[np.ndarray | None, list[str]]:
    """Lines across the glottis for a kymogram.

    gap_counts : (H, W) how often each pixel was in the gap; its weighted principal axis is the glottis.
    left_px : (col, row) of the left fold, to orient each line from the left fold to the right one.
    Returns (L, S, 2) (col, row) sample points (None when no gap was seen) and a label per line.
    """
    rows, cols = np.nonzero(gap_counts)
    if rows.size < 3:
        return None, []
    w = gap_counts[rows, cols].astype(float)
    xy = np.column_stack([cols, rows]).astype(float)
    c = np.average(xy, axis=0, weights=w)
    axis = np.linalg.eigh(np.cov((xy - c).T, aweights=w))[1][:, -1]
    along = (xy - c) @ axis
    normal = np.array([-axis[1], axis[0]])
    if left_px is not None and (np.asarray(left_px, float) - c) @ normal > 0:
        normal = -normal
    s = np.linspace(-half_width_mm, half_width_mm, n_samples) * px_per_mm
    lines = [c + axis * (along.min() + f * (along.max() - along.min())) + s[:, None] * normal for f in fractions]
    return np.array(lines), [f"{int(round(100 * f))} % along the glottis" for f in fractions]


def sample_lines(frames: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """(L, F, S) grey values of frames (F, H, W) at the line points (L, S, 2) (col, row), bilinear."""
    from scipy.ndimage import map_coordinates

    f = np.asarray(frames, dtype=float)
    out = np.zeros((len(lines), len(f), lines.shape[1]))
    for j, pts in enumerate(lines):
        for k in range(len(f)):
            out[j, k] = map_coordinates(f[k], [pts[:, 1], pts[:, 0]], order=1, mode="nearest")
    return out
