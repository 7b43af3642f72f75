"""The optimisation problem of a recording, from arrays and settings (reads nothing).

:func:`build_problem` turns what the optimize stage read from the store
(:class:`OptimizeInputs`: the mesh and its material, the window of measured velocities and
gap masks, the camera scale, the pressure) and the ``[optimize]`` settings into a
:class:`vfcli.inverse.problem.Problem`: the load model, the elastic model and its
response, the camera pose (configured, or estimated from the gap), the measurement, and
the ridge weight (the L-curve's when the load model asks for it).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable

import numpy as np
from scipy.ndimage import distance_transform_edt

from vfcli.camera.camera import Camera
from vfcli.camera.pose import (MEASURED_AXIS_TOLERANCE_DEG, gap_ray_axis, locate, model_axes_velocity,
                               motion_amplitude)
from vfcli.config import OptimizeConfig
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.problem import Measurement, ObjectiveSettings, Problem
from vfcli.inverse.regularization import LCurve, lcurve
from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec, LoadModel
from vfcli.model.loads.pressure import PressureLoad, band_limited
from vfcli.model.mesh import FoldMesh
from vfcli.model.response.quasi_static import QuasiStaticResponse

log = logging.getLogger(__name__)

#: ridge weight (1/Pa^2) of each load model when optimize.ridge_weight is null (None: chosen by the L-curve)
DEFAULT_RIDGE = {"free": 0.0, "free-regularised": None, "pressure": None}


@dataclass(frozen=True)
class OptimizeInputs:
    """Everything an optimisation run uses from a recording.

    Attributes
    ----------
    mesh : FoldMesh
        The fold mesh, mm.
    youngs_modulus_pa, poisson_ratio, density_kg_m3 : float
        The material the mesh was built for (Pa, 1, kg/m^3).
    length_mm : float
        Anterior-posterior length L of the folds, mm (places the estimated pose).
    times : (F,) float64
        Uniformly spaced frame times of the window, s.
    velocity : (F, H, W, 3) float32 or float64
        Measured surface velocity (u, v, w), mm/s (used as float64): (u, v) in the model's (x, y)
        axes for the camera rotation ``velocity_rotation_deg`` (as /fields stores it).
    valid : (F, H, W) bool
        Where the velocity is valid.
    gap_masks : (F, H, W) bool
        Measured glottal gap of the window's frames.
    px_per_mm : float
        Image scale, px/mm.
    roi_origin_px : (2,) float64
        Full-frame pixel (col, row) of the stored frames' first pixel (the ingest ROI's corner).
    gap_counts : (H, W) float64 or None
        Frames in which each pixel is gap, over the whole recording (for the pose estimate).
    velocity_rotation_deg : float
        Camera rotation, degrees, with which /flow already turned the image velocities into model
        axes (``velocity[..., :2]`` is (x, y) for that rotation; :func:`model_axes_velocity`).
    lateral_axis : int
        Lateral image axis /flow used for the gap's rays: 0 (rows) or 1 (columns).
    pressure_time, pressure : (S,) float64 or None
        Subglottal pressure recorded with the video (s, Pa), for the pressure load model.
    f0_hz : float
        The video's f0 (``/sync``), Hz, or NaN: the pressure's band (``optimize.pressure_band_harmonics``).
    """

    mesh: FoldMesh
    youngs_modulus_pa: float
    poisson_ratio: float
    density_kg_m3: float
    length_mm: float
    times: np.ndarray
    velocity: np.ndarray
    valid: np.ndarray
    gap_masks: np.ndarray
    px_per_mm: float
    roi_origin_px: np.ndarray
    gap_counts: np.ndarray | None = None
    velocity_rotation_deg: float = 0.0
    lateral_axis: int = 0
    pressure_time: np.ndarray | None = None
    pressure: np.ndarray | None = None
    f0_hz: float = float("nan")


@dataclass(frozen=True)
class Setup:
    """How the problem was set up (stored with the run).

    Attributes
    ----------
    rotation_deg : float
        Camera rotation, degrees.
    offset_px : (float, float)
        Pixel (col, row) of the model origin on the stored (ROI) pixel grid, px.
    pose_source : str
        "config" or "estimated from the glottal gap (mid-length: HOW)" (:class:`vfcli.camera.pose.Pose`).
    field : LoadModel
        The load model.
    lcurve : LCurve or None
        The L-curve that chose the ridge weight (None: the weight was given).
    model : ElasticModel or None
        The elastic model the response was solved on (factorised by then): the stated uncertainty's richer load
        family solves on it (:func:`richer_load_problem`) instead of factorising the folds again.
    """

    rotation_deg: float
    offset_px: tuple[float, float]
    pose_source: str
    field: LoadModel
    lcurve: LCurve | None
    model: ElasticModel | None = None


def camera_pose(inputs: OptimizeInputs, pose: tuple[float, tuple[float, float]] | None
                ) -> tuple[float, tuple[float, float], str]:
    """(rotation_deg, offset_px on the stored pixel grid, source) of the model in the image.

    Parameters
    ----------
    inputs : OptimizeInputs
    pose : (rotation_deg, (col, row) offset in full-frame px) or None
        A calibrated pose (``camera.pose = "config"``); its offset is moved onto the stored
        frames' grid by the ROI origin. None: estimated from ``inputs.gap_counts`` and the motion of
        ``inputs.velocity`` (:func:`vfcli.camera.pose.locate`).
    """
    if pose is not None:
        rotation, offset = pose
        origin = np.asarray(inputs.roi_origin_px, float)
        return float(rotation), (float(offset[0] - origin[0]), float(offset[1] - origin[1])), "config"
    if inputs.gap_counts is None:
        raise ValueError("estimating the camera pose needs inputs.gap_counts")
    found = locate(inputs.gap_counts, inputs.px_per_mm, inputs.length_mm, prior_deg=inputs.velocity_rotation_deg,
                   amplitude=motion_amplitude(inputs.velocity, inputs.valid))
    return found.rotation_deg, found.offset_px, f"estimated from the glottal gap (mid-length: {found.mid_length})"


def load_model(inputs: OptimizeInputs, cfg: OptimizeConfig, t_range: tuple[float, float]) -> LoadModel:
    """The load model ``cfg.loads`` selects, over the time window ``t_range`` (s).

    'free' and 'free-regularised': the paper's force field (optimize.setup, optimize.tie_folds);
    'pressure': :class:`vfcli.model.loads.pressure.PressureLoad` on ``inputs.pressure``, low-passed at
    ``cfg.pressure_band_harmonics`` harmonics of ``inputs.f0_hz`` (:func:`vfcli.model.loads.pressure.band_limited`;
    as recorded when either is missing).
    """
    if cfg.loads in ("free", "free-regularised"):
        return ForceField(ForceFieldSpec.from_name(cfg.setup, tie_folds=cfg.tie_folds), t_range)
    if inputs.pressure is None or inputs.pressure_time is None:
        raise ValueError("the pressure load model needs inputs.pressure and inputs.pressure_time")
    n_z, n_x = cfg.pressure_medial_shapes
    pressure = band_limited(inputs.pressure_time, inputs.pressure, inputs.f0_hz, cfg.pressure_band_harmonics)
    return PressureLoad(inputs.pressure_time, pressure, t_range, time_degree=cfg.pressure_time_degree,
                        medial_z=n_z, medial_x=n_x, inferior_linear_x=cfg.pressure_inferior_linear)


def near_gap(gap_masks: np.ndarray, margin_px: float) -> np.ndarray:
    """(H, W) bool: pixels within ``margin_px`` (Euclidean, px) of the gap's envelope over the window.

    gap_masks : (F, H, W) bool measured gap masks.  margin_px : 0 gives the envelope itself.
    The motion term leaves these pixels out (``optimize.gap_margin_px``): next to the open gap the
    vibrometer's interpolated field mixes scan points on the tissue with points that look through the
    gap (docs/benchmarks.md, "Where the widened phantoms' inferior error comes from").
    """
    envelope = np.asarray(gap_masks, bool).any(axis=0)
    if not envelope.any():
        return envelope
    return distance_transform_edt(~envelope) <= float(margin_px)


def build_problem(inputs: OptimizeInputs, cfg: OptimizeConfig,
                  pose: tuple[float, tuple[float, float]] | None, *,
                  map: Callable[..., Iterable[Any]] | None = None,
                  lateral_axis: int | None = None) -> tuple[Problem, Setup]:
    """The optimisation problem: mesh, elastic model, load model, camera, measurement, weights.

    Parameters
    ----------
    inputs : OptimizeInputs
        The recording's arrays (:class:`OptimizeInputs`).
    cfg : OptimizeConfig
        The ``[optimize]`` settings.
    pose : (rotation_deg, (col, row) full-frame px) or None
        The configured camera pose, or None to estimate it (:func:`camera_pose`).
    map : callable, optional
        Runs the response's basis solves (:class:`QuasiStaticResponse`'s ``map``): a thread
        pool's or a Dask client's map; default one after the other.
    lateral_axis : {0, 1}, optional
        The image axis of the gap term's rays, as a stored run had it (its ``gap_lateral_axis``); None: the pose's
        rotation's axis, or /flow's within :data:`vfcli.camera.pose.MEASURED_AXIS_TOLERANCE_DEG` of a diagonal
        (:func:`vfcli.camera.pose.gap_ray_axis`; warned where they disagree further off).

    Returns
    -------
    (Problem, Setup)
    """
    rotation, offset, pose_source = camera_pose(inputs, pose)
    velocity = np.array(inputs.velocity, dtype=np.float64)
    velocity[..., :2] = model_axes_velocity(velocity[..., :2], inputs.velocity_rotation_deg, rotation)
    if lateral_axis is None:
        lateral, disagrees = gap_ray_axis(rotation, inputs.lateral_axis, MEASURED_AXIS_TOLERANCE_DEG)
    else:
        lateral, disagrees = int(lateral_axis), False
    if disagrees:
        log.warning("optimize: the camera rotation %.1f deg makes image axis %d lateral but /flow measured the gap "
                    "along axis %d; set camera.rotation_deg to about %.0f deg (with camera.pose = 'estimate' the "
                    "rotation is the pose search's prior; 'config' needs camera.offset_px as well) and rerun "
                    "ingest-hsc and flow", rotation, lateral, inputs.lateral_axis, rotation)
    h, w = inputs.gap_masks.shape[1:]
    camera = Camera(inputs.px_per_mm, rotation, offset, w, h)
    times = inputs.times
    dt = float(times[1] - times[0])
    field = load_model(inputs, cfg, (float(times[0]), float(times[-1] + dt)))
    model = ElasticModel(inputs.mesh, inputs.youngs_modulus_pa, inputs.poisson_ratio, inputs.density_kg_m3)
    response = QuasiStaticResponse(model, field, map=map)
    ridge = cfg.ridge_weight if cfg.ridge_weight is not None else DEFAULT_RIDGE[cfg.loads]
    settings = ObjectiveSettings(motion_weight=cfg.motion_weight, gap_weight=cfg.gap_weight,
                                 gap_length_mm=cfg.gap_length_mm, ridge_weight=ridge or 0.0, outside=cfg.motion_outside,
                                 closed_rays=cfg.gap_closed_rays, motion_slide=cfg.motion_slide,
                                 lateral_axis=lateral)
    valid = np.asarray(inputs.valid, bool)
    if cfg.gap_margin_px > 0:
        valid = valid & ~near_gap(inputs.gap_masks, cfg.gap_margin_px)[None]
    measurement = Measurement.from_gap_masks(times, velocity, valid, inputs.gap_masks, lateral)
    problem = Problem(inputs.mesh, camera, response, measurement, settings)
    curve = None
    if ridge is None:
        # the weight of the bounded free fields, from the data: the L-curve's corner on the
        # Gauss-Newton model at the start (vfcli/inverse/regularization.py)
        curve = lcurve(gauss_newton_model(problem, np.zeros(problem.n_params)), np.zeros(problem.n_params),
                       problem.penalty)
        log.info("L-curve: ridge weight %.3g 1/Pa^2", curve.chosen)
        if cfg.loads == "pressure" and curve.unbounded:
            warn_unbounded_correction(curve)
        problem = Problem(inputs.mesh, camera, response, measurement, replace(settings, ridge_weight=curve.chosen))
    return problem, Setup(rotation, (float(offset[0]), float(offset[1])), pose_source, field, curve, model)


def richer_load_problem(problem: Problem, field: LoadModel, model: ElasticModel,
                        map: Callable[..., Iterable[Any]] | None = None) -> tuple[Problem, np.ndarray] | None:
    """The fit's problem under the next richer load family, and where its control values sit in it.

    problem : the fitted problem.  field : its load model.  model : its elastic model (the response's basis
    solves of the richer shapes).  map : as :func:`build_problem`'s.

    Returns (richer problem, (n,) index of each of ``problem``'s control values in the richer one's), or None
    when the load model has no richer family (:meth:`vfcli.model.loads.pressure.PressureLoad.richer`; the free
    force fields). The ridge weighs the same per control value: its weight scales with the number of them
    (E's ridge term is ``ridge_weight x^T Omega x / n``).
    """
    if not isinstance(field, PressureLoad):
        return None
    rich = field.richer()
    response = QuasiStaticResponse(model, rich, map=map)
    settings = replace(problem.settings, ridge_weight=problem.settings.ridge_weight * rich.n_params / field.n_params)
    return Problem(problem.mesh, problem.camera, response, problem.meas, settings), field.embedding(rich)


def warn_unbounded_correction(curve) -> None:
    """Warn that the L-curve left the ``pressure`` loads' free correction practically unbounded
    (:attr:`vfcli.inverse.regularization.LCurve.unbounded`): the loads tied to the measured pressure do not
    explain the motion, the pressure gains stop carrying the load's mean, and the static shape (which the
    velocities do not see) follows the free correction. On the blind panel's inertia phantoms the inferior
    surface of such fits was 47-140 % off, against 1-8 % on the widened nulls (docs/benchmarks.md, "Session 55")."""
    log.warning("optimize: the L-curve's corner (ridge weight %.3g 1/Pa^2) lies %.1f decades below the weight at which "
                "the penalty and the data weigh alike (%.3g): the loads tied to the measured pressure do not explain "
                "the motion, so their free correction is left practically unbounded and the static shape and the "
                "inferior surface are not determined by this fit. The model may miss physics the motion shows (on "
                "phantoms: the folds' inertia); run `vfcli diagnose`, whose refit of such a term bounds its loads "
                "anew", curve.chosen, float(np.log10(curve.reference / curve.chosen)), curve.reference)


def setup_summary(setup: Setup, problem: Problem) -> dict[str, Any]:
    """The stage attributes of a :class:`Setup` and its problem (camera pose and its source, the image axis of the gap
    term's rays)."""
    return {"camera_rotation_deg": setup.rotation_deg, "camera_offset_px": np.asarray(setup.offset_px),
            "pose_source": setup.pose_source, "gap_lateral_axis": int(problem.settings.lateral_axis)}
