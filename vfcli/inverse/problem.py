"""The paper's error E (section 3.4) with exact gradients for a frozen raster.

Frames and times
----------------
The measurement has F frames at uniformly spaced ``times`` (dt apart).  The model
is evaluated at the F + 1 times ``times`` and ``times[-1] + dt``
(:attr:`Problem.sim_times`); a force field's time range should be
``(sim_times[0], sim_times[-1])``.  Frame f compares the measured v(y, t_f) with
the velocity at t_f of the material point seen in pixel y at t_f: the paper's v-bar, with the
forward difference ``(x(u, v, t_f + dt) - x(u, v, t_f)) / dt`` (the velocity at t_f + dt/2) replaced by
the frame-time combination of :mod:`vfcli.inverse.stencil` (the measured velocities are the frame
times', and the forward difference put the model half a frame ahead of them).

E = motion_weight * E_motion + gap_weight * E_gap (both means over the F frames)
+ ridge_weight * x^T Omega x / n_params, the last an optional bound on the loads
(default 0, the paper's E; Omega is the load model's ``penalty_operator()``, the
identity unless the model says otherwise).  The superior-surface velocity fixes the displacement only up to
a time-constant field (the gap silhouette pins the medial edge), and the
inferior surface not at all (the reference note "What superior-surface data can and cannot reveal"): a
reconstruction that reports them should bound its loads.

Motion term (paper's three cases)
---------------------------------
Per frame: rasterise the deformed visible surface (faces with ``visible_tags``,
default superior + medial) with the camera; per pixel, the visible triangle and
barycentrics fix the material point.  With m_sim (a surface is visible) and
m_exp (``measurement.valid``)::

    both:       |v - v_bar|^2        only m_exp:  |v|^2        otherwise: 0

summed over the pixels and divided by N_f = number of valid measured pixels of
the frame (so E_motion is a mean squared velocity error, (mm/s)^2).

This is one-sided: a pixel where only the recording sees tissue costs |v|^2, a
pixel where only the simulation sees tissue costs nothing, so a step that moves
the simulated medial edge into the measured gap is never charged for it (the
raster is frozen in the gradient; the charge acts through which steps lower E).
``ObjectiveSettings.outside = "symmetric"`` charges that case too, where the
recording positively sees no tissue (the measured gap, ``Measurement.gap``)::

    only m_sim, in the measured gap:  |v_bar|^2

(pixels merely outside the measured region, e.g. beyond the vibrometer's hull,
still cost nothing).  Near an edge v ~ v_bar, so an edge pixel costs about the
same whichever side the mismatch is on.  ``"paper"`` (the default) is the
paper's literal E.

Gap term (our differentiable definition of the arctan term)
------------------------------------------------------------
Rays are the lateral image lines (one per column when ``lateral_axis == 0``, as in
:mod:`vfcli.flow.gap.opening`).  On a ray at integer ray coordinate c, each fold's
simulated silhouette is the lateral screen position (px) of its medial-most
point: the extreme (max for the fold at smaller lateral px, min for the other)
over the crossings of the fold's surface-mesh edges with the ray, where an edge
(a, b) crosses at ``s = lat_a + (c - ray_a) / (ray_b - ray_a) (lat_b - lat_a)``.
The measured silhouettes are the outermost gap-mask transitions of the ray
(:func:`measured_silhouettes`); on a closed ray both are the last known opening
location (the paper's fallback), where ``closed_rays = "meet"`` asks a simulated gap to
close.  A closed ray where the simulated folds overlap is left out
(``closed_rays = "overlap-allowed"``, the default since session 47): the camera
cannot see one fold pass behind the other, and the model has no contact, so its
folds overlap in the closed phase (:func:`vfcli.inverse.terms.gap.closed_rays_kept`; where they leave a gap, it is
asked to close where it stands, :func:`vfcli.inverse.terms.gap.closing_targets`;
``"meet"`` asks them to meet exactly, overlap or not; ``"overlap-bounded"`` leaves the ray out while the overlap is
within the widest opening measured in the window and charges the excess as ``(d / l)^2``, without the arctan's
saturation: :func:`vfcli.inverse.terms.gap.closed_rays_excess`).  With
``d = (s_sim - s_meas) / px_per_mm`` (mm) and the length scale l::

    E_gap = mean over frames of  (1 / (2 n_rays)) sum_rays sum_folds arctan((d / l)^2)

It is bounded (each term < pi/2), smooth in d (d^2 inside the arctan), and
penalises small differences most, as the paper's arctan intends.  The ray set
is fixed at construction (rays crossed by both folds at rest, minus
``ray_margin`` rays at each end).

Exact gradient "almost everywhere"
----------------------------------
Freezing (per frame) the raster (visible triangle and barycentrics of every
pixel) and the silhouette edge chosen on each ray makes E a smooth function of
the vertex positions, hence of the control values.  :meth:`Problem.value_and_grad`
returns E with the raster of the current iterate and the exact gradient of that
frozen function (chain rule through the interpolation matrices, the edge
crossings and the linear response, accumulated in one pass over the frames).
It is the gradient of the frozen function, whose barycentrics follow the
material: E evaluated with a fresh raster (as a line search does) compares each
pixel with the surface point under it now, and a step that moves the surface in
the image plane slides the surface under the pixels, a change of first order in
the step that this gradient and the Gauss-Newton model leave out (the velocity
field's image gradient times the slide; session 50 measured it ten times the
frozen change on an inertia refit, 96-97 % of it on pixels whose visible triangle
stayed the same: docs/benchmarks.md, "A bound on the closed rays' overlap that
does not saturate").  Where the slide is small against the velocity field's scale
the two agree.  ``ObjectiveSettings.motion_slide`` adds that term: the frozen frame then
also carries the velocity field's image gradient per visible triangle
(:class:`vfcli.inverse.terms.motion.Slide`), the frozen motion residual follows the surface
under the pixels to first order, and the gradient is the line search's derivative (to the
central differences' own spread, tests/test_objective.py).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from vfcli.camera.camera import Camera
from vfcli.camera.raster import rasterize
from vfcli.camera.silhouette import edge_crossings, extreme_per_ray, surface_edges
from vfcli.flow.gap.opening import measured_silhouettes
from vfcli.inverse.stencil import frame_velocity_stencil, stencil_apply
from vfcli.inverse.terms import DEFAULT_TERMS, Evaluation, Term, Terms
from vfcli.inverse.terms.gap import CLOSED_RAYS, closed_rays_excess, closed_rays_kept, closing_targets, widest_opening
from vfcli.inverse.terms.motion import Slide, frame_residual
from vfcli.model.mesh import TAG_MEDIAL, TAG_SUPERIOR, FoldMesh
from vfcli.model.response.base import Response


@dataclass(frozen=True)
class Measurement:
    """What the optimisation fits (all on the camera's pixel grid).

    Attributes
    ----------
    times : (F,) uniformly spaced frame times, s.
    velocity : (F, H, W, 3) measured v = (u, v, w), mm/s.
    valid : (F, H, W) bool, m_exp.
    gap_lo, gap_hi : (F, n_rays) lateral px of the measured silhouettes facing
        the fold at smaller / larger lateral px; NaN: no target on that ray.
    gap : (F, H, W) bool measured gap masks (where the recording sees no tissue), or
        None; needed by ``ObjectiveSettings.outside = "symmetric"``.
    pixel_stride : s: the motion is compared on every s-th pixel of every s-th row only
        (:meth:`thinned`; 1: every pixel).
    """

    times: np.ndarray
    velocity: np.ndarray
    valid: np.ndarray
    gap_lo: np.ndarray
    gap_hi: np.ndarray
    gap: np.ndarray | None = None
    pixel_stride: int = 1

    @property
    def dt(self) -> float:
        return float(self.times[1] - self.times[0])

    def thinned(self, stride: int) -> Measurement:
        """The measurement with its velocity compared on the pixels (row, col) with ``row % stride == 0`` and
        ``col % stride == 0`` only (``valid`` cleared elsewhere); the gap masks and silhouettes stay whole.
        Residuals of smooth fields are correlated over many pixels, so this keeps most of what the motion
        tells while the rows drop by ``stride ** 2`` (:func:`vfcli.inverse.uncertainty.effective_sample_size`
        counts the correlation area on the thinned grid)."""
        stride = int(stride)
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        if stride == self.pixel_stride:
            return self
        if self.pixel_stride != 1:
            raise ValueError(f"the measurement is thinned to every {self.pixel_stride}th pixel already")
        h, w = np.shape(self.valid)[1:]
        grid = np.zeros((h, w), bool)
        grid[::stride, ::stride] = True
        return replace(self, valid=np.asarray(self.valid, bool) & grid, pixel_stride=stride)

    @classmethod
    def from_gap_masks(cls, times: np.ndarray, velocity: np.ndarray, valid: np.ndarray, gap_masks: np.ndarray,
                       lateral_axis: int = 0, initial_center: np.ndarray | float | None = None) -> Measurement:
        """Measurement with silhouettes from (F, H, W) bool gap masks (:func:`measured_silhouettes`).

        velocity, valid : as :func:`vfcli.flow.velocity_field.combine_fields` returns them for the frames at ``times``.
        """
        lo, hi = measured_silhouettes(gap_masks, lateral_axis, initial_center)
        return cls(np.asarray(times, float), np.asarray(velocity), np.asarray(valid, bool), lo, hi,
                   np.asarray(gap_masks, bool))


#: how the motion term charges pixels that only one of simulation and recording sees
OUTSIDE = ("paper", "symmetric")


@dataclass(frozen=True)
class ObjectiveSettings:
    """Weights and definitions of E (see module docstring).

    Raises ValueError for values out of range: the config (``vfcli.config.OptimizeConfig``)
    bounds every field it sets, so a bad value here is a caller's bug, not a user's.
    """

    motion_weight: float = 1.0
    gap_weight: float = 1.0
    gap_length_mm: float = 0.25
    visible_tags: tuple[int, ...] = (TAG_SUPERIOR, TAG_MEDIAL)
    lateral_axis: int = 0
    ray_margin: int = 1
    ridge_weight: float = 0.0
    #: weight of each velocity component (model x, y, z) in the motion term (1, 1, 1: the
    #: paper's |v - v_bar|^2); (1, 1, 0) keeps the camera's in-plane motion only, (0, 0, 1)
    #: the vibrometer's vertical velocity only (:mod:`vfcli.inverse.uncertainty` compares the two)
    component_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: "paper": a pixel only the simulation sees costs nothing (the paper's one-sided E);
    #: "symmetric": it costs |v_bar|^2 where the recording sees the gap (module docstring)
    outside: str = "paper"
    #: a ray the camera sees closed: "overlap-allowed" leaves it out where the simulated folds overlap
    #: (:func:`vfcli.inverse.terms.gap.closed_rays_kept`); "meet" asks both silhouettes to meet at the last known
    #: opening location whatever the simulation shows (before session 47); "overlap-bounded" leaves it out while the
    #: overlap is within the widest measured opening and charges the excess quadratically
    #: (:func:`vfcli.inverse.terms.gap.closed_rays_excess`)
    closed_rays: str = "overlap-allowed"
    #: False: the motion term's gradient and Gauss-Newton model follow the material points the frozen raster saw
    #: (the paper's frozen (u, v)); True: they also follow the surface sliding under the pixels when a step moves it
    #: in the image plane (:class:`vfcli.inverse.terms.motion.Slide`), the first-order change a fresh raster sees
    motion_slide: bool = False

    def __post_init__(self) -> None:
        if self.outside not in OUTSIDE:
            raise ValueError(f"outside must be one of {OUTSIDE}, got {self.outside!r}")
        if self.closed_rays not in CLOSED_RAYS:
            raise ValueError(f"closed_rays must be one of {CLOSED_RAYS}, got {self.closed_rays!r}")
        if not (self.motion_weight >= 0 and self.gap_weight >= 0 and self.ridge_weight >= 0
                and len(self.component_weights) == 3 and min(self.component_weights) >= 0):
            raise ValueError("objective weights must be >= 0")
        if not self.gap_length_mm > 0:
            raise ValueError(f"gap_length_mm must be > 0, got {self.gap_length_mm!r}")
        if self.lateral_axis not in (0, 1):
            raise ValueError(f"lateral_axis must be 0 or 1, got {self.lateral_axis!r}")


@dataclass
class _Frame:
    """Frozen linearisation data of one frame."""

    m_both: object          # csr (n_both, N): interpolation rows of the compared pixels (valid in both,
    #                         and with outside="symmetric" the simulated pixels in the measured gap)
    v_both: np.ndarray      # (n_both, 3) measured velocity there (0 in the gap), mm/s
    const: float            # sum of |v|^2 over pixels valid only in the measurement
    n_norm: float           # N_f
    sil: list               # per fold side (lo, hi): (ray coordinate, edge, target px)
    pix_both: np.ndarray    # (n_both,) flat pixel indices of the rows of m_both
    pix_only: np.ndarray    # flat pixel indices valid only in the measurement
    excess: list = ()       # per fold side: closed rays overlapping beyond the widest opening, as ``sil``
    #                         (closed_rays = "overlap-bounded"; :func:`vfcli.inverse.terms.gap.closed_rays_excess`)
    slide: Slide | None = None  # the surface sliding under the compared pixels (motion_slide)

    def emptied(self) -> _Frame:
        """The frame with nothing compared and no silhouette: it adds nothing to E (a held-out frame)."""
        return replace(self, m_both=self.m_both[:0], v_both=self.v_both[:0], const=0.0,
                       pix_both=self.pix_both[:0], pix_only=self.pix_only[:0],
                       sil=[tuple(a[:0] for a in side) for side in self.sil],
                       excess=[tuple(a[:0] for a in side) for side in self.excess],
                       slide=None if self.slide is None else self.slide.emptied())


class Problem:
    """E(x) for a response, a camera and a measurement.

    Parameters
    ----------
    mesh : FoldMesh.
    camera : Camera.
    response : a :class:`vfcli.model.response.base.Response` (e.g.
        :class:`vfcli.model.response.quasi_static.QuasiStaticResponse`); used through its methods only.
    measurement : Measurement (its velocity/valid images must match ``camera.shape``).
    settings : ObjectiveSettings.
    terms : the terms of E (:mod:`vfcli.inverse.terms`), default motion, gap and ridge; each reads
        its weight from ``settings`` (or carries its own).
    """

    def __init__(self, mesh: FoldMesh, camera: Camera, response: Response, measurement: Measurement,
                 settings: ObjectiveSettings | None = None, terms: tuple[Term, ...] | None = None) -> None:
        self.mesh, self.camera, self.response = mesh, camera, response
        #: the terms of E, summed in this order
        self.terms: tuple[Term, ...] = tuple(terms) if terms is not None else tuple(t() for t in DEFAULT_TERMS)
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names) or not all(names):
            raise ValueError(f"the terms of E need distinct non-empty names, got {names}")
        #: (n, n) sparse PSD matrix Omega of the ridge term (identity unless the response says otherwise)
        self.penalty = (response.penalty_operator() if hasattr(response, "penalty_operator")
                        else sp.identity(response.n_params, format="csr"))
        self.meas, self.settings = measurement, settings or ObjectiveSettings()
        st = self.settings
        times = np.asarray(measurement.times, dtype=float)
        if times.ndim != 1 or len(times) < 2 or not np.allclose(np.diff(times), times[1] - times[0], rtol=1e-6):
            raise ValueError("measurement times must be (F,) uniformly spaced, F >= 2")
        if not times[1] > times[0]:
            raise ValueError("measurement times must increase")
        f, (h, w) = len(times), camera.shape
        if measurement.velocity.shape != (f, h, w, 3) or measurement.valid.shape != (f, h, w):
            raise ValueError(f"measurement velocity/valid must be ({f}, {h}, {w}, 3)/({f}, {h}, {w}), got "
                             f"{measurement.velocity.shape}/{measurement.valid.shape}")
        if st.outside == "symmetric" and (measurement.gap is None or np.shape(measurement.gap) != (f, h, w)):
            raise ValueError(f"outside='symmetric' needs the measurement's ({f}, {h}, {w}) gap masks")
        self.dt = float(times[1] - times[0])
        self.sim_times = np.append(times, times[-1] + self.dt)
        #: per frame, the simulated times and weights of the model's velocity at t_f (vfcli.inverse.stencil)
        self.stencil = frame_velocity_stencil(f)
        self.n_frames = f
        self.ray_comp = 0 if st.lateral_axis == 0 else 1
        self.n_rays_img = w if st.lateral_axis == 0 else h
        if measurement.gap_lo.shape != (f, self.n_rays_img) or measurement.gap_hi.shape != (f, self.n_rays_img):
            raise ValueError(f"measurement gap_lo/gap_hi must be ({f}, {self.n_rays_img})")
        self.tri = mesh.faces[np.isin(mesh.face_tag, st.visible_tags)]
        self.fold_edges = [surface_edges(mesh.faces[mesh.face_fold == k]) for k in (0, 1)]
        rest = camera.project(mesh.nodes)
        lat = rest[:, 1 - self.ray_comp]
        means = [lat[mesh.fold_nodes(k)].mean() for k in (0, 1)]
        self.fold_order = (0, 1) if means[0] < means[1] else (1, 0)   # (fold at low lateral px, high)
        rays = None
        for k in (0, 1):
            _, c, _ = edge_crossings(rest, self.fold_edges[k], self.ray_comp)
            c = np.unique(c[(c >= 0) & (c < self.n_rays_img)])
            rays = c if rays is None else np.intersect1d(rays, c)
        m = int(st.ray_margin)
        self.rays = rays[m:len(rays) - m] if len(rays) > 2 * m else rays[:0]
        self._in_rays = np.zeros(self.n_rays_img, bool)
        self._in_rays[self.rays] = True
        #: the widest opening the camera measured on the rays in the window, px (closed_rays = "overlap-bounded")
        self.widest_opening_px = widest_opening(measurement.gap_lo, measurement.gap_hi, self.rays)

    @property
    def n_params(self) -> int:
        return int(self.response.n_params)

    #: settings :meth:`with_weights` may change (nothing computed in ``__init__`` depends on them)
    _WEIGHTS = frozenset({"motion_weight", "gap_weight", "ridge_weight", "component_weights"})

    def with_weights(self, **weights) -> Problem:
        """The same problem with other term weights (``motion_weight``, ``gap_weight``,
        ``ridge_weight``, ``component_weights``); shares everything else with this one."""
        unknown = set(weights) - self._WEIGHTS
        if unknown:
            raise ValueError(f"with_weights changes term weights only, not {sorted(unknown)}")
        other = copy.copy(self)
        other.settings = replace(self.settings, **weights)
        return other

    def thinned(self, stride: int) -> Problem:
        """The same problem comparing the motion on a ``stride`` pixel grid only (:meth:`Measurement.thinned`);
        shares everything else with this one (nothing computed in ``__init__`` depends on ``valid``)."""
        if int(stride) == self.meas.pixel_stride:
            return self
        other = copy.copy(self)
        other.meas = self.meas.thinned(stride)
        return other

    def displacements(self, x: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) vertex displacements at :attr:`sim_times`, mm."""
        return self.response.displacements(np.asarray(x, dtype=float), self.sim_times)

    # ------------------------------------------------------------ freezing
    def silhouettes(self, positions: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Simulated silhouettes of one frame on the ray set.

        positions : (N, 3) deformed vertices, mm.  Returns, for the (low, high)
        folds, (rays c, chosen edge, lateral px).
        """
        scr = self.camera.project(positions)
        out = []
        limits = (int(self.rays[0]), int(self.rays[-1]) + 1) if len(self.rays) else (0, 0)
        # the limits lie within the image; when the ray set has no holes they are the ray set
        contiguous = len(self.rays) == limits[1] - limits[0]
        for side, k in enumerate(self.fold_order):
            e, c, s = edge_crossings(scr, self.fold_edges[k], self.ray_comp, limits)
            if not contiguous:
                keep = self._in_rays[c]
                e, c, s = e[keep], c[keep], s[keep]
            rays, edge = extreme_per_ray(e, c, s, take_max=(side == 0))
            ee = self.fold_edges[k][edge]
            lam = (rays - scr[ee[:, 0], self.ray_comp]) / (scr[ee[:, 1], self.ray_comp] - scr[ee[:, 0], self.ray_comp])
            lc = 1 - self.ray_comp
            out.append((rays, edge, scr[ee[:, 0], lc] + lam * (scr[ee[:, 1], lc] - scr[ee[:, 0], lc])))
        return out

    def freeze(self, x: np.ndarray, disp: np.ndarray | None = None, slide: bool | None = None) -> list[_Frame]:
        """Rasters and silhouette edges of every frame at ``x`` (the linearisation point).

        slide : whether the frames carry the surface's slide under the pixels (default: the settings'
        ``motion_slide``; it is zero at ``x``, so E's value there does not need it, its gradient does).
        """
        slide = self.settings.motion_slide if slide is None else bool(slide)
        u = self.displacements(x) if disp is None else disp
        cw = np.asarray(self.settings.component_weights, dtype=float)
        symmetric = self.settings.outside == "symmetric"
        n_pix = int(np.prod(self.camera.shape))
        frames = []
        for f in range(self.n_frames):
            pos = self.mesh.nodes + u[f]
            raster = rasterize(self.camera, pos, self.tri)
            valid = self.meas.valid[f].reshape(n_pix)                # (H W,) bool
            vel = self.meas.velocity[f].reshape(n_pix, 3)            # (H W, 3) mm/s, any float dtype
            vis = raster.visible_index
            both = valid[vis]
            only = valid.copy()
            only[vis] = False
            pix_only = np.flatnonzero(only)
            if symmetric:
                # the simulation sees tissue where the recording sees the gap: compare with v = 0
                both |= self.meas.gap[f].reshape(n_pix)[vis]
            rows = np.flatnonzero(both)
            pix_both = vis[rows]
            # gather the compared pixels first, then convert (not the whole frame); np.take is a
            # much faster row gather than fancy indexing
            v_both = np.take(vel, pix_both, axis=0).astype(float, copy=False)
            if symmetric:
                v_both[~valid[pix_both]] = 0.0
            v_only = np.take(vel, pix_only, axis=0).astype(float, copy=False)
            sil = []
            targets = (self.meas.gap_lo[f], self.meas.gap_hi[f])
            simulated = self.silhouettes(pos)
            excess = []
            if self.settings.closed_rays == "overlap-allowed":
                simulated, targets = closed_rays_kept(simulated, *targets), closing_targets(simulated, *targets)
            elif self.settings.closed_rays == "overlap-bounded":
                (simulated, excess), targets = (closed_rays_excess(simulated, *targets, self.widest_opening_px),
                                                closing_targets(simulated, *targets))
            for side, (rays, edge, _) in enumerate(simulated):
                tgt = targets[side][rays]
                ok = np.isfinite(tgt)
                sil.append((rays[ok], edge[ok], tgt[ok]))
            m_both = raster.interpolation_rows(rows)
            sliding = None
            if slide:
                sliding = Slide.at(self.camera, pos, self.tri, raster.visible_triangle[rows], self.frame_velocity(u, f),
                                 m_both @ u[f][:, :2])
            frames.append(_Frame(m_both, v_both, float(np.sum(v_only ** 2 @ cw)),
                                 float(max(1, np.count_nonzero(valid))), sil, pix_both, pix_only, excess, sliding))
        return frames

    # ------------------------------------------------------------ value and gradient
    def _frozen(self, x: np.ndarray, frames: list[_Frame], disp: np.ndarray | None,
                grad: bool) -> tuple[Terms, np.ndarray | None]:
        """E (sum of the weighted terms, in the order of :attr:`terms`) and, with ``grad``, its gradient."""
        u = self.displacements(x) if disp is None else disp
        ev = Evaluation(self, x, u, frames, np.zeros_like(u) if grad else None,
                        np.zeros(len(x)) if grad else None)
        terms = Terms.from_parts({t.name: t.value(ev) for t in self.terms})
        if not grad:
            return terms, None
        return terms, self.response.adjoint(ev.grad_disp, self.sim_times, x) + ev.grad_x

    def motion_residuals(self, x: np.ndarray, frames: list[_Frame]) -> np.ndarray:
        """(F, H, W, 3) simulated minus measured velocity, mm/s, for a frozen raster.

        Pixels valid in both: ``v_bar - v``; valid only in the measurement: ``-v``
        (the paper's second case); with ``outside="symmetric"``, ``v_bar`` where only the
        simulation sees tissue in the measured gap; elsewhere NaN.
        """
        u = self.displacements(np.asarray(x, float))
        h, w = self.camera.shape
        out = np.full((self.n_frames, h * w, 3), np.nan)
        for f, fr in enumerate(frames):
            out[f, fr.pix_both] = frame_residual(fr, self.frame_velocity(u, f), u[f])
            out[f, fr.pix_only] = -self.meas.velocity[f].reshape(-1, 3)[fr.pix_only]
        return out.reshape(self.n_frames, h, w, 3)

    def frame_velocity(self, u: np.ndarray, f: int) -> np.ndarray:
        """(N, 3) the model's vertex velocity at frame time t_f, mm/s, from its displacements u (F + 1, N, 3)
        at :attr:`sim_times` (:mod:`vfcli.inverse.stencil`)."""
        return stencil_apply(u, self.stencil[f]) / self.dt

    def frozen_value(self, x: np.ndarray, frames: list[_Frame]) -> Terms:
        """E at ``x`` with rasters and silhouette edges frozen at an earlier :meth:`freeze`."""
        return self._frozen(np.asarray(x, float), frames, None, grad=False)[0]

    def frozen_value_and_grad(self, x: np.ndarray, frames: list[_Frame]) -> tuple[Terms, np.ndarray]:
        """E and its exact gradient with a frozen linearisation."""
        return self._frozen(np.asarray(x, float), frames, None, grad=True)

    def evaluate(self, x: np.ndarray) -> Terms:
        """E at ``x`` (rasterised at ``x``)."""
        x = np.asarray(x, float)
        u = self.displacements(x)
        return self._frozen(x, self.freeze(x, u, slide=False), u, grad=False)[0]

    def value_and_grad(self, x: np.ndarray) -> tuple[Terms, np.ndarray]:
        """E at ``x`` and its exact gradient for the raster of ``x`` ((n_params,) per unit x)."""
        x = np.asarray(x, float)
        u = self.displacements(x)
        return self._frozen(x, self.freeze(x, u), u, grad=True)


def synthesize_measurement(mesh: FoldMesh, camera: Camera, response, times: np.ndarray, x: np.ndarray,
                           settings: ObjectiveSettings | None = None) -> Measurement:
    """Forward-simulate a measurement from control values (for tests and phantoms).

    The velocity is the model's frame-time velocity (:meth:`Problem.frame_velocity`) on the visible surface
    (valid where a surface is visible, the gap mask everywhere else), the gap targets
    are the model's own silhouettes on every ray both folds cross (NaN elsewhere): a
    fit of the same model can reach E = 0.
    """
    settings = settings or ObjectiveSettings()
    times = np.asarray(times, dtype=float)
    f, (h, w) = len(times), camera.shape
    n_rays = w if settings.lateral_axis == 0 else h
    dummy = Measurement(times, np.zeros((f, h, w, 3)), np.zeros((f, h, w), bool),
                        np.full((f, n_rays), np.nan), np.full((f, n_rays), np.nan))
    prob = Problem(mesh, camera, response, dummy, ObjectiveSettings(**{**settings.__dict__, "ray_margin": 0}))
    u = prob.displacements(x)
    vel = np.zeros((f, h * w, 3))
    valid = np.zeros((f, h * w), bool)
    lo, hi = np.full((f, n_rays), np.nan), np.full((f, n_rays), np.nan)
    for k in range(f):
        pos = mesh.nodes + u[k]
        raster = rasterize(camera, pos, prob.tri)
        vel[k, raster.visible_index] = raster.interpolate_visible(prob.frame_velocity(u, k))
        valid[k, raster.visible_index] = True
        (r0, _, s0), (r1, _, s1) = prob.silhouettes(pos)
        common = np.intersect1d(r0, r1)
        lo[k, common] = s0[np.searchsorted(r0, common)]
        hi[k, common] = s1[np.searchsorted(r1, common)]
    valid = valid.reshape(f, h, w)
    return Measurement(times, vel.reshape(f, h, w, 3), valid, lo, hi, ~valid)
