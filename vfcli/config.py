"""Configs: one pydantic model per subcommand, gathered in one recording-level TOML file.

Every field has a unit in its name or description, a default and a range. Models are
frozen and reject unknown keys, so a typo in ``recording.toml`` is an error, not a
silently ignored setting. The CLI loads a config once: the file (``--config``), then
``--set section.field=value`` overrides; a core function receives only its own section.
"""
from __future__ import annotations

import difflib
import json
import tomllib
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from vfcli.errors import ConfigError
from vfcli.overrides import apply_overrides, toml_limit


def _allows_bool(annotation: Any) -> bool:
    """Whether a field's type admits true/false anywhere (a bool, or a union, Literal or container holding one)."""
    if annotation is bool:
        return True
    return any(a is bool or isinstance(a, bool) or _allows_bool(a) for a in typing.get_args(annotation))


def _holds_bool(value: Any) -> bool:
    return isinstance(value, bool) or (isinstance(value, (list, tuple)) and any(_holds_bool(v) for v in value))


class _Section(BaseModel):
    # allow_inf_nan=False: NaN/inf in any float field (tuples too) is a config error at load time
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _no_bool_for_a_number(cls, data: Any) -> Any:
        """true/false where a number (or text) is meant is an error: pydantic reads `px_per_mm = true` as 1.0."""
        if isinstance(data, dict):
            for name, value in data.items():
                field = cls.model_fields.get(name)
                if field is not None and _holds_bool(value) and not _allows_bool(field.annotation):
                    raise ValueError(f"{name} = {str(value).lower()}: a number is meant here, not true/false")
        return data


#: A pixel coordinate, px (bounded: a camera frame is at most a few thousand px).
_Px = Annotated[float, Field(ge=-1e6, le=1e6)]
#: An entry of the LDV affine map (mm per mm or mm).
_AffineEntry = Annotated[float, Field(ge=-1e4, le=1e4)]
_AffineRow = tuple[_AffineEntry, _AffineEntry, _AffineEntry]
#: A pixel index or size of a region of interest, px.
_RoiInt = Annotated[int, Field(ge=0, le=10**6)]
#: A per-fold mounting offset, mm.
_OffsetMm = Annotated[float, Field(ge=-10, le=10)]
#: A per-fold mounting rotation, degrees.
_RotDeg = Annotated[float, Field(ge=-90, le=90)]
#: A number of Legendre shapes (1..8: a 3 mm medial surface meshed at 1-2 mm resolves no more).
_Shapes = Annotated[int, Field(ge=1, le=8)]


class CameraConfig(_Section):
    """Calibration of the high-speed camera (superior view), see docs/conventions.md."""

    fps_hz: float | None = Field(None, gt=0, le=1e7, description="Frame rate in Hz; null: from the video's metadata")
    px_per_mm: float = Field(20.0, gt=0, le=1000, description="Image scale from a calibration target, px/mm")
    rotation_deg: float = Field(0.0, ge=-180, le=180, description="In-plane rotation of the model frame in the image, degrees")
    offset_px: tuple[_Px, _Px] = Field(
        (0.0, 0.0), description="Pixel (col, row) of the model origin (x = 0, y = 0) in the full frame, px"
    )
    pose: Literal["estimate", "config"] = Field(
        "estimate", description="Pose of the model in the image: 'estimate' from the glottal gap (optimize), or "
        "'config': camera.rotation_deg and camera.offset_px as calibrated (zero included)"
    )

    @model_validator(mode="after")
    def _pose_is_said(self) -> "CameraConfig":
        if "pose" not in self.model_fields_set and (self.rotation_deg != 0 or any(self.offset_px)):
            raise ValueError("camera.rotation_deg/offset_px are set but camera.pose is not: set camera.pose = "
                             "'config' to use them, or 'estimate' to estimate the pose from the glottal gap")
        return self


class LdvFrameConfig(_Section):
    """How the vibrometer's point coordinates map into the camera frame (mm)."""

    affine: tuple[_AffineRow, _AffineRow] = Field(
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        description="2x3 affine map from scan (x, y) in mm to camera-frame (x, y) in mm",
    )


class IngestHscConfig(_Section):
    """`vfcli ingest-hsc`: which frames and region to keep, where the pressure is."""

    first_frame: int = Field(0, ge=0, le=10**9, description="First frame to ingest (index)")
    n_frames: int | None = Field(None, ge=1, le=10**9, description="Number of frames to ingest; null: to the end")
    roi_px: tuple[_RoiInt, _RoiInt, _RoiInt, _RoiInt] | None = Field(
        None, description="Region of interest (col0, row0, width, height) in px; null: whole frame"
    )
    pressure_group: str | None = Field(None, description="TDMS group of the pressure; null: the only one")
    pressure_channel: str | None = Field(
        None, description="Channel of the pressure: a TDMS/CSV channel name, or a WAV channel's index (0, 1, ...); "
        "null: the only one")
    pressure_unit: str | None = Field(
        None, description="Unit of the pressure values where the file states none (a TDMS channel without unit_string "
        "or NI_UnitDescription, a CSV without a unit in its header or '# unit'): Pa, hPa, kPa, mbar, bar, psi, cmH2O, "
        "mmH2O, inH2O, mmHg, or V, mV (a transducer's output: set pressure_pa_per_volt); where the file states one, "
        "it must agree; null: Pa, with a stored warning")
    pressure_pa_per_volt: float | None = Field(
        None, gt=0, le=1e9, description="Sensitivity of the pressure transducer, Pa per V, for a pressure recorded as "
        "its output voltage (a file or pressure_unit in V or mV): Pa = (V - pressure_zero_volts) * this; null: such "
        "a record is refused")
    pressure_zero_volts: float = Field(
        0.0, ge=-1000, le=1000, description="The transducer's output at zero pressure, V (with pressure_pa_per_volt)")
    compression: Literal["auto", "nbit", "gzip", "gzip4", "none"] = Field(
        "auto",
        description="Filter of the stored frames, all standard HDF5: auto (nbit for a 12-bit packed MRAW, else "
        "gzip), nbit (12 bits per pixel, uncompressed, 12-bit video only), gzip (deflate 1 + shuffle), gzip4, none",
    )
    wav_full_scale_pa: float = Field(
        10_000.0, gt=0, le=1e7, description="WAV pressure: Pa at digital full scale (a WAV states no unit: set your "
        "amplifier's calibration; the default is vfcli.io.pressure.wav's, a 10 kPa transducer range)")

    @field_validator("pressure_unit")
    @classmethod
    def _known_pressure_unit(cls, v: str | None) -> str | None:
        from vfcli.io.pressure.record import (PA_PER_UNIT, VOLTS_PER_UNIT,   # numpy: only when a unit is set
                                             is_pressure_unit, is_voltage_unit)

        if v is not None and not (is_pressure_unit(v) or is_voltage_unit(v)):
            raise ValueError(f"{v!r} is not a pressure unit vfcli knows ({', '.join(PA_PER_UNIT)}; a transducer's "
                             f"output in {', '.join(VOLTS_PER_UNIT)})")
        return v

    @field_validator("pressure_channel", mode="before")
    @classmethod
    def _channel_index_as_text(cls, v):
        """A WAV channel given as its number (``pressure_channel = 1``) is the text "1"."""
        return str(v) if isinstance(v, int) and not isinstance(v, bool) else v


class IngestLdvConfig(_Section):
    """`vfcli ingest-ldv`: scan grid and channel labels."""

    grid_rows: int = Field(17, ge=1, le=1000, description="Rows of the scan grid (points)")
    grid_cols: int = Field(22, ge=1, le=1000, description="Columns of the scan grid (points)")
    velocity_id1: str = Field("Response Time Trace", description="UFF id1 of the vibrometer channel")
    velocity_id2: str = Field(r"^\s*Vib", description="UFF id2 of the vibrometer channel, a regular expression "
                              "(case-insensitive; records stating a displacement or an acceleration are left out)")
    reference_id1: str = Field("Reference Time Trace", description="UFF id1 of the pressure reference channel")
    reference_id2: str = Field(r"^\s*Ref1", description="UFF id2 of the pressure reference channel, a regular "
                               "expression (case-insensitive)")
    velocity_unit: Literal["m/s", "mm/s", "um/s", "nm/s", "in/s"] | None = Field(
        None, description="Unit of the UFF velocity records where they state none (no ordinate axis label); null: "
        "m/s, as the vibrometer exports, with a warning; records that state one must agree")
    length_unit: Literal["m", "cm", "mm", "um", "in"] | None = Field(
        None, description="Unit of the scan point coordinates in a UFF without a units dataset (164); null: the one of "
        "m and mm that gives a plausible scan extent, with a warning (refused when neither does); files with 164 "
        "and CSV/MAT state their own")

    @field_validator("velocity_id2", "reference_id2")
    @classmethod
    def _a_regular_expression(cls, v: str) -> str:
        import re

        try:
            re.compile(v)
        except re.error as exc:
            raise ValueError(f"{v!r} is not a regular expression: {exc}") from None
        return v


class SyncConfig(_Section):
    """`vfcli sync`: pressure-based alignment of the LDV epochs to the video (see vfcli/sync/align.py)."""

    f0_min_hz: float = Field(50.0, gt=0, le=5000, description="Lowest admissible fundamental frequency, Hz")
    f0_max_hz: float = Field(500.0, gt=0, le=5000, description="Highest admissible fundamental frequency, Hz")
    max_drift: float = Field(0.05, gt=0, le=0.5, description="Largest relative f0 difference of an epoch from the video (1)")
    min_quality: float = Field(0.9, ge=0, le=1, description="Alignment quality below which a point is rejected (1)")
    n_harmonics: int = Field(10, ge=1, le=50, description="Harmonics of the pressure template (1)")
    knot_cycles: float = Field(2.0, ge=0.5, le=50, description="Knot spacing of the phase track, cycles")
    min_cycles: float = Field(2.0, ge=1, le=1000, description="Fewest full cycles an epoch must cover, cycles")
    smooth: float = Field(0.1, ge=0, le=100, description="Smoothing penalty of the phase track (1)")
    phase_reference: Literal["fundamental", "template"] = Field(
        "fundamental", description="Phase zero: peak of each record's pressure fundamental, or the video's whole waveform"
    )

    @model_validator(mode="after")
    def _f0_range(self) -> "SyncConfig":
        if not self.f0_min_hz < self.f0_max_hz:
            raise ValueError(f"f0_min_hz ({self.f0_min_hz}) must be below f0_max_hz ({self.f0_max_hz})")
        return self


def literal_choices(model: type[BaseModel], name: str) -> tuple[str, ...]:
    """The values a ``Literal`` field of ``model`` admits, in their declared order (the one
    source of the CLI's choices and of the names the core iterates over)."""
    annotation = model.model_fields[name].annotation
    if typing.get_origin(annotation) is not Literal:
        raise TypeError(f"{model.__name__}.{name} is not a Literal field")
    return typing.get_args(annotation)


#: Field tags: the stage a setting shapes (read by :func:`fields_shaping`).
_SHAPES_FLOW: dict[str, Any] = {"shapes": "flow"}
_SHAPES_FIELDS: dict[str, Any] = {"shapes": "fields"}


def fields_shaping(model: type[BaseModel], stage: str) -> tuple[str, ...]:
    """Names of the fields of ``model`` tagged as shaping store stage ``stage`` (what decides
    whether that stage is up to date)."""
    return tuple(name for name, f in model.model_fields.items()
                 if isinstance(f.json_schema_extra, dict) and f.json_schema_extra.get("shapes") == stage)


class FlowConfig(_Section):
    """`vfcli flow`: gap segmentation and optical flow (/flow), then the surface velocity field (/fields).

    Each field is tagged with the stage it shapes (``json_schema_extra={"shapes": ...}``,
    :func:`fields_shaping`): a change reruns that stage only.
    """

    method: Literal["sparse_to_dense", "dis"] = Field("sparse_to_dense", json_schema_extra=_SHAPES_FLOW, description="Optical flow method")
    threshold: float | None = Field(
        None, ge=0, le=65535,
        json_schema_extra=_SHAPES_FLOW, description="Gap intensity threshold in counts; null: automatic (minimum-error + Otsu near the gap, vfcli.flow.gap.detect)",
    )
    median_px: int = Field(5, ge=1, le=31, json_schema_extra=_SHAPES_FLOW, description="Median filter size of the gap mask, px (odd)")
    exclude_surround: bool = Field(
        True, json_schema_extra=_SHAPES_FLOW, description="Leave the folds' dark surroundings (dark in every sampled frame, "
        "thick, touching the image border: vfcli.flow.gap.surround) out of the gap masks, and out of the automatic "
        "threshold where they are as dark as the gap; false: every pixel may be gap"
    )
    subpixel_edges: bool = Field(
        True, json_schema_extra=_SHAPES_FLOW, description="Gap edges to a fraction of a pixel: a blurred-slit fit across the glottis on every ray, "
        "smoothed along the glottis and in time (vfcli.flow.gap.detect); false: the paper's binary mask (threshold + median filter)"
    )
    gap_detection: Literal["threshold", "crease"] = Field(
        "crease", json_schema_extra=_SHAPES_FLOW, description="How a ray across the glottis is found open (with subpixel_edges): "
        "'crease': darker than the ray's own closed crease (its lightest sampled dips) by 3 times their scatter, or than "
        "flow.threshold where that is higher, and darker than the crease gets in the frames where the whole glottis is "
        "closed (vfcli.flow.gap.subpixel.crease; finds the narrow phases of the cycle, not the closed line); "
        "'threshold': pixels darker than flow.threshold (the paper's)"
    )
    edge_window_mm: float = Field(
        1.0, ge=0, le=20, json_schema_extra=_SHAPES_FLOW, description="Half-window of the sub-pixel edge smoothing along the glottis, mm (0: none)"
    )
    edge_window_ms: float = Field(
        0.2, ge=0, le=10, json_schema_extra=_SHAPES_FLOW, description="Half-window of the sub-pixel edge smoothing in time, ms (0: none)"
    )
    rbf_smoothing: float = Field(0.0, ge=0, le=1e6, json_schema_extra=_SHAPES_FIELDS, description="Thin-plate-spline smoothing of the LDV fit (1)")
    sample_frames: int = Field(
        64, ge=2, le=100000,
        json_schema_extra=_SHAPES_FLOW, description="Frames sampled evenly over the video for the automatic threshold and the 8-bit intensity range",
    )
    split_folds: bool = Field(
        False, json_schema_extra=_SHAPES_FLOW, description="Optical flow of each fold separately (sharper next to the gap, twice the cost)"
    )
    grid_step: int = Field(8, ge=2, le=64, json_schema_extra=_SHAPES_FLOW, description="sparse_to_dense: spacing of the Lucas-Kanade match grid, px")
    dis_preset: Literal["ultrafast", "fast", "medium"] = Field("medium", json_schema_extra=_SHAPES_FLOW, description="dis: OpenCV DIS preset")
    ldv_skip_gap: bool = Field(
        True, json_schema_extra=_SHAPES_FIELDS,
        description="LDV spots that look through the gap in a frame (no surface returns the beam) are left out of that frame's "
        "thin-plate spline; false: every good spot in every frame (the paper)",
    )
    ldv_gap_margin_px: float = Field(
        1.0, ge=0, le=50, json_schema_extra=_SHAPES_FIELDS,
        description="A spot within this distance of the frame's gap mask looks through the gap (the spot's size, the edge's blur), px",
    )
    w_inside_hull: bool = Field(
        True, json_schema_extra=_SHAPES_FIELDS, description="Velocity valid only inside the convex hull of the good LDV points (no TPS extrapolation)"
    )

    @model_validator(mode="after")
    def _odd_median(self) -> "FlowConfig":
        if self.median_px % 2 == 0:
            raise ValueError(f"median_px ({self.median_px}) must be odd")
        return self


class MeshConfig(_Section):
    """`vfcli mesh`: the M5 model (Scherer et al. 2001, uniform glottis) and its tetrahedralisation."""

    thickness_mm: float = Field(3.0, gt=0.5, le=10, description="T: medial surface thickness incl. exit arc, mm")
    exit_radius_mm: float = Field(0.987, gt=0.05, le=5, description="R_O: radius of the exit arc, mm")
    entrance_radius_mm: float = Field(1.5, gt=0.05, le=5, description="R_L: radius of the entrance arc, mm")
    entrance_sweep_deg: float = Field(50.0, gt=0, le=90, description="Sweep of the entrance arc, degrees")
    inferior_angle_deg: float = Field(40.0, ge=0, lt=90, description="Inferior surface angle to the medial-lateral plane, degrees")
    depth_mm: float = Field(8.0, gt=2, le=20, description="D: medial-lateral depth of one fold, mm")
    length_mm: float = Field(15.0, gt=2, le=40, description="L: anterior-posterior length, mm")
    gap_mm: float = Field(0.1, ge=0, le=2, description="Pre-phonatory gap between the folds, mm")
    offset_y_mm: tuple[_OffsetMm, _OffsetMm] = Field((0.0, 0.0), description="Per-fold (left, right) lateral mounting offset, mm")
    offset_z_mm: tuple[_OffsetMm, _OffsetMm] = Field((0.0, 0.0), description="Per-fold (left, right) vertical mounting offset, mm")
    rotation_deg: tuple[_RotDeg, _RotDeg] = Field(
        (0.0, 0.0), description="Per-fold (left, right) mounting rotation about the x axis, degrees"
    )
    target_edge_mm: float = Field(
        1.5, ge=0.7, le=5, description="Target tetrahedron edge length, mm; at least 0.7: there the P2 model has "
        "167,000 unknowns per fold and assembling and factorising it took 12 min and 4 GB (cholespy; 4 s at the default "
        "1.5 mm); at 0.1 tetgen alone ran 12 min into 2.8 GB")
    min_ratio: float = Field(1.5, gt=1, le=5, description="tetgen radius-edge ratio bound (1)")
    min_dihedral_deg: float = Field(
        15.0, ge=0, le=18, description="tetgen minimum dihedral angle target, degrees: a goal of tetgen's sliver removal, not a "
        "bound (at the defaults 56 of 7352 tets stay below 15; `vfcli mesh` prints how many); at most 18: tetgen's "
        "quality refinement does not terminate above about 21 degrees on the M5 geometry (and at 20 it doubles the mesh)")
    youngs_modulus_pa: float = Field(4400.0, gt=0, le=1e8, description="Young's modulus E, Pa")
    poisson_ratio: float = Field(0.499, ge=0, lt=0.5, description="Poisson's ratio nu (1)")
    density_kg_m3: float = Field(1070.0, gt=0, le=1e5, description="Density of the silicone, kg/m^3")

    @model_validator(mode="after")
    def _m5_profile(self) -> "MeshConfig":
        """The shape fields together must make an M5 profile the mesher can build (vfcli/model/m5.py)."""
        from vfcli.model.m5 import m5_shape_problem

        problem = m5_shape_problem(self, prefix="mesh.")
        if problem is not None:
            raise ValueError(problem)
        return self


class OptimizeConfig(_Section):
    """`vfcli optimize`: load model, time window, objective and optimiser (see docs/optimize.md)."""

    setup: Literal["3x3x10-one-sided", "3x3x10-two-sided", "5x5x15-two-sided"] = Field(
        "5x5x15-two-sided", description="The paper's force-field setups: control points (u x v x t) and sides"
    )
    tie_folds: bool = Field(False, description="Mirror one fold's force field onto the other")
    method: Literal["gauss-newton", "lbfgs", "paper"] = Field(
        "gauss-newton", description="Optimiser: 'gauss-newton' (Levenberg-Marquardt on the frozen-raster Gauss-Newton "
        "model), 'lbfgs' (exact gradients), 'paper' (finite-difference gradient descent)")
    max_iterations: int = Field(60, ge=1, le=100000, description="Iteration limit")
    first_frame: int = Field(0, ge=0, le=10**9, description="First video frame of the window [T1, T2] (index)")
    n_frames: int | None = Field(
        None, ge=2, le=100000, description="Frames in the window; null (default): one glottal cycle of the video, "
        "ceil(frame rate / f0) with the video's f0 from sync (84 at 120 Hz and 10 kHz)")
    motion_weight: float = Field(1e-4, ge=0, le=1e6, description="Weight of the motion term, 1/(mm/s)^2")
    gap_weight: float = Field(1.0, ge=0, le=1e6, description="Weight of the arctan gap term (1)")
    gap_length_mm: float = Field(0.25, gt=0, le=10, description="Length scale of the gap term's arctan((d/l)^2), mm")
    gap_closed_rays: Literal["overlap-allowed", "meet", "overlap-bounded"] = Field(
        "overlap-allowed", description="Gap term on an image line the camera sees closed: 'overlap-allowed' (default): "
        "left out where the simulated folds overlap (a superior view cannot see one fold pass behind the other, and "
        "the model has no contact), a simulated gap there is asked to close where it stands; 'meet': both simulated "
        "edges are asked to meet at the last known opening location, overlap or not (before session 47); "
        "'overlap-bounded': left out while the overlap is within the widest opening the camera measured in the window, "
        "the excess beyond it charged as (d/l)^2 without the arctan's saturation (vfcli/inverse/terms/gap.py)")
    motion_slide: bool = Field(
        False, description="Motion term's gradient and Gauss-Newton model: false (default, the paper's frozen (u, v)): "
        "each pixel follows the material point the raster saw at the linearisation point; true: also the surface "
        "sliding under the pixels when a step moves it in the image plane, the first-order change E evaluated with a "
        "fresh raster sees (vfcli/inverse/terms/motion.py)")
    motion_outside: Literal["paper", "symmetric"] = Field(
        "paper", description="Motion term where only one of simulation and recording sees tissue: 'paper': only the "
        "recording's side costs |v|^2 (the paper's one-sided E); 'symmetric': the simulation's side in the measured gap "
        "costs |v_bar|^2 too (vfcli/inverse/problem.py)")
    gap_margin_px: float = Field(
        0.0, ge=0, le=100, description="Leave the motion term out within this distance (px) of the glottal gap's "
        "envelope over the window (0: off, the default): next to the open gap the vibrometer's interpolated field "
        "mixes scan points on the tissue with points that look through the gap; the gap term still places the medial "
        "edge (4 px halves the inferior error on widened phantoms but its stated uncertainty then understates, "
        "docs/benchmarks.md)")
    keep_every: int = Field(1, ge=1, le=10000, description="Store the control values of every k-th iteration")
    uncertainty: bool = Field(True, description="Compute the posterior standard deviation of every reconstructed "
                              "displacement (vfcli/inverse/uncertainty.py)")
    stop_rel_decrease: float = Field(
        1e-5, ge=0, le=1, description="Stop when an iteration lowers E by less than this fraction of E (1)"
    )
    stop_rel_change: float = Field(
        1e-3, ge=0, le=1, description="gauss-newton: stop when an accepted step changes the reconstructed displacements "
        "by less than this fraction of their RMS (1; 0: off)"
    )
    loads: Literal["free", "free-regularised", "pressure"] = Field(
        "pressure", description="Load model: 'free': the paper's force field (optimize.setup); 'free-regularised': the "
        "same bounded by a Tikhonov term (size and smoothness) whose weight the L-curve chooses; 'pressure': normal pressure "
        "on the inferior and medial surfaces, alike on both folds, tied in time to the recorded subglottal pressure "
        "(needs /hsc pressure; see vfcli/model/loads/pressure.py)"
    )
    pressure_time_degree: int = Field(4, ge=0, le=30, description="Degree of the free Bernstein correction in time of "
                                      "the pressure load model (1)")
    pressure_medial_shapes: tuple[_Shapes, _Shapes] = Field(
        (3, 2), description="Pressure load model: Legendre shapes on the medial surface (in height, even ones along the fold)"
    )
    pressure_inferior_linear: bool = Field(False, description="Pressure load model: add a linear variation along the "
                                           "fold to the uniform inferior pressure")
    pressure_band_harmonics: float | None = Field(
        10.0, gt=0, le=1000, description="Pressure load model: the recorded subglottal pressure is low-passed at this many "
        "harmonics of f0 (the video's f0 from /sync; zero phase, 4th-order Butterworth) before it drives the loads, so "
        "that its sensor noise above the band of motion does not enter every frame's load; null: used as recorded"
    )
    ridge_weight: float | None = Field(
        None, ge=0, le=1e6, description="Weight of ridge_weight * x^T Omega x / n on the control values, 1/Pa^2 (Omega: "
        "identity for the pressure model; size + squared neighbour differences for the force fields); null: the load "
        "model's default (free: 0, the paper's E; free-regularised and pressure: chosen from the data by the L-curve, "
        "vfcli/inverse/regularization.py)"
    )


class SynthConfig(_Section):
    """`vfcli synth`: a phantom recording (the fold geometry comes from the [mesh] section)."""

    effect: Literal["none", "inertia", "damping", "contact", "asymmetry", "random"] = Field(
        "none", description="Hidden physics effect; 'random' draws one and names it only in truth.h5"
    )
    strength: float | None = Field(
        None, ge=0, le=2,
        description="Effect strength; null: the effect's default (inertia: density factor 1; damping: loss factor 0.2 "
        "at f0; contact: adduction factor 1; asymmetry: left-fold softening 0.2)",
    )
    panel: Literal["default", "widened"] = Field(
        "default", description="'default': the fixed phantom of the demo; 'widened': per seed, draws (docs/synth.md) "
        "the camera in-plane angle (-180..180 deg), the zoom (field of view 0.65 x the glottis length .. 1.3 x the "
        "folds' extent; replaces px_per_mm, camera_rotation_max_deg, camera_offset_max_px; glottis centre within "
        "+-15 % of the frame), the optics blur (Gaussian sigma 0.3-3 px), fixture in view or not, the M5 geometry "
        "(T 2.5-3.5, R_O 0.8-1.2, R_L 0.9-1.1 x T/2 mm, entrance sweep 40-60 (<= 90 - inferior angle), inferior angle 30-50 deg, D 5-10, "
        "L 15-17, rest gap 0-0.3 mm), E and density within +-15 % / +-3 % of [mesh]'s nominal values, an "
        "intraglottal drive with its own lag (0-0.1 cycle), 2nd harmonic (0-30 %) and drop with the opening "
        "(0-50 %), vibrometer artefacts (2-10 % of points with spike bursts of 1-5 ms or frozen segments, replaces "
        "ldv_dropout_fraction; noise of 0.3-2 x the signal RMS through the gap) and a UFF with or without its "
        "units record (164); all drawn values go to truth.h5 only",
    )
    seed: int = Field(1, ge=0, le=2**31 - 1, description="Random seed (same seed, same bytes)")
    f0_hz: float = Field(120.0, ge=50, le=400, description="Fundamental frequency of the phonation, Hz")
    f0_drift_rel: float = Field(0.01, ge=0, le=0.05, description="Bound of the f0 random walk between LDV epochs (1)")
    mean_pressure_pa: float = Field(1000.0, ge=100, le=3000, description="Mean subglottal pressure, Pa")
    pressure_amplitude_rel: float = Field(0.6, ge=0.05, le=0.9, description="Half peak-to-peak pressure swing over the mean (1)")
    pressure_noise_pa: float = Field(4.0, ge=0, le=100, description="Pressure sensor noise, Pa RMS")
    closed_fraction: float = Field(0.25, ge=0.0, le=0.8, description="Fraction of the cycle the glottis is closed (sets the adduction)")
    load_harmonics: int = Field(4, ge=1, le=12, description="Harmonics of f0 kept in the aerodynamic load (1)")
    n_phase: int = Field(128, ge=32, le=1024, description="Phase samples per cycle for the true motion (1)")
    target_edge_mm: float = Field(1.25, ge=0.3, le=5, description="Element size of the phantom's own (true) mesh, mm")
    fps_hz: float = Field(10000.0, ge=500, le=200000, description="Camera frame rate, Hz")
    duration_s: float = Field(0.05, ge=0.002, le=2, description="Length of the video, s")
    width_px: int = Field(256, ge=32, le=2048, description="Frame width, px")
    height_px: int = Field(256, ge=32, le=2048, description="Frame height, px")
    px_per_mm: float = Field(15.0, ge=3, le=200, description="Image scale, px/mm")
    camera_rotation_max_deg: float = Field(2.0, ge=0, le=20, description="Largest unknown in-plane camera rotation, degrees")
    camera_offset_max_px: float = Field(3.0, ge=0, le=100, description="Largest unknown camera offset from the nominal centre, px")
    supersample: int = Field(2, ge=1, le=4, description="Anti-aliasing supersampling factor (1)")
    snr: float = Field(40.0, ge=5, le=1000, description="Camera signal-to-noise ratio at the surface brightness (1)")
    ldv_fs_hz: float = Field(50000.0, ge=1000, le=500000, description="Vibrometer sampling rate, Hz")
    ldv_epoch_s: float = Field(0.1, ge=0.01, le=2, description="Length of each LDV point's recording, s")
    ldv_noise_rel: float = Field(0.01, ge=0, le=0.5, description="LDV noise floor relative to the signal RMS (1)")
    ldv_dropout_fraction: float = Field(0.02, ge=0, le=0.5, description="Fraction of LDV points with signal dropouts (1)")


class DiagnoseConfig(_Section):
    """`vfcli diagnose`: the calibration of the candidates' screening (see docs/diagnose.md)."""

    replicates: int = Field(199, ge=19, le=100000, description="Bootstrap replicates of the calibrated null "
                            "(noise resampled in whole cycles, periodic model error included); p-values resolve "
                            "1 / (replicates + 1)")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="Seed of the bootstrap (the same seed gives the same p-values)")
    max_motion_rows: int = Field(20_000_000, ge=100_000, le=10**10,
                                 description="Most motion rows (3 per compared pixel and frame of the run's window) "
                                 "the diagnosis compares; a larger window is compared on every s-th pixel of every "
                                 "s-th row, s the smallest that fits. Memory grows with it: 2.0-2.8 GB peak at 3.8-3.9 "
                                 "million, 6.5 GB at 11.3 million (docs/diagnose.md)")


class RecordingConfig(_Section):
    """Everything vfcli knows about one recording, as in ``recording.toml``."""

    name: str = Field("recording", description="A label for the recording")
    camera: CameraConfig = CameraConfig()
    ldv_frame: LdvFrameConfig = LdvFrameConfig()
    ingest_hsc: IngestHscConfig = IngestHscConfig()
    ingest_ldv: IngestLdvConfig = IngestLdvConfig()
    sync: SyncConfig = SyncConfig()
    flow: FlowConfig = FlowConfig()
    mesh: MeshConfig = MeshConfig()
    optimize: OptimizeConfig = OptimizeConfig()
    diagnose: DiagnoseConfig = DiagnoseConfig()
    synth: SynthConfig = SynthConfig()


#: The models exported as JSON Schema into ``schemas/``.
SCHEMA_MODELS: dict[str, type[BaseModel]] = {
    "recording": RecordingConfig,
    "camera": CameraConfig,
    "ldv_frame": LdvFrameConfig,
    "ingest_hsc": IngestHscConfig,
    "ingest_ldv": IngestLdvConfig,
    "sync": SyncConfig,
    "flow": FlowConfig,
    "mesh": MeshConfig,
    "optimize": OptimizeConfig,
    "diagnose": DiagnoseConfig,
    "synth": SynthConfig,
}


def _unknown_setting(loc: tuple[Any, ...]) -> str:
    """'camera.px_per_m: unknown setting (did you mean camera.px_per_mm?)': the nearest known key
    of the same section (difflib), else the section's keys."""
    model: type[BaseModel] = RecordingConfig
    for part in loc[:-1]:
        field = model.model_fields.get(str(part))
        if field is None or not (isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)):
            return f"{'.'.join(map(str, loc))}: unknown setting"
        model = field.annotation
    prefix = "".join(f"{p}." for p in loc[:-1])
    known = list(model.model_fields)
    near = difflib.get_close_matches(str(loc[-1]), known, n=1, cutoff=0.6)
    hint = f"did you mean {prefix}{near[0]}?" if near else f"known: {', '.join(prefix + k for k in known)}"
    return f"{prefix}{loc[-1]}: unknown setting ({hint})"


def _one_line(exc: ValidationError, source: str) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if err["type"] == "extra_forbidden":
            parts.append(_unknown_setting(tuple(err["loc"])))
        elif isinstance(err.get("input"), dict):  # a rule across the fields of a section (our own words)
            parts.append(f"{loc}: {err['msg'].removeprefix('Value error, ')}")
        else:
            parts.append(f"{loc} = {err.get('input')!r}: {err['msg']}")
    return f"{source}: invalid config: " + "; ".join(parts)


def _validate(data: dict[str, Any], source: str) -> RecordingConfig:
    try:
        return RecordingConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_one_line(exc, source)) from None


def load_config(
    path: str | Path | None = None, stored_json: str | None = None, overrides: list[str] | None = None
) -> tuple[RecordingConfig, RecordingConfig]:
    """The recording config to store and the one to run with.

    Parameters
    ----------
    path
        ``recording.toml`` given with ``--config``; it replaces the stored config.
    stored_json
        The config stored in the recording's store, used when no file is given.
    overrides
        ``--set section.field=value`` items: they apply to this run only.

    Returns
    -------
    (stored, effective)
        ``stored`` goes into the store; ``effective`` (stored + overrides) drives the run.
    """
    if path is not None:
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"{path}: config file not found") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: not valid TOML ({exc})") from None
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the config ({exc.strerror or exc})") from None
        except (RecursionError, ValueError, MemoryError) as exc:  # 100,000-deep nesting, 5,000-digit integers
            raise ConfigError(f"{path}: {toml_limit(exc)}") from None
        stored = _validate(data, str(path))
    elif stored_json:
        stored = _validate(json.loads(stored_json), "stored recording config")
    else:
        stored = RecordingConfig()
    effective = stored
    if overrides:
        # from the values set so far: what --set gives counts as set (a calibration stated at its default value
        # is stated; camera.rotation_deg given without camera.pose is refused as in a config file)
        effective = _validate(apply_overrides(stored.model_dump(mode="json", exclude_unset=True), overrides), "--set")
    return stored, effective


def persist_overrides(stored: RecordingConfig, overrides: list[str]) -> RecordingConfig:
    """The stored config with ``--set section.field=value`` items applied, to be stored
    (`vfcli config FILE --set ...`); only the values given so far count as set."""
    return _validate(apply_overrides(stored.model_dump(mode="json", exclude_unset=True), overrides), "--set")


def export_schemas(out_dir: str | Path) -> list[Path]:
    """Write one JSON Schema per config model into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, model in SCHEMA_MODELS.items():
        p = out_dir / f"{name}.schema.json"
        p.write_text(json.dumps(model.model_json_schema(), indent=2, sort_keys=True) + "\n")
        written.append(p)
    return written
