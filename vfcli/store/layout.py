"""The store layout: every group and dataset of a vfcli store, with units and axes.

This module is the one place that names HDF5 paths. Stage modules refer to datasets
by the keys declared here; :mod:`vfcli.store.transaction` turns them into paths, attaches the
units and makes every axis an HDF5 dimension scale (:data:`AXES`). ``docs/store-layout.md``
is generated from this table (``vfcli schemas`` writes it), so the documentation
cannot drift from the code.

A store has one group per stage (``/hsc``, ``/ldv``, ``/sync`` ...). Stages that can
run several times with different settings (``optimize``, ``diagnose``) keep one
subgroup per run: ``/optimize/<run>``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

FORMAT_NAME = "vfcli-store"
FORMAT_VERSION = 1

#: Root attribute holding the recording's config (JSON of :class:`vfcli.config.RecordingConfig`).
ROOT_CONFIG_ATTR = "recording_config_json"

#: Root attribute holding the SHA-256 of the config file (recording.toml) the stored config was last read
#: from (absent: never stored from a file). `vfcli run --raw` reads the raw folder's recording.toml again
#: only when its content differs from that file's, so a value set since with `vfcli config` stays.
ROOT_CONFIG_FILE_ATTR = "recording_config_file_sha256"

#: Stage-group attribute holding what the stage run reported: its figures (the summary the
#: command prints) and the warnings it logged, as JSON ``{"figures": {...}, "warnings": [...]}``.
SUMMARY_ATTR = "summary_json"

#: Stage-group attribute holding the stage's manifest: each dataset's shape, dtype and SHA-256,
#: and the SHA-256 of the group's other attributes (:mod:`vfcli.store.integrity`).
MANIFEST_ATTR = "manifest_json"

#: Stage-group attribute holding the version of the stage's method that wrote it (:attr:`Stage.method`;
#: absent in stages written before vfcli recorded it, which count as version 1).
METHOD_ATTR = "method_version"

#: Stages kept in their own part file beside the store file, external-linked from it
#: (:mod:`vfcli.store.parts`): every stage whose size grows with the recording (frames, LDV
#: points and samples). Only /mesh (a few hundred kB) stays in the store file.
PART_STAGES = frozenset({"hsc", "ldv", "sync", "flow", "fields", "optimize", "diagnose"})

#: Attributes every stage group carries (its provenance).
PROVENANCE_ATTRS = (
    "stage",
    "vfcli_version",
    "command",
    "created_utc",
    "config_json",
    "inputs_json",
    "upstream_json",
    "digest",
)


@dataclass(frozen=True)
class Dataset:
    """One dataset of a stage.

    Parameters
    ----------
    units
        Physical unit of the values (``"1"`` for dimensionless, ``"bool"``, ``"index"``).
    description
        One line, shown in ``docs/store-layout.md`` and as the dataset's ``description``.
    dims
        Name of each axis; an axis named after another dataset of the same stage
        (``"frame_time"``) is attached to it as an HDF5 dimension scale.
    frame_chunked
        Large per-frame arrays: chunked one frame (first axis) per chunk and compressed.
    """

    units: str
    description: str
    dims: tuple[str, ...] = ()
    frame_chunked: bool = False


@dataclass(frozen=True)
class Stage:
    """A stage group: which command writes it, what it reads, what it holds."""

    name: str
    written_by: str
    description: str
    reads: tuple[str, ...] = ()
    datasets: dict[str, Dataset] = field(default_factory=dict)
    has_runs: bool = False
    #: Version of the stage's method: raised when a code change alters what the stage computes from
    #: the same inputs and config, so a stage written by an older method shows as stale
    #: (:meth:`vfcli.store.reader.StoreReader.status`) and ``vfcli run`` writes it again.
    method: int = 1
    #: What changed at each version above 1, ``{version: one line}`` (shown as the reason).
    method_changes: dict[int, str] = field(default_factory=dict)

    def group_path(self, run: str | None = None) -> str:
        """HDF5 path of the stage group (``/optimize/<run>`` for stages with runs)."""
        if self.has_runs:
            if not run:
                raise ValueError(f"stage {self.name!r} needs a run name")
            return f"/{self.name}/{run}"
        return f"/{self.name}"


D = Dataset


@dataclass(frozen=True)
class Axis:
    """An axis that is not a dataset of its stage (time axes are): stored beside the
    datasets under its own name as an HDF5 dimension scale, so that netCDF readers
    (xarray) see named dimensions. Its values are ``labels`` (text) when given, else the
    0-based index along the axis."""

    description: str
    labels: tuple[str, ...] = ()


#: Every axis name used in :data:`STAGES` that is not a dataset of its stage. Pixel axes
#: are (row, col) everywhere: frames are (frame, row, col), 0-based from the top-left
#: pixel; only ``/fields/ldv_px`` stores screen positions as (col, row), as its axis says.
AXES: dict[str, Axis] = {
    "row": Axis("Pixel row from the top of the frame (0-based index)"),
    "col": Axis("Pixel column from the left of the frame (0-based index)"),
    "point": Axis("LDV scan point (0-based index, in the order of /ldv)"),
    "sample": Axis("LDV sample within a point's record (0-based index; /ldv attribute fs_hz gives the rate)"),
    "rc": Axis("Component: grid row, grid column", ("row", "col")),
    "colrow": Axis("Component: screen column, screen row", ("col", "row")),
    "xyz": Axis("Component: x, y, z", ("x", "y", "z")),
    "xy": Axis("Component: x, y", ("x", "y")),
    "uv": Axis("Component: u, v", ("u", "v")),
    "surface_uv": Axis("Surface coordinate: u, v", ("u", "v")),
    "uvw": Axis("Component: u, v, w", ("u", "v", "w")),
    "node": Axis("Mesh node (0-based index)"),
    "tet": Axis("Tetrahedron (0-based index)"),
    "tet_corner": Axis("Corner of a tetrahedron (0-based index)"),
    "face": Axis("Boundary triangle (0-based index)"),
    "face_corner": Axis("Corner of a boundary triangle (0-based index)"),
    "param": Axis("Control value (0-based index; parameter_names names them)"),
    "kept": Axis("Kept iteration (0-based index; kept_iterations gives the iteration)"),
    "iteration": Axis("Entry of the history (0-based index; history_iteration gives the iteration)"),
    "lcurve": Axis("Weight of the L-curve scan (0-based index)"),
    "region": Axis("Motion region: fold x band across x band along (0-based index; region_name names them)"),
    "gap_region": Axis("Gap region: fold x band along the medial edge (0-based index; gap_region_name names them)"),
    "component": Axis("Velocity component in model axes", ("longitudinal", "lateral", "vertical")),
    "gap_component": Axis("Gap residual component", ("medial edge position",)),
    "cycle_phase": Axis("Phase of the glottal cycle", ("opening", "open", "closing", "closed")),
    "harmonic": Axis("Harmonic of f0 (0-based index: index k - 1 is the k-th harmonic)"),
    "hotspot": Axis("Tested part of the residual, most significant first (0-based index)"),
    "candidate": Axis("Candidate physics term screened (0-based index; candidate_name names them)"),
    "refit_param": Axis("Parameter of the candidate term a confirmation refit fitted (0-based index; "
                        "refit_parameter_name names them)"),
    "cycle_split": Axis("Held-out split leaving one glottal cycle of the window out (0-based index)"),
    "instrument_split": Axis("Glottal cycle of the window on which the vertical velocity predicted from the "
                             "camera is scored (0-based index)"),
    "replicate": Axis("Parametric bootstrap replicate of the calibrated screening (0-based index)"),
}

#: the datasets of a confirmation refit's candidate parameters (in /optimize/<run>+<candidate> and /diagnose/<run>)
_REFIT_PARAMS = {
    "refit_parameter_name": D("text", "Confirmation refit by `vfcli diagnose`: name (with units) of each "
                              "parameter of the candidate term (attribute refit_candidate names it)",
                              ("refit_param",)),
    "refit_theta": D("1", "Confirmation refit: fitted value of each candidate parameter (units in its name); in "
                     "/diagnose/<run> corrected for the fit mesh's discretisation where the term states it (inertia: "
                     "confirmation_json's fit_mesh_estimate and mesh_shift, vfcli/diagnose/confirmation.py "
                     "mesh_corrected), in the refit run the fit mesh's value its displacements are at",
                     ("refit_param",)),
    "refit_theta_sd": D("1", "Confirmation refit: stated standard deviation of each candidate parameter (the "
                        "sandwich over frames, vfcli/diagnose/refit.py, or the held-out fits' jackknife where larger, "
                        "plus the camera-only fit's difference: vfcli/diagnose/confirmation.py heldout_sd)", ("refit_param",)),
}

STAGES: dict[str, Stage] = {
    s.name: s
    for s in [
        Stage(
            "hsc",
            "ingest-hsc",
            "High-speed video of the superior surface and the subglottal pressure recorded with it.",
            datasets={
                "frames": D("counts", "Video frames, unchanged bit depth", ("frame_time", "row", "col"), True),
                "frame_time": D("s", "Time of each frame from the first frame", ("frame_time",)),
                "pressure": D("Pa", "Subglottal pressure recorded with the video", ("pressure_time",)),
                "pressure_time": D("s", "Time of each pressure sample, video time base", ("pressure_time",)),
            },
        ),
        Stage(
            "ldv",
            "ingest-ldv",
            "Scanning-vibrometer grid: one epoch per point, with the pressure reference channel.",
            datasets={
                "node_id": D("index", "Scan point number in the source file", ("point",)),
                "grid_index": D("index", "(row, col) of each point in the scan grid", ("point", "rc")),
                "coords_mm": D("mm", "Point coordinates in the camera frame (x, y, z)", ("point", "xyz")),
                "velocity": D("mm/s", "Vertical surface velocity per point", ("point", "sample")),
                "reference": D("Pa", "Pressure reference channel recorded with each point (V when uncalibrated)", ("point", "sample")),
                "epoch_t0": D("s", "Start time of each point's record as written by the vibrometer", ("point",)),
                "dropout": D("bool", "Point whose signal drops out (flagged, kept)", ("point",)),
                "dropout_reason": D("text", "Why a point was flagged", ("point",)),
            },
        ),
        Stage(
            "sync",
            "sync",
            "LDV epochs mapped onto the video's time base through the subglottal pressure.",
            reads=("hsc", "ldv"),
            datasets={
                "offset_s": D("s", "Start of each LDV epoch relative to the video's phase reference", ("point",)),
                "f0_hz": D("Hz", "Fundamental frequency of each LDV epoch", ("point",)),
                "drift": D("1", "Relative f0 difference of each epoch against the video", ("point",)),
                "drift_rate_per_s": D("1/s", "Linear trend of each epoch's f0 relative to its mean", ("point",)),
                "n_cycles": D("1", "Cycles averaged per point", ("point",)),
                "video_phase": D("cycles", "Cycle phase of the video at each frame", ("frame_time",)),
                "quality": D("1", "Alignment quality in [0, 1]", ("point",)),
                "ok": D("bool", "Point aligned", ("point",)),
                "reason": D("text", "Why a point could not be aligned", ("point",)),
                "aligned_w": D("mm/s", "Vertical velocity on the video frame times", ("point", "frame_time")),
                "frame_time": D("s", "Video frame times", ("frame_time",)),
            },
        ),
        Stage(
            "flow",
            "flow",
            "Gap mask, glottal area, opening function and horizontal optical flow per frame.",
            reads=("hsc",),
            method=5,
            method_changes={2: "a ray shows the gap only where it is darker than the closed crease gets there (the "
                               "closed line of sharp optics was read as a slit; with it, the gap steps of sessions "
                               "30-38: the blur beside dark walls, the taper limit)",
                            3: "the gap's blur is never read sharper than a pixel blurs (1 / sqrt(12) px): a lit rim at "
                               "the gap's edge had read 0.2 px under sharp optics, the slit a few per cent narrow",
                            4: "dark surroundings cut into pieces are fixture, not gap: a piece reaching a lateral image "
                               "border on more than half of its own rays (each piece "
                               "shorter than half a border had passed as gap and set the glottal midline)",
                            5: "the folds' dark surroundings (dark in every sampled frame) are left out of the gap "
                               "threshold and masks (flow.exclude_surround): the threshold had been read from a "
                               "surround as dark as a blurred slit, and the mask took the silicone's texture for gap"},
            datasets={
                "gap_mask": D("bool", "Glottal gap per frame", ("frame_time", "row", "col"), True),
                "glottal_area": D("mm^2", "Glottal area waveform", ("frame_time",)),
                "opening": D("mm", "Gap opening function o(y, t)", ("frame_time", "row", "col"), True),
                "flow": D("mm/s", "Horizontal surface velocity (u, v)", ("frame_time", "row", "col", "uv"), True),
                "frame_time": D("s", "Time at which each flow frame applies", ("frame_time",)),
            },
        ),
        Stage(
            "fields",
            "flow",
            "Tri-variate surface velocity field v(y, t) = (u, v, w) on the pixel grid.",
            reads=("flow", "sync", "ldv"),
            datasets={
                "velocity": D("mm/s", "Surface velocity (u, v, w); float32 rounded to 12 stored mantissa bits "
                              "(relative error below 1.3e-4, attribute mantissa_bits)",
                              ("frame_time", "row", "col", "uvw"), True),
                "valid": D("bool", "Fold surface visible (velocity valid)", ("frame_time", "row", "col"), True),
                "frame_time": D("s", "Frame times", ("frame_time",)),
                "ldv_px": D("px", "Screen position (col, row) of each LDV point", ("point", "colrow")),
                "ldv_used": D("bool", "LDV point used by the thin-plate spline (aligned, no dropout)", ("point",)),
            },
        ),
        Stage(
            "mesh",
            "mesh",
            "Tetrahedral M5 model of both folds with tagged boundary and (u, v) surface maps.",
            datasets={
                "nodes": D("mm", "Node coordinates (x, y, z)", ("node", "xyz")),
                "tets": D("index", "Tetrahedra (node indices)", ("tet", "tet_corner")),
                "tet_fold": D("index", "Fold of each tetrahedron (0 left, 1 right)", ("tet",)),
                "faces": D("index", "Boundary triangles (node indices, outward)", ("face", "face_corner")),
                "face_tag": D("index", "1 inferior, 2 superior, 3 medial, 4 fixture", ("face",)),
                "face_fold": D("index", "Fold of each boundary triangle", ("face",)),
                "uv": D("1", "(u, v) surface coordinates, NaN off the parameterised sides", ("node", "surface_uv")),
                "node_side": D("index", "0 none, 1 inferior side, 2 superior side", ("node",)),
            },
        ),
        Stage(
            "optimize",
            "optimize",
            "One optimisation run: force-field control values, history and the reconstructed motion.",
            reads=("mesh", "fields", "flow", "hsc"),
            has_runs=True,
            method=9,
            method_changes={2: "the model's velocity at the frame times (central differences), no longer half a "
                               "frame later (vfcli 2c4c8b6)",
                            3: "the L-curve scans 16 decades of ridge weight, to its real corner (it stopped on "
                               "the curve's vertical branch, where the corner is round-off)",
                            4: "the stated uncertainty's instrument part compares single-instrument fits with the "
                               "ridge centred on the joint fit (centred on 0, the ridge's own bias pulled them apart "
                               "and the stated uncertainty was several times too wide)",
                            5: "the estimated pose places mid-length by the motion's symmetry with both ends of the "
                               "gap in view too (the midpoint of the gap's extent was off where the opening is "
                               "wider toward one end)",
                            6: "a ray the camera sees closed asks a simulated gap on it to close where it stands, not "
                               "at the last known opening location (E jumped where the folds started to overlap)",
                            7: "the estimated pose searches mid-length by the motion's symmetry wherever the glottis "
                               "covers the visible gap (a gap found over part of the glottis, away from its middle, "
                               "left mid-length outside the search and the gap's envelope placed it 8 mm off)",
                            8: "the stated uncertainty measures what the load model leaves open (the velocities-only "
                               "against the gap-only reconstruction, and a step into the next richer pressure load "
                               "family) in place of the expected bias of the pressure gains' 1e-6 ridge share, which "
                               "followed the share, not the data",
                            9: "the stated uncertainty adds how far the fit moves across the width of the L-curve's "
                               "corner (the ridge weights where its curvature falls to half the corner's)"},
            datasets={
                "sim_time": D("s", "Model times: the window's frame times and one step after", ("sim_time",)),
                "displacements": D("mm", "Reconstructed vertex displacements", ("sim_time", "node", "xyz"), True),
                "controls": D("Pa", "Final control values of the force field", ("param",)),
                "parameter_names": D("text", "Name of each control value", ("param",)),
                "kept_iterations": D("index", "Iterations whose control values are kept", ("kept",)),
                "kept_controls": D("Pa", "Control values at the kept iterations", ("kept", "param")),
                "history_iteration": D("index", "Iteration number", ("iteration",)),
                "history_total": D("1", "Error E at each iteration", ("iteration",)),
                "history_motion": D("1", "Motion term of E", ("iteration",)),
                "history_gap": D("1", "Gap term of E", ("iteration",)),
                "history_step": D("1", "Step length of each iteration", ("iteration",)),
                "history_wall_time": D("s", "Wall time since the start of the run", ("iteration",)),
                "history_n_evals": D("1", "Objective evaluations so far", ("iteration",)),
                "history_ridge": D("1", "Ridge (Tikhonov) term of E", ("iteration",)),
                "displacement_std": D("mm", "Standard deviation of each reconstructed displacement component: "
                                      "the fit's mean squared error (sandwich covariance and the ridge's expected bias, "
                                      "vfcli/inverse/sandwich.py) and the splits' systematic parts (the instruments, "
                                      "the kinds of data, the load family, the L-curve corner's width; "
                                      "vfcli/inverse/uncertainty.py) in quadrature; absent "
                                      "with optimize.uncertainty = false and in diagnose's refit runs (<run>+<term>), "
                                      "which state their parameter's interval (refit_theta_sd)",
                                      ("sim_time", "node", "xyz"), True),
                "displacement_std_instruments": D("mm", "Systematic part of displacement_std: RMS over time of the "
                                                  "difference between the camera-only and the vibrometer-only "
                                                  "reconstructions, / sqrt 2", ("node", "xyz")),
                "displacement_std_static": D("mm", "Standard deviation of the static part of each displacement "
                                             "component (its mean over the window): the fit's and the splits' "
                                             "parts in quadrature", ("node", "xyz")),
                "lcurve_weight": D("1/Pa^2", "Tikhonov weights scanned by the L-curve (free-regularised)", ("lcurve",)),
                "lcurve_misfit": D("1", "Predicted data misfit E_data at each weight", ("lcurve",)),
                "lcurve_penalty": D("Pa^2", "Penalty x^T Omega x at each weight", ("lcurve",)),
                "history_theta": D("1", "Confirmation refit: the candidate's parameters at each iteration",
                                   ("iteration", "refit_param")),
                **_REFIT_PARAMS,
            },
        ),
        Stage(
            "diagnose",
            "diagnose",
            "Missing-physics diagnosis of one optimisation run: Locate (the residual by where, when, component "
            "and harmonic of f0, against a noise floor from the recording itself), the candidates' screening and its "
            "bootstrap calibration, and the decision (attrs decision, alpha_family).",
            reads=("optimize", "mesh", "fields", "flow", "ldv", "sync"),
            has_runs=True,
            method=9,
            method_changes={2: "the model's velocity at the frame times in every motion row (vfcli 2c4c8b6)",
                            3: "a refit confirms a finding only when it lowers E below the baseline's (a refit that "
                               "kept no step had confirmed on its held-out fits alone; session 51)",
                            4: "the leads are refitted in turn until one is confirmed, at most three (a second "
                               "calibrated lead had not been refitted; session 52)",
                            5: "every lead is refitted and the confirmed one whose refit predicts held-out data best "
                               "is named (the first confirmed had been, though a later lead explained the residual "
                               "better; session 53)",
                            6: "a one-sided term (contact, damping) is refitted on its physical side only, and a "
                               "held-out fit that switches it off predicts as the baseline (a camera-only contact "
                               "fit had pulled the folds through the midplane; session 54)",
                            7: "the refit of a term with its own response (inertia, damping) bounds the loads' free "
                               "correction at its own L-curve corner where optimize chose the baseline's so (an "
                               "inertia refit kept its quasi-static baseline's near-zero bound and lost the static "
                               "shape; session 55)",
                            8: "a refit that never left the value it started from (contact's full share) confirms no "
                               "finding: it estimates nothing (nulls 2061 and 2139 had been named contact on its "
                               "held-out fits; session 65)",
                            9: "a refit confirms no finding where the baseline lacks its term's signature: contact's "
                               "crossing of the midplane must come with the closure (null 2348 had been named contact "
                               "on a crossing its fit held open as closed; session 77)"},
            datasets={
                "frame_time": D("s", "Times of the run's window frames", ("frame_time",)),
                "frame_phase": D("cycles", "Glottal cycle phase of each window frame (from the gap area)", ("frame_time",)),
                "frame_cycle_phase": D("index", "Phase of the cycle of each window frame: 0 opening, 1 open, 2 closing, 3 closed", ("frame_time",)),
                "region_name": D("text", "Name of each motion region", ("region",)),
                "gap_region_name": D("text", "Name of each gap region", ("gap_region",)),
                "pixel_region": D("index", "Motion region the model shows at each pixel, -1 none (on every s-th pixel of every "
                                  "s-th row only, attr pixel_stride s)", ("row", "col")),
                "rms_residual": D("mm/s", "RMS over the window of the measured minus simulated velocity (compared on every "
                                  "s-th pixel of every s-th row, attr pixel_stride s: each grid pixel's value fills its "
                                  "block)", ("row", "col", "component")),
                "motion_phase_mean": D("mm/s", "Surface velocity: mean residual (measured minus simulated) over each phase of the cycle", ("region", "component", "cycle_phase")),
                "motion_phase_sd": D("mm/s", "Surface velocity: noise floor (standard deviation) of that mean", ("region", "component", "cycle_phase")),
                "motion_phase_dof": D("1", "Surface velocity: degrees of freedom of the noise floor (whole cycles)", ("region", "component", "cycle_phase")),
                "motion_phase_p": D("1", "Surface velocity: p-value of the phase mean (F(1, dof) test), NaN: not tested", ("region", "component", "cycle_phase")),
                "motion_harmonic_amplitude": D("mm/s", "Surface velocity: amplitude A_k of harmonic k of f0 (residual ~ A_k cos(2 pi k phase + theta_k))", ("region", "component", "harmonic")),
                "motion_harmonic_phase": D("rad", "Surface velocity: phase theta_k of harmonic k", ("region", "component", "harmonic")),
                "motion_harmonic_sd": D("mm/s", "Surface velocity: noise floor (standard deviation) of a cosine or sine coefficient", ("region", "component", "harmonic")),
                "motion_harmonic_dof": D("1", "Surface velocity: degrees of freedom of the harmonic's noise floor", ("region", "component", "harmonic")),
                "motion_harmonic_p": D("1", "Surface velocity: p-value of harmonic k (F(2, dof) test), NaN: not tested", ("region", "component", "harmonic")),
                "gap_phase_mean": D("mm", "Gap silhouette (medial positive): mean residual (measured minus simulated) over each phase of the cycle", ("gap_region", "gap_component", "cycle_phase")),
                "gap_phase_sd": D("mm", "Gap silhouette (medial positive): noise floor (standard deviation) of that mean", ("gap_region", "gap_component", "cycle_phase")),
                "gap_phase_dof": D("1", "Gap silhouette (medial positive): degrees of freedom of the noise floor (whole cycles)", ("gap_region", "gap_component", "cycle_phase")),
                "gap_phase_p": D("1", "Gap silhouette (medial positive): p-value of the phase mean (F(1, dof) test), NaN: not tested", ("gap_region", "gap_component", "cycle_phase")),
                "gap_harmonic_amplitude": D("mm", "Gap silhouette (medial positive): amplitude A_k of harmonic k of f0 (residual ~ A_k cos(2 pi k phase + theta_k))", ("gap_region", "gap_component", "harmonic")),
                "gap_harmonic_phase": D("rad", "Gap silhouette (medial positive): phase theta_k of harmonic k", ("gap_region", "gap_component", "harmonic")),
                "gap_harmonic_sd": D("mm", "Gap silhouette (medial positive): noise floor (standard deviation) of a cosine or sine coefficient", ("gap_region", "gap_component", "harmonic")),
                "gap_harmonic_dof": D("1", "Gap silhouette (medial positive): degrees of freedom of the harmonic's noise floor", ("gap_region", "gap_component", "harmonic")),
                "gap_harmonic_p": D("1", "Gap silhouette (medial positive): p-value of harmonic k (F(2, dof) test), NaN: not tested", ("gap_region", "gap_component", "harmonic")),
                "hotspot_family": D("text", "Residual family of each part: motion or gap", ("hotspot",)),
                "hotspot_kind": D("text", "phase (mean over a phase of the cycle) or harmonic", ("hotspot",)),
                "hotspot_region": D("index", "Region of the part (into region_name or gap_region_name)", ("hotspot",)),
                "hotspot_component": D("index", "Component of the part", ("hotspot",)),
                "hotspot_index": D("index", "Phase of the cycle (kind phase) or harmonic number k (kind harmonic)", ("hotspot",)),
                "hotspot_ratio": D("1", "Size of the part in units of its noise floor (sqrt of the F statistic)", ("hotspot",)),
                "hotspot_p": D("1", "p-value of the part", ("hotspot",)),
                "hotspot_p_adjusted": D("1", "Holm-adjusted p-value over all parts (family-wise)", ("hotspot",)),
                "candidate_name": D("text", "Name of each candidate physics term screened (absent: none screened)", ("candidate",)),
                "candidate_statistic": D("1", "Screening statistic of each candidate", ("candidate",)),
                "candidate_p": D("1", "p-value of each candidate's screening (null: the term is absent)", ("candidate",)),
                "candidate_identifiable": D("bool", "False: the load model can absorb the term (not identifiable with it)", ("candidate",)),
                "candidate_words": D("text", "Each candidate's finding in plain words", ("candidate",)),
                "candidate_p_calibrated": D("1", "Bootstrap-calibrated p-value of each candidate alone (null: noise "
                                            "resampled in whole cycles plus the periodic model error no candidate "
                                            "explains; attrs calibration_replicates, calibration_seed)", ("candidate",)),
                "candidate_p_family": D("1", "Family-wise (Westfall-Young min-p over all candidates) calibrated "
                                        "p-value; a lead when at most attrs alpha_family", ("candidate",)),
                "candidate_statistic_studentized": D("1", "The calibrated test's statistic: the candidate's efficient "
                                                     "score studentized by its noise covariance over the whole-cycle "
                                                     "stretches of the recording", ("candidate",)),
                "candidate_null_statistic": D("1", "The bootstrap replicates of that statistic under the null",
                                              ("candidate", "replicate")),
                **_REFIT_PARAMS,
                "heldout_cycles_baseline": D("mm/s", "RMS velocity error of the baseline on each cycle left out of its "
                                             "refit", ("cycle_split",)),
                "heldout_cycles_extended": D("mm/s", "The same for the baseline extended by the refitted candidate",
                                             ("cycle_split",)),
                "heldout_instruments_baseline": D("mm/s", "RMS error of the vertical velocity predicted by the baseline "
                                                  "fitted to the camera, gap and pressure only, per cycle",
                                                  ("instrument_split",)),
                "heldout_instruments_extended": D("mm/s", "The same for the baseline extended by the candidate",
                                                  ("instrument_split",)),
            },
        ),
    ]
}


#: The phantom's ``truth.h5`` (written by `vfcli synth`, read only by tests and benchmarks):
#: key -> dataset. Root attributes: effect, strength, seed, config_json, camera_*, adduction_mm.
TRUTH: dict[str, Dataset] = {
    "mesh/nodes": D("mm", "Rest positions of the phantom's own mesh (with the adduction)", ("node", "xyz")),
    "mesh/tets": D("index", "Tetrahedra", ("tet", "corner")),
    "mesh/tet_fold": D("index", "Fold of each tetrahedron", ("tet",)),
    "mesh/faces": D("index", "Boundary triangles", ("face", "corner")),
    "mesh/face_tag": D("index", "1 inferior, 2 superior, 3 medial, 4 fixture", ("face",)),
    "mesh/face_fold": D("index", "Fold of each boundary triangle", ("face",)),
    "mesh/uv": D("1", "(u, v) surface coordinates", ("node", "uv")),
    "mesh/node_side": D("index", "0 none, 1 inferior side, 2 superior side", ("node",)),
    "motion/coeffs_real": D("mm", "Fourier coefficients of the vertex displacement over one cycle (real)", ("harmonic", "node", "xyz")),
    "motion/coeffs_imag": D("mm", "Fourier coefficients (imaginary part)", ("harmonic", "node", "xyz")),
    "motion/load_coefficients": D("Pa", "Aerodynamic load pattern coefficients over one cycle", ("phase", "pattern")),
    "frames/time": D("s", "Frame times", ("frame",)),
    "frames/phase": D("cycles", "Cycle phase at each frame", ("frame",)),
    "frames/displacement": D("mm", "Vertex displacements at the frame times", ("frame", "node", "xyz"), True),
    "frames/velocity": D("mm/s", "Vertex velocities at the frame times", ("frame", "node", "xyz"), True),
    "screen/velocity": D("mm/s", "True screen-space surface velocity (x, y, z), NaN off the folds", ("frame", "row", "col", "xyz"), True),
    "screen/gap": D("bool", "True glottal gap at the pixel centres", ("frame", "row", "col"), True),
    "screen/visible": D("bool", "Fold surface visible", ("frame", "row", "col"), True),
    "screen/glottal_area": D("mm^2", "True glottal area", ("frame",)),
    "ldv/points_model_mm": D("mm", "Scan points in the model frame (x, y)", ("point", "xy")),
    "ldv/points_camera_mm": D("mm", "Scan points in the camera frame as written to the scan file", ("point", "xy")),
    "ldv/start_phase": D("cycles", "Cycle phase at each epoch's first sample", ("point",)),
    "ldv/f0_hz": D("Hz", "Fundamental during each epoch", ("point",)),
    "ldv/sync_offset_s": D("s", "Epoch time whose phase equals the first frame's (what sync estimates)", ("point",)),
    "ldv/dropout_kind": D("index", "0 none, 1 spikes, 2 flat", ("point",)),
    "ldv/clean_velocity": D("mm/s", "True vertical velocity at each point, NaN where no surface", ("point", "sample")),
    "pressure/true_pa": D("Pa", "True subglottal pressure beside the video", ("sample",)),
    "pressure/phase": D("cycles", "Cycle phase at each pressure sample", ("sample",)),
}


def stage(name: str) -> Stage:
    """The :class:`Stage` called ``name``; ``KeyError`` lists the known ones."""
    try:
        return STAGES[name]
    except KeyError:
        raise KeyError(f"unknown stage {name!r}; known: {', '.join(STAGES)}") from None


def dataset_path(stage_name: str, key: str, run: str | None = None) -> str:
    """HDF5 path of dataset ``key`` of a stage; ``KeyError`` if the layout does not declare it."""
    st = stage(stage_name)
    if st.datasets and key not in st.datasets:
        raise KeyError(f"stage {stage_name!r} declares no dataset {key!r}")
    return f"{st.group_path(run)}/{key}"


def layout_markdown() -> str:
    """The layout as a Markdown page (written to ``docs/store-layout.md``)."""
    lines = [
        "# Store layout",
        "",
        "Generated from `vfcli/store/layout.py` by `vfcli schemas`; do not edit.",
        "",
        "## A store is a file plus its parts folder",
        "",
        "A recording's store is the HDF5 file `<name>` (say `rec.h5`) plus the folder `<name>.parts/` beside it. "
        "The file holds the root attributes, `/mesh` (small) and one HDF5 external link per other stage ("
        + ", ".join(f"`/{n}/<run>`" if n in ("optimize", "diagnose") else f"`/{n}`" for n in sorted(PART_STAGES))
        + "); each of these stages lives, at the same path, in its own part file `<name>.parts/<stage>-<16 hex>.h5`. "
        "Readers built on libhdf5 (h5py, HDFView, MATLAB's h5read, netCDF-C) follow the links, so every path below "
        "opens from the store file as long as the folder is beside it; xarray opens every group of the store file "
        "with its netcdf4 engine (`xr.open_dataset(\"rec.h5\", group=\"hsc\", engine=\"netcdf4\")`, xarray's "
        "default when netCDF4 is installed). xarray's h5netcdf engine does not: it looks a dataset's dimension "
        "scales up in the file it opened, not in the part file that holds the dataset; "
        "`vfcli.store.open_dataset(\"rec.h5\", \"hsc\")` opens a group from the file that holds it, with any "
        "engine. A write costs what it writes: it puts a rewritten stage in a new part file and "
        "renames a new, compact store file (a few kB plus /mesh) into place; part files are never modified, and the "
        "next write deletes the ones no store file in the same folder links to. Copy, move or back up the file and "
        "its folder together and keep their names (a store file alone is refused: \"its stage data folder is "
        "missing\"); a copy of the file alone in the same folder (`cp rec.h5 rec2.h5`) links to the original's "
        "parts until its first write gives it its own (hard links where the file system allows); "
        "meanwhile the original's writes keep the part files the copy links to, or a reader of it holds. "
        "`vfcli share rec.h5 out.h5` writes one self-contained file with the links resolved, to send or archive. "
        "Temporary files of a write are `.<name>.vfcli-<pid>-<8 hex>.tmp`; the lock "
        "files are `.<name>.lock` and `.<name>.readers`. A symlinked store stays a symlink (its parts and "
        "locks are beside its target).",
        "",
        "## Groups and attributes",
        "",
        f"Root attributes: `format` = `{FORMAT_NAME}`, `format_version` = {FORMAT_VERSION}, "
        f"`{ROOT_CONFIG_ATTR}` (the recording's config as JSON), `{ROOT_CONFIG_FILE_ATTR}` (the SHA-256 of the "
        "recording.toml it was last read from, if any: `vfcli run --raw` reads the raw folder's recording.toml "
        "again only when its content changed, so values set since with `vfcli config` stay).",
        "",
        "Every stage group carries its provenance as attributes: "
        + ", ".join(f"`{a}`" for a in PROVENANCE_ATTRS)
        + f". A complete stage also carries `{SUMMARY_ATTR}`: the figures its command printed and the warnings "
        "it logged (JSON `{\"figures\": {...}, \"warnings\": [...]}`, shown by `vfcli info`), and "
        f"`{MANIFEST_ATTR}`: each dataset's shape, dtype and SHA-256 and the checksum of the group's other "
        "attributes, which vfcli checks (docs/input-checks.md, \"Store integrity\"), and "
        f"`{METHOD_ATTR}`: the version of the stage's method that wrote it (absent: 1). A stage written by "
        "an older method than the installed vfcli's is stale (`vfcli info` says what changed; `vfcli run` "
        "writes it again): " + "; ".join(f"`/{st.name}` {v}: {text}" for st in STAGES.values()
                                         for v, text in sorted(st.method_changes.items())) + ". "
        "Every dataset carries `units` and `description`, and every axis is an HDF5 dimension scale: time "
        "axes are the stage's time datasets, the other axes are stored beside the datasets under their own "
        "name (below), so netCDF readers (xarray) see named dimensions.",
        "",
    ]
    for st in STAGES.values():
        path = st.group_path("<run>") if st.has_runs else st.group_path()
        lines += [f"## `{path}`", "", f"{st.description} Written by `vfcli {st.written_by}`."]
        if st.reads:
            lines.append(f"Reads: {', '.join('`/' + r + '`' for r in st.reads)}.")
        lines.append("")
        if st.datasets:
            lines += ["| dataset | units | axes | description |", "| --- | --- | --- | --- |"]
            for key, ds in st.datasets.items():
                axes = ", ".join(ds.dims)
                lines.append(f"| `{key}` | {ds.units} | {axes} | {ds.description} |")
            lines.append("")
    lines += ["## Axes", "", "Stored in each stage group that uses them: text labels, or the 0-based index.", "",
              "| axis | values | description |", "| --- | --- | --- |"]
    for name, ax in AXES.items():
        lines.append(f"| `{name}` | {', '.join(ax.labels) if ax.labels else 'index'} | {ax.description} |")
    lines.append("")
    lines += ["## Phantom `truth.h5` (`vfcli synth`; read by tests and benchmarks only)", "",
              "| dataset | units | axes | description |", "| --- | --- | --- | --- |"]
    for key, ds in TRUTH.items():
        lines.append(f"| `/{key}` | {ds.units} | {', '.join(ds.dims)} | {ds.description} |")
    lines.append("")
    return "\n".join(lines)
