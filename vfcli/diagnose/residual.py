"""The residual of a fitted run: measured minus simulated, per pixel and per silhouette crossing.

Built from a :class:`vfcli.diagnose.candidate.Baseline` (the run's problem at its fitted
control values, rasters frozen there):

* **motion** (F, H, W, 3), mm/s: the measured velocity minus the simulated one on the pixels
  both see, the measured velocity where only the recording sees tissue (the model shows
  none there; the objective's second case), NaN elsewhere; components in model axes.
* **gap** (F, n_rays, 2), mm: the measured silhouette minus the simulated one on each ray and
  fold side of the objective's ray set, signed so that positive means the measured edge is
  more medial (towards the glottis' midline) than the model's.

Each pixel gets the region (:mod:`vfcli.diagnose.regions`) of the material point the model
shows there most often over the window (the vertex with the largest interpolation weight);
each ray and side the region of its fold and length band.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from vfcli.diagnose.regions import N_REGIONS, thirds, vertex_fold, vertex_regions
from vfcli.inverse.terms.gap import gap_rows


@dataclass(frozen=True)
class WindowResidual:
    """The residual of a fitted window (module docstring).

    motion : (F, H, W, 3) mm/s.  gap : (F, n_rays, 2) mm.
    pixel_region : (H, W) motion region of each pixel, -1 none.
    gap_region : (n_rays, 2) gap region (fold * 3 + length band) of each ray and side, -1 none.
    pixel_stride : s: the motion is compared on every s-th pixel of every s-th row only (NaN elsewhere;
        ``Measurement.pixel_stride``).
    """

    motion: np.ndarray
    gap: np.ndarray
    pixel_region: np.ndarray
    gap_region: np.ndarray
    pixel_stride: int = 1


def region_means(values: np.ndarray, labels: np.ndarray, n_regions: int) -> np.ndarray:
    """(F, R, C) mean over the labelled pixels of each region per frame, NaN where a region has none.

    values : (F, ..., C) with NaN where not valid.  labels : (...) region index per pixel, -1 none.

    One sparse (R, P) indicator times the (P, F * C) pixel columns: a stacked dense ``(F, C, P) @ (P, R)``
    took 0.10 s for 100 frames of 160 x 160 px on a quiet machine and 13.5 s beside two busy processes (BLAS
    threads on many small products); this takes 0.06-0.2 s (bench/bench_diagnose_kernels.py).
    """
    v = np.asarray(values, dtype=float)
    f, c = v.shape[0], v.shape[-1]
    flat = v.reshape(f, -1, c)
    lab = np.asarray(labels).reshape(-1)
    keep = np.flatnonzero(lab >= 0)
    flat, lab = flat[:, keep], lab[keep]
    ok = np.isfinite(flat)
    indicator = sparse.csr_matrix((np.ones(lab.size), (lab, np.arange(lab.size))), shape=(n_regions, lab.size))

    def per_region(a: np.ndarray) -> np.ndarray:                      # (F, P, C) -> (F, R, C) sums
        columns = np.ascontiguousarray(a.transpose(1, 0, 2)).reshape(lab.size, f * c)
        return (indicator @ columns).reshape(n_regions, f, c).transpose(1, 0, 2)

    sums, counts = per_region(np.where(ok, flat, 0.0)), per_region(ok.astype(float))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / counts, np.nan)


def pixel_regions(baseline, n_regions: int = N_REGIONS) -> np.ndarray:
    """(H, W) the motion region the model shows most often at each pixel over the window, -1 never."""
    p = baseline.problem
    mesh = p.mesh
    vreg = vertex_regions(mesh.uv, vertex_fold(len(mesh.nodes), mesh.tets, mesh.tet_fold))
    n_pix = int(np.prod(p.camera.shape))
    keys = []                                         # pixel * (n_regions + 1) + region, every frame's
    for fr in baseline.frames:
        m = fr.m_both.tocsr()
        if m.shape[0] == 0:
            continue
        # the vertex of largest weight in each row: sort the entries by (row, -weight), take each row's first
        row = np.repeat(np.arange(m.shape[0]), np.diff(m.indptr))
        order = np.lexsort((-m.data, row))
        first = order[m.indptr[:-1][np.diff(m.indptr) > 0]]
        rows_with = np.flatnonzero(np.diff(m.indptr) > 0)
        reg = vreg[m.indices[first]]
        keys.append(fr.pix_both[rows_with] * (n_regions + 1) + np.where(reg >= 0, reg, n_regions))
    # one count at the end: a count per frame, each the size of the image times the regions, was most of the time
    flat = np.concatenate(keys) if keys else np.zeros(0, int)
    counts = np.bincount(flat, minlength=n_pix * (n_regions + 1)).reshape(n_pix, n_regions + 1)
    best = np.argmax(counts[:, :n_regions], axis=1)
    best[counts[:, :n_regions].sum(axis=1) == 0] = -1
    return best.reshape(p.camera.shape)


def gap_regions(problem) -> np.ndarray:
    """(n_rays_img, 2) gap region of each image ray and side (low, high lateral px), -1 off the ray set."""
    mesh = problem.mesh
    scr = problem.camera.project(mesh.nodes)
    ok = np.all(np.isfinite(mesh.uv), axis=1)
    out = np.full((problem.n_rays_img, 2), -1, int)
    if ok.sum() < 2 or len(problem.rays) == 0:
        return out
    ray = scr[ok, problem.ray_comp]
    a = np.vstack([np.ones(ok.sum()), ray]).T
    coef = np.linalg.lstsq(a, mesh.uv[ok, 0], rcond=None)[0]               # u ~ c0 + c1 * ray coordinate
    band = thirds(coef[0] + coef[1] * problem.rays.astype(float))
    for side, fold in enumerate(problem.fold_order):
        out[problem.rays, side] = fold * 3 + band
    return out


def window_residual(baseline) -> WindowResidual:
    """The residual of the baseline's window (module docstring)."""
    p = baseline.problem
    motion = -p.motion_residuals(baseline.x, baseline.frames)
    gap = np.full((p.n_frames, p.n_rays_img, 2), np.nan)
    none = np.zeros((len(p.mesh.nodes), 3, 0))
    for f, fr in enumerate(baseline.frames):
        # simulated minus measured px per crossing, the sides' rays in order (as the gap term has them)
        _, dist = gap_rows(p, p.mesh.nodes + baseline.displacements[f], fr.sil, none)
        at = 0
        for side, (rays, _, _) in enumerate(fr.sil):
            sign = 1.0 if side == 0 else -1.0          # medial is +px for the low side, -px for the high one
            gap[f, rays, side] = -sign * dist[at:at + rays.size] / p.camera.px_per_mm
            at += rays.size
    return WindowResidual(motion, gap, pixel_regions(baseline), gap_regions(p), p.meas.pixel_stride)


def grid_filled(image: np.ndarray, stride: int) -> np.ndarray:
    """(H, W, ...) each ``stride`` x ``stride`` block of ``image`` set to its top-left (grid) pixel's value: a map
    of a residual compared on every s-th pixel of every s-th row, shown whole.  ``stride`` 1: ``image`` itself."""
    if stride <= 1:
        return image
    h, w = image.shape[:2]
    return np.repeat(np.repeat(image[::stride, ::stride], stride, axis=0), stride, axis=1)[:h, :w]


def medial_silhouettes(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(F, n_rays, 2) measured silhouettes signed as :attr:`WindowResidual.gap` (medial positive), px."""
    return np.stack([np.asarray(lo, float), -np.asarray(hi, float)], axis=-1)


def rms_residual(motion: np.ndarray) -> np.ndarray:
    """(H, W, 3) RMS over the frames of the motion residual (F, H, W, 3), mm/s; NaN where never compared."""
    m = np.asarray(motion, dtype=float)
    n = np.sum(np.isfinite(m), axis=0)
    ss = np.nansum(m * m, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(ss / np.maximum(n, 1)), np.nan)
