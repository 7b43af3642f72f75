"""The pose of the fold model in the image, from the glottal gap and the motion seen over the recording.

The camera's scale (px/mm) comes from a calibration target, but its in-plane rotation and
the position of the model origin are usually unknown. The glottal midline (model y = 0) is
the principal axis of the gap pixels over the recording (any in-plane angle; the sign of the
axis is the one nearest a prior rotation). Along it, the folds are clamped at both ends
(x = 0 and x = L), so they move symmetrically about mid-length: the amplitude of the surface velocity along
the glottis is mirror-symmetric about it (:func:`motion_amplitude`, :func:`symmetry_mid`), over the whole
superior surface in view. Mid-length is placed there, within what the gap's extent allows: the glottis covers the
visible gap, whichever ends the image cuts (the gap may be found over only part of it). The gap's extent itself is
not taken as symmetric: its ends are where the opening first exceeds the folds' contact, where the opening
grows slowly along the glottis, so one a little wider toward one end moves them by millimetres. Without the
motion (or when it cannot say): with both ends in view, the midpoint of the visible gap's extent (however often
each part of it was found open); with one end cut, the opening's sine envelope (:func:`envelope_start`); with
both cut, the position along the glottis is unmeasured: the visible centre is used and a warning says so.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vfcli.errors import InputDataError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GapAxis:
    """Where the gap lies in the image, from the gap counts.

    Attributes
    ----------
    rotation_deg : float
        In-plane angle of the model x axis (the gap's principal axis), degrees, in
        (prior - 90, prior + 90].
    centre_px : (2,) float
        Count-weighted centre (col, row) of the gap pixels, px.
    extent_px : (float, float)
        Smallest and largest position of a gap pixel along the axis from ``centre_px``, px.
    cut : (bool, bool)
        The image border cuts the gap at that (low, high) end.
    """

    rotation_deg: float
    centre_px: np.ndarray
    extent_px: tuple[float, float]
    cut: tuple[bool, bool]


#: The gap is a slit: a gap pixel lies within this multiple of the count-weighted median lateral distance of the
#: gap pixels from its axis, or within TRIM_MIN_PX; pixels beyond (a dark streak of the detection beyond the
#: glottis's end: widened seed 1100 turned the axis by 2.4 deg) are left out and the axis refitted, at most
#: MAX_TRIMS times. On the true gaps of 44 widened videos (docs/benchmarks.md, "A gap never resolved") this leaves
#: out nothing on 42, and 0.6 and 0.3 % of the counts on the other two.
TRIM_FACTOR = 5.0
TRIM_MIN_PX = 2.0
MAX_TRIMS = 5


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The weighted median of values (n,) with weights (n,) >= 0."""
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def _principal_axis(pts: np.ndarray, wgt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(count-weighted centre (2,), unit principal direction (2,)) of points (n, 2) with weights (n,)."""
    centre = (pts * wgt[:, None]).sum(axis=0) / wgt.sum()
    d = pts - centre
    evals, evecs = np.linalg.eigh((d * wgt[:, None]).T @ d / wgt.sum())
    return centre, evecs[:, int(np.argmax(evals))]


def gap_axis(gap_counts: np.ndarray, prior_deg: float = 0.0, end_px: float = 2.0) -> GapAxis:
    """The principal axis of the gap pixels (H, W) counts and whether the border cuts its ends.

    The axis is refitted without the pixels farther from it than a slit's width allows
    (:data:`TRIM_FACTOR`): a dark streak the detection adds beyond the glottis's end would turn it.

    Parameters
    ----------
    gap_counts : (H, W) float
        Number of frames in which each pixel is gap.
    prior_deg : float
        Rotation the axis's sign is chosen nearest to, degrees.
    end_px : float
        A border pixel of the gap within this distance (px, along the axis) of an end cuts it.
    """
    counts = np.asarray(gap_counts, float)
    rows, cols = np.nonzero(counts > 0)
    if rows.size < 3:
        raise InputDataError("the glottal gap never opens in the selected frames: cannot locate the folds; "
                             "set camera.pose = 'config' with camera.rotation_deg and camera.offset_px")
    wgt = counts[rows, cols]
    pts = np.stack([cols, rows], axis=1).astype(float)
    keep = np.ones(len(pts), bool)
    for _ in range(MAX_TRIMS):
        centre, e = _principal_axis(pts[keep], wgt[keep])
        lateral = np.abs((pts - centre) @ np.array([-e[1], e[0]]))
        again = lateral <= max(TRIM_FACTOR * _weighted_median(lateral[keep], wgt[keep]), TRIM_MIN_PX)
        if np.array_equal(again, keep) or again.sum() < 3:
            break
        keep = again
    rows, cols, pts = rows[keep], cols[keep], pts[keep]
    centre, e = _principal_axis(pts, wgt[keep])           # the axis of the pixels kept
    d = pts - centre
    angle = np.degrees(np.arctan2(e[1], e[0]))
    angle = prior_deg + ((angle - prior_deg + 90.0) % 180.0) - 90.0   # in [prior - 90, prior + 90)
    th = np.radians(angle)
    e = np.array([np.cos(th), np.sin(th)])
    s = d @ e
    lo, hi = float(s.min()), float(s.max())
    h, w = counts.shape
    on_border = (rows == 0) | (rows == h - 1) | (cols == 0) | (cols == w - 1)
    sb = s[on_border]
    cut = (bool((sb <= lo + end_px).any()), bool((sb >= hi - end_px).any()))
    return GapAxis(float(angle), centre, (lo, hi), cut)


def envelope_start(gap_counts: np.ndarray, ax: GapAxis, length_px: float) -> float:
    """Position s0 (px along the axis, from ``ax.centre_px``) of the clamped end x = 0 of a glottis of
    ``length_px`` from the width of the gap seen over the recording.

    The folds are clamped at both ends, so the widest opening along the glottis follows
    ``A sin(pi (s - s0) / length_px)``; its thin ends are below the threshold, so the visible
    gap ends short of the glottis (about 2 mm on a 16 mm glottis at 22 px/mm). The width of
    the gap pixels' union in each 1 px bin along the axis is fitted by least squares (A
    eliminated) over s0 with the glottis covering the whole visible gap.
    """
    rows, cols = np.nonzero(np.asarray(gap_counts) > 0)
    th = np.radians(ax.rotation_deg)
    s = (np.stack([cols, rows], axis=1) - ax.centre_px) @ np.array([np.cos(th), np.sin(th)])
    lo, hi = ax.extent_px
    edges = np.arange(np.floor(lo), np.ceil(hi) + 1.0)
    width, _ = np.histogram(s, edges)
    centres = 0.5 * (edges[1:] + edges[:-1])
    seen = width > 0
    sc, wd = centres[seen], width[seen].astype(float)
    candidates = np.arange(hi - length_px, lo + 0.25, 0.25)
    if candidates.size == 0:          # the visible gap is longer than the glottis: centre it
        return 0.5 * (lo + hi) - length_px / 2
    best, s0 = np.inf, float(candidates[0])
    for c in candidates:
        phi = np.sin(np.pi * np.clip((sc - c) / length_px, 0.0, 1.0))
        a = phi @ wd / max(phi @ phi, 1e-12)
        r = float(np.sum((wd - a * phi) ** 2))
        if r < best:
            best, s0 = r, float(c)
    return s0


#: The motion profiled along the glottis for its symmetry: pixels within this share of the glottis length
#: of the midline (each side), where both folds' superior surfaces move.
MOTION_BAND_REL = 0.25
#: A pixel's motion amplitude counts when its velocity is valid in at least this share of the frames (the gap
#: opens over the pixels next to the midline for part of the cycle).
MOTION_VALID_SHARE = 0.5
#: The mirrored motion profile must overlap the profile over at least this share of the glottis length.
MIN_OVERLAP_REL = 0.4


def motion_amplitude(velocity: np.ndarray, valid: np.ndarray, chunk: int = 32) -> np.ndarray:
    """(H, W, 2) RMS about its mean over the frames of the horizontal (u, v) and the vertical (w) velocity.

    velocity : (F, H, W, 3) mm/s.  valid : (F, H, W) bool.
    A pixel valid in fewer than :data:`MOTION_VALID_SHARE` of the frames is NaN. Summed frame chunks of
    ``chunk`` at a time (float64), so a long window needs no float64 copy of the whole video.
    """
    n_f, h, w = np.shape(valid)
    n = np.zeros((h, w))
    s1 = np.zeros((h, w, 3))
    s2 = np.zeros((h, w, 3))
    for i in range(0, n_f, chunk):
        ok = np.asarray(valid[i:i + chunk], bool)
        v = np.where(ok[..., None], np.asarray(velocity[i:i + chunk], np.float64), 0.0)
        n += ok.sum(axis=0)
        s1 += v.sum(axis=0)
        s2 += (v * v).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        var = np.maximum(s2 / n[..., None] - (s1 / n[..., None]) ** 2, 0.0)
    amp = np.stack([np.sqrt(var[..., 0] + var[..., 1]), np.sqrt(var[..., 2])], axis=-1)
    amp[n < MOTION_VALID_SHARE * max(n_f, 1)] = np.nan
    return amp


def _motion_profile(amplitude: np.ndarray, ax: GapAxis, band_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions (B,) px along the axis from ``ax.centre_px``, (B, k) median amplitude per 1 px bin) of the
    pixels within ``band_px`` of the midline; bins with fewer than 3 pixels are left out."""
    amp = np.asarray(amplitude, float)
    amp = amp.reshape(amp.shape[:2] + (-1,))
    th = np.radians(ax.rotation_deg)
    e = np.array([np.cos(th), np.sin(th)])
    rows, cols = np.mgrid[0:amp.shape[0], 0:amp.shape[1]]
    q = np.stack([cols, rows], axis=-1) - ax.centre_px
    s, t = q @ e, q @ np.array([-e[1], e[0]])
    ok = (np.abs(t) <= band_px) & np.all(np.isfinite(amp), axis=-1)
    if ok.sum() < 3:
        return np.zeros(0), np.zeros((0, amp.shape[-1]))
    b = np.floor(s[ok]).astype(np.int64)
    order = np.argsort(b, kind="stable")
    b, vals = b[order], amp[ok][order]
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    sizes = np.diff(np.r_[starts, b.size])
    keep = sizes >= 3
    prof = np.array([np.median(vals[i:i + k], axis=0) for i, k in zip(starts[keep], sizes[keep])])
    return b[starts[keep]] + 0.5, prof.reshape(-1, amp.shape[-1])


def symmetry_mid(amplitude: np.ndarray, ax: GapAxis, length_px: float, lo: float, hi: float) -> float | None:
    """Position (px along the axis from ``ax.centre_px``) in [lo, hi] about which the motion is most nearly
    mirror-symmetric, or None when the motion in view cannot say.

    amplitude : (H, W, k) RMS amplitude of k velocity components per pixel (:func:`motion_amplitude`), NaN
        where not measured.  length_px : the glottis length L in px.
    The profile of each component along the axis (median over the pixels within :data:`MOTION_BAND_REL` L
    of the midline, 1 px bins, scaled by its largest value) is compared with its mirror image about each
    candidate m (0.25 px steps): the sum of squared differences over the positions both cover, over the sum
    of their squares. The mirror must overlap the profile over :data:`MIN_OVERLAP_REL` L. None when no
    candidate does, when the motion is all zero, or when the best candidate is the last one that overlaps
    enough while [lo, hi] goes on (mid-length lies too near the image's border to be tested).
    """
    pos, prof = _motion_profile(amplitude, ax, MOTION_BAND_REL * length_px)
    if pos.size < 3 or not np.all(np.nanmax(prof, axis=0) > 0):
        return None
    prof = prof / prof.max(axis=0)
    candidates = np.arange(lo, hi + 0.125, 0.25)
    cost = np.full(candidates.size, np.inf)
    for i, m in enumerate(candidates):
        mirror = np.stack([np.interp(2 * m - pos, pos, p, left=np.nan, right=np.nan) for p in prof.T], axis=1)
        both = np.all(np.isfinite(mirror), axis=1)
        if both.sum() >= MIN_OVERLAP_REL * length_px:
            cost[i] = np.sum((prof[both] - mirror[both]) ** 2) / np.sum(prof[both] ** 2 + mirror[both] ** 2)
    tested = np.flatnonzero(np.isfinite(cost))
    if not tested.size:
        return None
    best = int(np.argmin(cost))
    if (best == tested[0] and best > 0) or (best == tested[-1] and best < candidates.size - 1):
        return None
    return float(candidates[best])


def symmetry_window(ax: GapAxis, half_px: float) -> tuple[float, float] | None:
    """(low, high) positions (px along the axis from ``ax.centre_px``) mid-length can lie between, from the
    visible gap's extent, or None when the extent allows none.

    half_px : half the glottis length L/2, px. The gap opens only inside the glottis, so the glottis covers the
    visible gap, whichever of its ends the image's border cuts: mid-length lies within L/2 of both ends of the
    visible gap. Nothing narrower is assumed: the gap may be found over only part of the glottis (its narrow
    openings unresolved), off its middle and away from a cut end (widened null 2237: found over 72 px next to one
    border of the 282 px of glottis in view, mid-length 120 px from the visible gap's centre, outside the window
    "from the visible gap's centre to L/2 from its visible end" of optimize method 6, so the gap's envelope placed
    it 8.1 mm off). None when the visible gap is longer than L.
    """
    lo, hi = ax.extent_px
    low, high = hi - half_px, lo + half_px
    return (low, high) if low <= high else None


@dataclass(frozen=True)
class Pose:
    """rotation_deg : in-plane angle of the model x axis, degrees.  offset_px : (col, row) of the model
    origin, px.  mid_length : how mid-length was placed along the glottis ("extent of the gap", "symmetry
    of the motion", "envelope of the gap", "not measured")."""

    rotation_deg: float
    offset_px: tuple[float, float]
    mid_length: str


def locate(gap_counts: np.ndarray, px_per_mm: float, length_mm: float, prior_deg: float = 0.0,
           amplitude: np.ndarray | Callable[[], np.ndarray] | None = None) -> Pose:
    """The model frame in the image (see docs/conventions.md), and how mid-length was placed.

    Parameters
    ----------
    gap_counts : (H, W) number of frames in which each pixel is gap: the sum of the gap
        masks, accumulated by the caller frame by frame.
    px_per_mm : image scale.
    length_mm : anterior-posterior length L of the folds.
    prior_deg : rotation the principal axis's direction is chosen nearest to, degrees (the
        gap fixes the axis, not which way along it x grows).
    amplitude : (H, W, k) RMS amplitude of the measured velocity per pixel (:func:`motion_amplitude`),
        NaN where not measured, or a function returning it (called once); None: the gap only.

    Mid-length is where the motion is mirror-symmetric (:func:`symmetry_mid`), searched over
    :func:`symmetry_window`. Without the motion, or when it cannot say: with both ends of the gap in
    view, the midpoint of its extent; with one, the opening's sine envelope (:func:`envelope_start`);
    with none, the position is unmeasured (the visible centre, and a warning).
    """
    ax = gap_axis(gap_counts, prior_deg)
    th = np.radians(ax.rotation_deg)
    e = np.array([np.cos(th), np.sin(th)])
    half = px_per_mm * length_mm / 2
    lo, hi = ax.extent_px
    mid, how = None, "symmetry of the motion"
    window = symmetry_window(ax, half)
    if amplitude is not None and window is not None:
        mid = symmetry_mid(amplitude() if callable(amplitude) else amplitude, ax, 2 * half, *window)
    if mid is None and not ax.cut[0] and not ax.cut[1]:
        # both ends in view, no motion to go by: the midpoint of the extent (the count-weighted centre was taken
        # before: where the gap is found in more frames along one part of the glottis, its narrow phases missed
        # elsewhere, it moved toward that part; widened seed 1139: 1.94 mm off, 0.16 with the extent)
        mid, how = 0.5 * (lo + hi), "extent of the gap"
    elif mid is None and (not ax.cut[0] or not ax.cut[1]):
        # one end in view, no motion to go by: the opening's envelope, A sin(pi (s - s0) / L), on the visible gap
        mid, how = envelope_start(gap_counts, ax, 2 * half) + half, "envelope of the gap"
    elif mid is None:
        mid, how = 0.0, "not measured"
        log.warning("pose: the image cuts the glottal gap at both ends, so its position along the glottis is not "
                    "measured; mid-length is taken at the visible gap's centre. Set camera.pose = 'config' with "
                    "camera.offset_px (and camera.rotation_deg) if the model origin is known")
    if amplitude is not None and how in ("extent of the gap", "envelope of the gap"):
        log.warning("pose: the motion's symmetry does not place mid-length (too little of the folds' motion in view "
                    "about it to compare), so the %s does, which takes the gap as found along the whole glottis: "
                    "where its narrow openings are not found the model lies millimetres off along the glottis. Set "
                    "camera.pose = 'config' with camera.offset_px (and camera.rotation_deg) if the model origin is "
                    "known", how)
    origin = ax.centre_px + (mid - half) * e
    return Pose(float(ax.rotation_deg), (float(origin[0]), float(origin[1])), how)


def camera_to_model(vectors: np.ndarray, rotation_deg: float) -> np.ndarray:
    """Rotate image-aligned (u, v) components (..., 2) into the model's (x, y) axes."""
    r = np.radians(rotation_deg)
    c, s = np.cos(r), np.sin(r)
    v = np.asarray(vectors)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], axis=-1)


def lateral_axis_for(rotation_deg: float) -> int:
    """Image axis that is lateral for a camera rotation: 0 (rows) or 1 (columns).

    Parameters
    ----------
    rotation_deg : float
        Camera model rotation, degrees (``docs/conventions.md``).

    Returns
    -------
    int
        0 when the model's y axis is closer to the row axis (``|cos| >= |sin|``), else 1.
    """
    th = np.deg2rad(rotation_deg)
    return 0 if abs(np.cos(th)) >= abs(np.sin(th)) - 1e-12 else 1


#: Within this many degrees of a diagonal (45 deg + k 90 deg) either image axis crosses the glottis alike (at 44-46
#: deg): the rotation's own axis is then a coin the pose's precision tosses (the rotation estimated from the gap is
#: a few tenths of a degree off on the widened panels, docs/benchmarks.md), so the axis /flow measured the gap along
#: stands
DIAGONAL_TOLERANCE_DEG = 1.0

#: Within this many degrees of a diagonal optimize reads the gap along the image axis /flow measured it along (the
#: axis of flow's sub-pixel edges), where the pose's rotation makes the other axis lateral, and says nothing: both axes
#: cross the glottis at 35-55 deg there, and the axis of a gap's masks is known to a few degrees only where the gap is
#: never resolved (widened seed 4229, the glottis at -46.7 deg under a 2.8 px blur: the pose read -46.6 deg, /flow's
#: masks the other side of the diagonal, and setting camera.rotation_deg as optimize advised changed nothing;
#: docs/benchmarks.md "Session 63: the glottis near a diagonal"). The same figure as flow's warning of a configured
#: rotation off the gap's axis (:data:`vfcli.flow.pipeline.ROTATION_WARN_DEG`).
MEASURED_AXIS_TOLERANCE_DEG = 10.0


def gap_ray_axis(rotation_deg: float, measured_axis: int, tolerance_deg: float = DIAGONAL_TOLERANCE_DEG
                 ) -> tuple[int, bool]:
    """(axis, disagrees): the lateral image axis to read the gap's rays along, 0 (rows) or 1 (columns), for a camera
    rotation (degrees) and the axis the gap was measured along (optimize: /flow's axis; flow's check of the sampled
    gap passes the gap's own angle as the rotation and the configured rotation's axis as the measured one).

    The rotation's axis (:func:`lateral_axis_for`), unless the rotation lies within ``tolerance_deg`` of a diagonal,
    where either axis crosses the glottis at about 45 deg and the measured one is taken (a rotation of -44.9 deg
    estimated for a stated -45.1 deg had made optimize warn that the rotation and /flow disagree, advising to set the
    rotation already set; widened seed 4194). ``disagrees``: the rotation's axis is not the measured one and the
    rotation is away from the diagonals (a rotation that does not fit the measured gap; the caller warns)."""
    axis = lateral_axis_for(rotation_deg)
    if axis == int(measured_axis):
        return axis, False
    off = abs((float(rotation_deg) - 45.0) % 90.0)
    if min(off, 90.0 - off) <= tolerance_deg:
        return int(measured_axis), False
    return axis, True


def model_axes_velocity(velocity_uv: np.ndarray, velocity_rotation_deg: float, rotation_deg: float) -> np.ndarray:
    """(u, v) of the model axes for ``rotation_deg``, from (u, v) /flow turned by ``velocity_rotation_deg``.

    The one rotation convention (docs/conventions.md): the image velocity is
    ``R(velocity_rotation_deg) @ uv``, so the model axes of the pose ``rotation_deg`` see
    ``R(rotation_deg - velocity_rotation_deg)^T @ uv`` (nothing turns twice; identical poses
    leave the velocity unchanged).

    Parameters
    ----------
    velocity_uv : (..., 2) float, mm/s
    velocity_rotation_deg, rotation_deg : float, degrees

    Returns
    -------
    (..., 2) float64, mm/s
    """
    v = np.asarray(velocity_uv, dtype=np.float64)
    delta = float(rotation_deg) - float(velocity_rotation_deg)
    return v.copy() if delta == 0 else camera_to_model(v, delta)
