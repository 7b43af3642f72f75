"""A synthetic high-speed video of two folds and a glottal slit, with exact truth.

Used by ``tests/test_gap.py``, ``tests/test_opticalflow.py`` and ``bench/bench_flow.py``.

Every frame is rendered by sampling an *analytic* band-limited texture (a sum of plane
waves) at the material coordinates of each sub-pixel sample: there is no image warping
(``cv2.remap``) anywhere, so the flow estimators are not tested against their own
interpolation (no inverse crime).

Motion (screen pixels, rows = lateral y, columns = longitudinal x), for material point
``a = (a_col, a_row)`` of fold ``i`` (0 above the midline row ``m``, 1 below):

* columns: ``col = a_col + tau(t) + eps(t) * (a_col - cx)`` (translation + stretch along x);
* rows: ``row = a_row -/+ delta_i(a_col, t) * exp(-|a_row - m| / lam) + drift(t)``, with the
  medial edge's excursion ``delta_i = delta_max_i * max(0, sin(2 pi f0 (t - lag_i))) *
  sin(pi (a_col - c0) / (c1 - c0))`` on the glottis ``c0 <= a_col <= c1`` (zero outside):
  the gap opens and closes every cycle, is closed half of it, and the lateral motion
  shears the surface along x and compresses it along y.

The medial edges' screen rows are analytic, so the true gap (per column, and its area),
and the true forward flow of every fold pixel (inverse map by Newton, then forward map)
are exact. Each pixel averages ``supersample`` x ``supersample`` point samples; with
``psf_sigma_px > 0`` the image is then blurred by a Gaussian (the optics) before the noise.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np


#: frames :meth:`SlitPhantom.render` made without an rng, by (the phantom's repr: every field, t), the least
#: recently used dropped beyond :data:`_FRAMES_MAX_BYTES`
_FRAMES: OrderedDict[tuple[str, float], np.ndarray] = OrderedDict()
_FRAMES_MAX_BYTES = 256 * 2**20


@dataclass
class SlitPhantom:
    height: int = 256
    width: int = 256
    fps: float = 10_000.0
    f0_hz: float = 150.0
    px_per_mm: float = 15.0
    midline_row: float = 127.3
    delta_max_px: tuple[float, float] = (13.0, 11.0)
    lag_s: tuple[float, float] = (0.0, 0.0004)
    lam_px: float = 45.0
    glottis_cols: tuple[float, float] = (14.0, 242.0)
    tau_amp_px: float = 2.0
    eps_amp: float = 0.01
    drift_amp_px: float = 1.0
    level_counts: float = 2400.0
    texture_contrast: float = 0.35
    gap_counts: float = 150.0
    noise_counts: float = 12.0
    psf_sigma_px: float = 0.0
    supersample: int = 2
    n_waves: int = 32
    seed: int = 0
    _waves: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        wavelength = rng.uniform(5.0, 28.0, self.n_waves)
        angle = rng.uniform(0, np.pi, self.n_waves)
        k = 2 * np.pi / wavelength
        self._waves = np.stack(
            [k * np.cos(angle), k * np.sin(angle), rng.uniform(0, 2 * np.pi, self.n_waves)], axis=1
        )

    # ---- motion -------------------------------------------------------------------
    def _tau(self, t):
        return self.tau_amp_px * np.sin(2 * np.pi * self.f0_hz * t + 0.3)

    def _eps(self, t):
        return self.eps_amp * np.sin(2 * np.pi * self.f0_hz * t + 1.1)

    def _drift(self, t):
        return self.drift_amp_px * np.sin(2 * np.pi * self.f0_hz * t + 2.0)

    def _delta(self, fold: int, a_col, t):
        c0, c1 = self.glottis_cols
        s = np.clip((a_col - c0) / (c1 - c0), 0.0, 1.0)
        g = max(0.0, np.sin(2 * np.pi * self.f0_hz * (t - self.lag_s[fold])))
        return self.delta_max_px[fold] * g * np.sin(np.pi * s)

    def _a_col(self, col, t):
        cx = 0.5 * (self.width - 1)
        return cx + (col - self._tau(t) - cx) / (1.0 + self._eps(t))

    def edges(self, t: float, col=None):
        """Screen rows of the two medial edges, per column: (edge0, edge1), each (W,)."""
        col = np.arange(self.width, dtype=float) if col is None else col
        a_col = self._a_col(col, t)
        m, d = self.midline_row, self._drift(t)
        return m - self._delta(0, a_col, t) + d, m + self._delta(1, a_col, t) + d

    def forward(self, fold: int, a_col, a_row, t):
        """Screen (col, row) of material point (a_col, a_row) of a fold at time t."""
        cx = 0.5 * (self.width - 1)
        col = a_col + self._tau(t) + self._eps(t) * (a_col - cx)
        sign = -1.0 if fold == 0 else 1.0
        decay = np.exp(-np.abs(a_row - self.midline_row) / self.lam_px)
        row = a_row + sign * self._delta(fold, a_col, t) * decay + self._drift(t)
        return col, row

    def inverse(self, fold: int, col, row, t):
        """Material (a_col, a_row) of the screen point (col, row) on a fold at time t."""
        a_col = self._a_col(col, t)
        m, lam = self.midline_row, self.lam_px
        sign = -1.0 if fold == 0 else 1.0
        delta = self._delta(fold, a_col, t)
        target = row - self._drift(t)
        a_row = target.copy()
        for _ in range(8):  # Newton on a_row + sign*delta*exp(-|a_row-m|/lam) = target
            a_row = np.minimum(a_row, m) if fold == 0 else np.maximum(a_row, m)
            e = np.exp(-np.abs(a_row - m) / lam)
            f = a_row + sign * delta * e - target
            fp = 1.0 + delta * e / lam
            a_row = a_row - f / fp
        return a_col, a_row

    # ---- truth --------------------------------------------------------------------
    def gap_mask(self, t: float) -> np.ndarray:
        """True gap: pixel centres between the medial edges, (H, W) bool."""
        e0, e1 = self.edges(t)
        rows = np.arange(self.height, dtype=float)[:, None]
        return (rows > e0[None, :]) & (rows < e1[None, :])

    def gap_area_px2(self, t: float) -> float:
        """Exact glottal area, px^2 (midpoint rule over columns on the smooth width)."""
        cols = np.arange(0, self.width, 0.125) - 0.5 + 0.0625
        e0, e1 = self.edges(t, cols)
        return float(np.sum(np.maximum(e1 - e0, 0.0)) * 0.125)

    def true_flow(self, t0: float, t1: float) -> np.ndarray:
        """Exact forward displacement of each fold pixel from t0 to t1, (H, W, 2) px
        as (d col, d row); NaN on gap pixels."""
        rows, cols = np.mgrid[0 : self.height, 0 : self.width].astype(float)
        e0, e1 = self.edges(t0)
        out = np.full((self.height, self.width, 2), np.nan)
        for fold, sel in ((0, rows <= e0[None, :]), (1, rows >= e1[None, :])):
            a_col, a_row = self.inverse(fold, cols[sel], rows[sel], t0)
            c, r = self.forward(fold, a_col, a_row, t1)
            out[sel, 0] = c - cols[sel]
            out[sel, 1] = r - rows[sel]
        return out

    # ---- rendering ----------------------------------------------------------------
    def _texture(self, fold: int, a_col, a_row):
        """Sum of the plane waves at material points (a_col, a_row): the phases as one matrix product (BLAS),
        the cosines in place (1.6 times faster than broadcasting; equal to 4e-13 of a texture of unit size)."""
        w = self._waves
        points = np.stack([a_col, a_row, np.ones_like(a_col)], axis=-1)
        ph = points @ np.stack([w[:, 0], w[:, 1], w[:, 2] + 1.7 * fold])
        np.cos(ph, out=ph)
        return ph.sum(axis=-1) * np.sqrt(2.0 / len(w))

    def _shade(self, a_row):
        dist = np.abs(a_row - self.midline_row)  # material distance from the medial edge
        lateral = 0.8 + 0.2 * np.cos(np.pi * np.clip(dist / 110.0, 0, 1))
        edge = 1.0 - 0.35 * np.exp(-dist / 1.2)
        return lateral * edge

    def render(self, t: float, rng: np.random.Generator | None = None) -> np.ndarray:
        """One 12-bit frame at time t, (H, W) uint16 counts (a fresh array).  Without ``rng`` the frame is
        a function of the phantom's fields and t alone (its noise seeded by both), so it is rendered once per
        test process and copied after (:data:`_FRAMES`): a third of the gap and flow tests' frames were
        rendered again by another test of the same file, 0.17 s each at the default size."""
        if rng is not None:
            return self._render(t, rng)
        key = (repr(self), float(t))
        frame = _FRAMES.pop(key, None)
        if frame is None:
            frame = self._render(t, None)
            while _FRAMES and sum(f.nbytes for f in _FRAMES.values()) + frame.nbytes > _FRAMES_MAX_BYTES:
                _FRAMES.pop(next(iter(_FRAMES)))
        _FRAMES[key] = frame                               # the most recent last
        return frame.copy()

    def _render(self, t: float, rng: np.random.Generator | None) -> np.ndarray:
        s = self.supersample
        offs = (np.arange(s) + 0.5) / s - 0.5
        H, W = self.height, self.width
        acc = np.zeros((H, W))
        rows0, cols0 = np.mgrid[0:H, 0:W].astype(float)
        for dr in offs:
            for dc in offs:
                rows, cols = rows0 + dr, cols0 + dc
                e0, e1 = self.edges(t, cols[0])
                val = np.full((H, W), self.gap_counts)
                for fold, sel in ((0, rows <= e0[None, :]), (1, rows >= e1[None, :])):
                    a_col, a_row = self.inverse(fold, cols[sel], rows[sel], t)
                    tex = self._texture(fold, a_col, a_row)
                    val[sel] = self.level_counts * (1 + self.texture_contrast * np.tanh(tex)) * self._shade(a_row)
                acc += val
        acc /= s * s
        if self.psf_sigma_px > 0:  # optics blur (Gaussian) before the sensor noise
            from scipy.ndimage import gaussian_filter

            acc = gaussian_filter(acc, self.psf_sigma_px, mode="nearest")
        if rng is None:
            rng = np.random.default_rng(self.seed + 1 + int(round(t * self.fps)))
        acc = acc + rng.normal(0.0, self.noise_counts, acc.shape)
        return np.clip(np.rint(acc), 0, 4095).astype(np.uint16)

    def frame_time(self, k: int) -> float:
        return k / self.fps

    def video(self, n_frames: int, first: int = 0) -> np.ndarray:
        return np.stack([self.render(self.frame_time(first + k)) for k in range(n_frames)])
