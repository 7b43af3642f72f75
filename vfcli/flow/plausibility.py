"""Is a product plausible? Pure checks of what the LDV and field stages produce (issue 15).

* :func:`points_on_image`: the vibrometer points' screen positions lie on the video's frames
  (a scan read in the wrong length unit lands thousands of px away, and the thin-plate
  spline then extrapolates a "valid" field from nothing).
* :func:`pressure_velocity_bound`: the largest surface velocity a pressure swing can drive,
  ``max |p| / (rho c)`` (the momentum flux of a wave of speed ``c`` in tissue of density
  ``rho``), with the slowest documented mucosal wave (0.5 m/s) and a tissue density of
  1000 kg/m^3: 2 m/s per kPa, above the in-vivo closing velocities (0.3-1.6 m/s at about
  1 kPa; docs/physical-setup).
* :class:`ContrastAccumulator` and :func:`points_on_folds`: the vibrometer points lie on the folds,
  not on the fixture, the silicone block around the folds or the background. The folds are what
  moves in the video: their textured surface slides past the pixels and the gap opens and closes
  at the phonation frequency, while the fixture and the block are static (their pixels show noise
  only). A point is on the folds when moving pixels lie within :data:`FOLD_MARGIN_MM` of it.
* :func:`gap_length_share`: how much of the glottis in view the gap was found on. Folds clamped at
  both ends open over their middle (``A sin(pi s / L)``): the gap seen over a recording spans about
  three quarters of the length L (its thin ends stay below detection). A gap found over less than
  :data:`GAP_LENGTH_WARN` of the length in view means the slit's narrow parts were not resolved
  (a slit one or two pixels wide under sharp optics stays above the gap threshold), or an opening
  that is not the whole glottis (a posterior chink): the glottal area and the gap term then cover
  only that part. The other way, a gap longer than the folds (:data:`GAP_LONGER_WARN`) is impossible
  with both ends clamped: the image scale (camera.px_per_mm) or the folds' length is wrong.
* :func:`area_f0`: the glottal area's own fundamental frequency on the video's time base. The folds
  open and close once per cycle of the pressure recorded beside the video, so the two frequencies are
  one; a different one means the video's time base (its frame rate) is wrong. On 28 phantom recordings
  (default and widened panels, 2-6 cycles each; bench/bench_plausibility.py) the two agreed to 0.4 %; a frame
  rate 5 % high gave 1.051, one twice the true rate 2.001.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from vfcli.camera.pose import gap_axis

#: Tissue (or silicone) density used by the velocity bound, kg/m^3.
TISSUE_DENSITY_KG_M3 = 1000.0
#: Slowest mucosal wave speed, m/s (excised larynges: 0.5-2 m/s).
SLOWEST_WAVE_M_S = 0.5
#: "Far beyond": speeds over this multiple of :func:`pressure_velocity_bound` are flagged (a widened
#: phantom's flow reached 1.06 x the bound at its 99th percentile, a mis-scaled vibrometer 10-1000 x).
FAR_BEYOND = 2.0

#: Frames per block of the temporal contrast at most: 1.6 ms at 10 kHz, a fifth of a 125 Hz cycle.  A block
#: must be short against the phonation cycle, so that its mean keeps the cycle's motion and averages the noise:
#: :func:`contrast_block` takes a fifth of the cycle when that is shorter (at 6 kHz and 300 Hz, 20 frames per
#: cycle, blocks of 16 averaged the motion away and every vibrometer point read as off the folds).
CONTRAST_BLOCK = 16
#: Frames per block at least (a static pixel's contrast 1 / sqrt(3) against the folds' several times that).
MIN_CONTRAST_BLOCK = 4
#: A pixel moves when its temporal contrast exceeds this multiple of a static pixel's expected
#: contrast, ``1 / sqrt(block - 1)`` (white noise only): measured on phantoms (blocks of 16), static
#: pixels (fixture, silicone block) lie at 0.6-0.9 of that expectation (1st-10th percentile 0.15-0.22
#: for an expected 0.26), the folds at 3-7 times it (median 0.9-1.8).
MOVING_FACTOR = 2.0
#: A point is on the folds when a moving pixel lies within this distance: the lab's scan grid
#: stays about 0.5 mm inside the folds' clamped lateral edges, where they hardly move.
FOLD_MARGIN_MM = 0.5
#: Share of the points off the folds above which `fields` warns, and above which it fails.
OFF_FOLD_WARN = 0.1
OFF_FOLD_FAIL = 0.5
#: Share of the glottis length in view below which the gap's extent over the recording is doubtful
#: (`flow` warns): half, against the three quarters a clamped fold's opening spans (module doc).
GAP_LENGTH_WARN = 0.5
#: A gap's extent over the recording above this multiple of the folds' length, plus :data:`GAP_END_PX` for
#: the pixel grid and the blur at each end, cannot be the glottis of folds clamped at both ends (`flow`
#: warns: the scale or the length is wrong). On 28 phantom recordings (default and widened panels, blur 0.3-2.8 px;
#: bench/bench_plausibility.py) the extent was 0.64-0.85 of the length; a px_per_mm half the true one gave 1.57 and
#: 1.70.
GAP_LONGER_WARN = 1.1
GAP_END_PX = 2.0
#: The superior surface moves vertically and horizontally by the same order (the
#: vibrometer's vertical against the optical flow's horizontal velocity, RMS over the valid pixels, was 2.8-3.5
#: on 28 phantom recordings, 1.5-6.1 with a wrong scale or frame rate); a ratio beyond this factor either way is a
#: unit (a velocity in m/s read as mm/s gave 0.003), not the folds: `flow` warns.
VELOCITY_ORDER = 30.0


def points_on_image(points_px: np.ndarray, shape: tuple[int, int], margin_px: float = 0.5) -> np.ndarray:
    """Which screen points (P, 2) (col, row) px lie on an (H, W) frame (pixel edges +- ``margin_px``).

    Returns
    -------
    (P,) bool
    """
    p = np.asarray(points_px, float).reshape(-1, 2)
    h, w = shape
    return (np.isfinite(p).all(axis=1) & (p[:, 0] >= -margin_px) & (p[:, 0] <= w - 1 + margin_px)
            & (p[:, 1] >= -margin_px) & (p[:, 1] <= h - 1 + margin_px))


#: What a scan partly off the frames asks of the user (ingest-ldv and fields say it alike).
SCAN_FRAME_ADVICE = ("check ingest_ldv.length_unit (the unit of the file's coordinates), ldv_frame.affine (scan to camera "
                     "mm) and camera.px_per_mm")


def scan_beyond_frames(points_px: np.ndarray, shape: tuple[int, int], px_per_mm: float) -> str:
    """The words for scan points partly off the frames: where the scan lies against the frames, in mm and px.

    A camera zoomed in closer than the vibrometer scanned sees only part of the scan (the widened phantoms'
    fields of view are 0.65-1.3 glottis lengths, the scan covers both folds): points off the frames are then
    expected, and advice to check the length unit would mislead. A scan in the wrong unit, or moved by a wrong
    affine, lies far off or shrunk to a few pixels. The sizes side by side tell the two apart at a glance, so
    the words give them and the advice for the second case; they decide nothing (no threshold).

    Parameters
    ----------
    points_px : (P, 2) (col, row) px of the scan points on the stored frames (NaN: none).
    shape : (H, W) of the frames, px.
    px_per_mm : image scale, px/mm.

    Returns
    -------
    str, e.g. (widened panel seed 2002) "the scan spans 16.8 x 18.6 mm (columns -89..308, rows -114..325 px), the
    frames 10.8 x 10.8 mm (256 x 256 px): expected where the camera sees only part of the scanned folds; otherwise
    check ..."
    """
    p = np.asarray(points_px, float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    h, w = shape
    s = float(px_per_mm)
    frames = f"the frames {w / s:.1f} x {h / s:.1f} mm ({w} x {h} px)"
    if len(p) == 0:
        return f"{frames}; {SCAN_FRAME_ADVICE}"
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = (hi - lo) / s
    return (f"the scan spans {span[0]:.3g} x {span[1]:.3g} mm (columns {lo[0]:.0f}..{hi[0]:.0f}, rows "
            f"{lo[1]:.0f}..{hi[1]:.0f} px), {frames}: expected where the camera sees only part of the scanned "
            f"folds; otherwise {SCAN_FRAME_ADVICE}")


def pressure_velocity_bound(pressure_pa: np.ndarray) -> float:
    """The largest surface velocity the pressure can drive, mm/s: ``max |p| / (rho c)`` (module doc).

    Parameters
    ----------
    pressure_pa : (S,) float, Pa (subglottal, as recorded: mean included)

    Returns
    -------
    float
        mm/s; NaN when no finite sample.
    """
    p = np.asarray(pressure_pa, float)
    p = p[np.isfinite(p)]
    if p.size == 0:
        return float("nan")
    return float(np.max(np.abs(p)) / (TISSUE_DENSITY_KG_M3 * SLOWEST_WAVE_M_S) * 1e3)


class ContrastAccumulator:
    """Temporal contrast of each pixel over a video, fed block by block (memory O(H W)).

    ``add(frames)`` takes consecutive frames (k, H, W) in any blocking; they are regrouped into
    blocks of ``block`` frames (a trailing partial block is ignored). :meth:`contrast` is
    ``sqrt(variance of the block means / mean variance within a block)``, (H, W): about
    ``1 / sqrt(block - 1)`` where a pixel shows white noise only, far above it where the image
    changes over a phonation cycle (the block means follow the cycle, the noise averages out).
    """

    def __init__(self, block: int = CONTRAST_BLOCK) -> None:
        if block < 2:
            raise ValueError(f"contrast block must hold at least 2 frames, got {block}")
        self.block = int(block)
        self._pending: np.ndarray | None = None
        self._n = 0
        self._sum = self._sum2 = self._within = None

    def add(self, frames: np.ndarray) -> None:
        """Feed the next frames (k, H, W), counts (any real type)."""
        f = np.asarray(frames, dtype=np.float64)
        if self._pending is not None and len(self._pending):
            f = np.concatenate([self._pending, f])
        n_full = len(f) // self.block * self.block
        self._pending = f[n_full:]
        if n_full == 0:
            return
        blocks = f[:n_full].reshape(-1, self.block, *f.shape[1:])
        means = blocks.mean(axis=1)
        within = blocks.var(axis=1, ddof=1).sum(axis=0)
        if self._sum is None:
            self._sum, self._sum2, self._within = np.zeros(f.shape[1:]), np.zeros(f.shape[1:]), np.zeros(f.shape[1:])
        self._sum += means.sum(axis=0)
        self._sum2 += (means ** 2).sum(axis=0)
        self._within += within
        self._n += len(blocks)

    @property
    def n_blocks(self) -> int:
        """Whole blocks fed so far."""
        return self._n

    def contrast(self) -> np.ndarray:
        """(H, W) temporal contrast (see the class doc); needs at least 2 blocks (ValueError)."""
        if self._n < 2:
            raise ValueError(f"temporal contrast needs at least 2 blocks of {self.block} frames, got {self._n}")
        mean = self._sum / self._n
        between = np.maximum(self._sum2 / self._n - mean ** 2, 0.0) * self._n / (self._n - 1)
        within = self._within / self._n
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(within > 0, np.sqrt(between / within), np.where(between > 0, np.inf, 0.0))


def contrast_block(frames_per_cycle: float) -> int:
    """Frames per block of the temporal contrast for a video with ``frames_per_cycle`` frames per phonation
    cycle: a fifth of the cycle, within :data:`MIN_CONTRAST_BLOCK` .. :data:`CONTRAST_BLOCK` (the latter when
    the cycle is not known, NaN)."""
    if not np.isfinite(frames_per_cycle) or frames_per_cycle <= 0:
        return CONTRAST_BLOCK
    return int(np.clip(np.floor(frames_per_cycle / 5.0), MIN_CONTRAST_BLOCK, CONTRAST_BLOCK))


def moving_pixels(contrast: np.ndarray, block: int = CONTRAST_BLOCK) -> np.ndarray:
    """Pixels whose temporal contrast (H, W) exceeds :data:`MOVING_FACTOR` times a static pixel's
    ``1 / sqrt(block - 1)``; (H, W) bool."""
    return np.asarray(contrast) > MOVING_FACTOR / np.sqrt(block - 1)


def points_on_folds(points_px: np.ndarray, moving: np.ndarray, margin_px: float) -> np.ndarray:
    """Which screen points (P, 2) (col, row) px have a moving pixel (H, W) bool within ``margin_px``.

    Points off the frame (or not finite) are False. The distance is from the point to the nearest
    moving pixel centre (Euclidean distance transform).

    Returns
    -------
    (P,) bool
    """
    from scipy import ndimage

    p = np.asarray(points_px, float).reshape(-1, 2)
    mv = np.asarray(moving, bool)
    h, w = mv.shape
    on = points_on_image(p, (h, w))
    if not mv.any():
        return np.zeros(len(p), bool)
    dist = ndimage.distance_transform_edt(~mv)
    out = np.zeros(len(p), bool)
    ij = np.rint(p[on]).astype(int)
    ij[:, 0] = np.clip(ij[:, 0], 0, w - 1)
    ij[:, 1] = np.clip(ij[:, 1], 0, h - 1)
    out[on] = dist[ij[:, 1], ij[:, 0]] <= margin_px
    return out


def points_on_folds_of_video(chunks: Iterable[np.ndarray], points_px: np.ndarray, px_per_mm: float,
                             block: int = CONTRAST_BLOCK) -> np.ndarray | None:
    """Which screen points (P, 2) (col, row) px lie on the folds of a video fed as consecutive chunks
    of frames (k, H, W) counts: moving pixels (:class:`ContrastAccumulator` with blocks of ``block`` frames,
    :func:`contrast_block`; :func:`moving_pixels`) within :data:`FOLD_MARGIN_MM` (:func:`points_on_folds`).

    Returns
    -------
    (P,) bool, or None when the video holds fewer than 2 blocks of ``block`` frames.
    """
    acc = ContrastAccumulator(block)
    for chunk in chunks:
        acc.add(chunk)
    if acc.n_blocks < 2:
        return None
    return points_on_folds(points_px, moving_pixels(acc.contrast(), acc.block), FOLD_MARGIN_MM * float(px_per_mm))


def image_chord_px(centre_px: np.ndarray, angle_deg: float, shape: tuple[int, int]) -> float:
    """Length (px) of the line through ``centre_px`` (col, row) at ``angle_deg`` inside an (H, W) frame
    (between pixel centres 0 and W - 1, H - 1); 0 when the centre lies outside."""
    c = np.asarray(centre_px, float)
    h, w = shape
    if not (0 <= c[0] <= w - 1 and 0 <= c[1] <= h - 1):
        return 0.0
    e = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    lo, hi = -np.inf, np.inf
    for k, limit in ((0, w - 1), (1, h - 1)):
        if abs(e[k]) > 1e-12:
            a, b = sorted(((0 - c[k]) / e[k], (limit - c[k]) / e[k]))
            lo, hi = max(lo, a), min(hi, b)
    return float(hi - lo)


def gap_length_share(gap_counts: np.ndarray, length_px: float) -> tuple[float, float]:
    """The gap's extent along its principal axis over a recording, and the glottis length in view, px.

    Parameters
    ----------
    gap_counts : (H, W) number of frames in which each pixel is gap (at least 3 gap pixels).
    length_px : the folds' length L times the image scale, px.

    Returns
    -------
    found_px : extent of the gap pixels along the axis (first to last pixel centre, plus one pixel).
    in_view_px : ``min(length_px, chord)``, the chord of the frame along the axis through the gap's centre.
    """
    ax = gap_axis(gap_counts)
    lo, hi = ax.extent_px
    chord = image_chord_px(ax.centre_px, ax.rotation_deg, np.asarray(gap_counts).shape)
    return float(hi - lo + 1.0), float(min(length_px, chord + 1.0))


def area_f0(area_mm2: np.ndarray, fps_hz: float, f_range: tuple[float, float], f0_hz: float) -> float | None:
    """The glottal area's fundamental frequency on the video's time base, Hz (module doc), or None where it
    cannot be told: a video of fewer than 2 cycles, counted at ``f0_hz`` (the pressure's) or, where the glottis
    closes, as openings (a time base too fast shortens the first count: a 0.03 s video at twice its frame rate
    holds 1.8 cycles of the pressure but 3.6 openings), or an area that :func:`vfcli.sync.f0.estimate_f0` finds
    not periodic.

    area_mm2 : (n,) glottal area of each frame.  fps_hz : the video's frame rate.  f_range : search range, Hz.
    """
    from vfcli.errors import InputDataError
    from vfcli.sync.f0 import estimate_f0

    a = np.asarray(area_mm2, dtype=float)
    if not (np.isfinite(f0_hz) and f0_hz > 0) or not np.ptp(a) > 0:
        return None
    is_open = np.concatenate([[False], a > 0])
    openings = int(np.count_nonzero(is_open[1:] & ~is_open[:-1]))          # runs of open frames
    if max(len(a) / fps_hz * f0_hz, openings - 1) < 2.0:
        return None
    try:
        return float(estimate_f0(a, fps_hz, f_range, source="glottal area"))
    except InputDataError:
        return None
