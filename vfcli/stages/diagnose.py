"""`vfcli diagnose FILE --run RUN`: locate where a fitted run disagrees with its recording.

Reads /optimize/<run> and what it was fitted to (/mesh, /fields, /flow, /hsc's pressure for
the pressure loads), the whole recording's /fields and /flow for the noise floor, and /ldv
and /sync for the vibrometer's noise; writes /diagnose/<run>.

:func:`read_inputs` (the run's baseline, rebuilt from the store with the run's own settings and
camera pose, and the recording as array-likes) -> :func:`vfcli.diagnose.run.diagnose_run` -> write.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from vfcli.camera.pose import gap_ray_axis
from vfcli.config import RecordingConfig
from vfcli.diagnose.candidate import Baseline
from vfcli.diagnose.cycles import TooFewCycles, too_few_advice
from vfcli.diagnose.residual import grid_filled, rms_residual
from vfcli.diagnose.run import Diagnosis, LocateSettings, Recording, diagnose_run
from vfcli.diagnose.words import fold_side_words, gap_doubt_words
from vfcli.errors import ConfigError, InputDataError
from vfcli.model.refine import finer_model
from vfcli.parallel import serial_map
from vfcli.progress import Phases
from vfcli.stages.base import RunContext, StageResult, run_stage
from vfcli.store import StageWriter, StoreReader, layout
from vfcli.store.fit import pressure_f0_hz, problem_of_store, run_model  # noqa: F401 (pressure_f0_hz: this module's name too)
from vfcli.store.refit_run import write_refit_params, write_refit_run
from vfcli.store.runs import read_run

log = logging.getLogger(__name__)

#: largest difference (mm) between the stored displacements of a run and those of its rebuilt model
#: (the store keeps float32: about 1e-7 relative)
_REBUILD_TOL_MM = 1e-4


@dataclass(frozen=True)
class DiagnoseInputs:
    """baseline : the run's fitted model.  recording : the whole recording.  run_config : the run's settings.
    run_attrs : the run's attributes.  roi_origin_px : (col, row) of the stored frames' first pixel in the video.
    gap_edge_disagreement, gap_level_disagreement : /flow's ``edge_disagreement`` and ``level_disagreement`` (NaN: not
    stored; :func:`vfcli.diagnose.words.gap_doubt_words`)."""

    baseline: Baseline
    recording: Recording
    run_config: dict[str, Any]
    run_attrs: dict[str, Any] | None = None
    roi_origin_px: tuple[float, float] = (0.0, 0.0)
    gap_edge_disagreement: float = float("nan")
    gap_level_disagreement: float = float("nan")


def run_recording_config(config: RecordingConfig, run_config: dict[str, Any], attrs: dict[str, Any],
                         roi_origin_px: np.ndarray) -> RecordingConfig:
    """The recording config the run was fitted under: its own [optimize] settings, its ridge weight (no
    L-curve rescan) and its camera pose (as found then, on the full frame)."""
    data = config.model_dump(mode="json")
    data["optimize"] = {**run_config.get("optimize", data["optimize"]), "ridge_weight": float(attrs["ridge_weight"])}
    # a run stored before optimize band-limited the recorded pressure (optimize.pressure_band_harmonics) used it as
    # recorded: rebuilt with today's default its model would differ from its stored displacements
    data["optimize"].setdefault("pressure_band_harmonics", None)
    # a run stored before session 47 asked the simulated edges to meet on every closed ray
    data["optimize"].setdefault("gap_closed_rays", "meet")
    # a run stored before session 51 followed the material points in its gradient
    data["optimize"].setdefault("motion_slide", False)
    offset = np.asarray(attrs["camera_offset_px"], float) + np.asarray(roi_origin_px, float)
    data["camera"] = {**run_config.get("camera", data["camera"]), "pose": "config",
                      "rotation_deg": float(attrs["camera_rotation_deg"]), "offset_px": [float(v) for v in offset]}
    return RecordingConfig.model_validate(data)


def run_gap_axis(attrs: dict[str, Any], flow_attrs: dict[str, Any]) -> int:
    """The image axis a run's gap rays ran along: its ``gap_lateral_axis``; a run stored before session 63 has none and
    ran them along its rotation's axis unless within :data:`vfcli.camera.pose.DIAGONAL_TOLERANCE_DEG` of a diagonal
    (the rule then; since, /flow's axis within :data:`vfcli.camera.pose.MEASURED_AXIS_TOLERANCE_DEG`)."""
    if "gap_lateral_axis" in attrs:
        return int(attrs["gap_lateral_axis"])
    return gap_ray_axis(float(attrs["camera_rotation_deg"]), int(flow_attrs.get("lateral_axis", 0)))[0]


def motion_stride(valid: np.ndarray, max_rows: int) -> int:
    """The smallest pixel stride s whose grid (every s-th pixel of every s-th row) leaves at most ``max_rows``
    motion rows (3 per valid pixel and frame) of the window's ``valid`` (F, H, W) bool."""
    v = np.asarray(valid, bool)
    s = 1
    while 3 * int(np.count_nonzero(v[:, ::s, ::s])) > max_rows and s < min(v.shape[1:]):
        s += 1
    return s


def read_inputs(reader: StoreReader, config: RecordingConfig, run: str) -> DiagnoseInputs:
    """The run's baseline and the recording (module docstring).

    Raises
    ------
    InputDataError
        The model rebuilt from the store does not reproduce the run's stored displacements
        (/mesh, /fields or /flow changed since the run).
    """
    group = layout.stage("optimize").group_path(run)
    attrs = reader.attrs("optimize", run) if reader.has_stage("optimize", run) else {}
    if "refit_of" in attrs:
        # its model is the baseline's extended by a candidate, which the store cannot rebuild as a plain run: the
        # check below failed on it with "/mesh ... changed since the run; rerun `vfcli optimize --run NAME`"
        raise ConfigError(f"diagnose --run {run}: {group} is diagnose's refit of run {attrs['refit_of']!r} with "
                          f"{attrs.get('refit_candidate', 'a candidate')}, not a fit diagnose can judge; diagnose "
                          f"run {attrs['refit_of']!r} (its refit's figures are in its diagnosis)")
    stored = read_run(reader, run)
    flow_attrs = reader.attrs("flow")
    roi = np.asarray(flow_attrs.get("roi_origin_px", (0.0, 0.0)), dtype=float)
    cfg = run_recording_config(config, stored.config, stored.attrs, roi)
    problem, _ = problem_of_store(reader, cfg, lateral_axis=run_gap_axis(stored.attrs, flow_attrs))
    # a large window (many frames of large images) is compared on a coarser pixel grid: the diagnosis holds
    # several row-length vectors per candidate, which outgrew 23 GB at 101.6 M rows (docs/diagnose.md)
    problem = problem.thinned(motion_stride(problem.meas.valid, config.diagnose.max_motion_rows))
    if problem.n_params != len(stored.controls) or not np.allclose(problem.sim_times, stored.sim_time, atol=1e-9):
        raise InputDataError(f"{group} does not match the model rebuilt from the store ({problem.n_params} "
                             f"controls, {len(problem.sim_times)} times against {len(stored.controls)}, "
                             f"{len(stored.sim_time)}); rerun `vfcli optimize --run {run}`", reader.path)
    baseline = Baseline.at(problem, stored.controls, model=run_model(reader))
    baseline.finer_model = partial(finer_model, cfg.mesh, baseline.model)
    worst = float(np.max(np.abs(baseline.displacements - stored.displacements)))
    scale = float(np.max(np.abs(stored.displacements))) or 1.0
    if worst > _REBUILD_TOL_MM + 1e-5 * scale:
        raise InputDataError(f"{group}: its stored displacements differ from its model rebuilt from the store "
                             f"by up to {worst:.3g} mm (/mesh, /fields, /flow or /sync changed since the run, or another vfcli version "
                             f"made it); rerun "
                             f"`vfcli optimize --run {run}`", reader.path)
    ldv = {}
    if reader.has_stage("ldv") and reader.has_stage("sync"):
        used = np.asarray(reader.read("sync", "ok"), bool) & ~np.asarray(reader.read("ldv", "dropout"), bool)
        n_cyc, f0 = reader.read("sync", "n_cycles").astype(float), reader.read("sync", "f0_hz").astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            record = n_cyc / f0
        ok = used & np.isfinite(record) & (record > 0)
        ldv = dict(ldv_velocity=reader.read("ldv", "velocity"), ldv_fs_hz=float(reader.attrs("ldv")["fs_hz"]),
                   ldv_used=used, ldv_px=reader.read("fields", "ldv_px"),
                   ldv_record_s=float(np.median(record[ok])) if ok.any() else float("nan"),
                   pressure_f0_hz=pressure_f0_hz(reader))
    rec = Recording(glottal_area=reader.read("flow", "glottal_area"), velocity=reader.dataset("fields", "velocity"),
                    valid=reader.dataset("fields", "valid"), gap_masks=reader.dataset("flow", "gap_mask"),
                    velocity_rotation_deg=float(flow_attrs.get("rotation_deg", 0.0)),
                    window_start=int(cfg.optimize.first_frame), **ldv)
    return DiagnoseInputs(baseline, rec, stored.config, dict(stored.attrs), (float(roi[0]), float(roi[1])),
                          float(flow_attrs.get("edge_disagreement", float("nan"))),
                          float(flow_attrs.get("level_disagreement", float("nan"))))


class ContextLines(NamedTuple):
    """The lines that follow the diagnosis' first (:func:`context_lines`), each kept apart so the stage logs
    each as what it is: ``stride`` the coarser grid the motion was compared on ("" on every pixel), ``fold`` which
    fold of the video is which, ``doubt`` a doubtful gap ("" when /flow does not say so)."""

    stride: str
    fold: str
    doubt: str

    @property
    def lines(self) -> list[str]:
        """The lines in the order they are shown, the empty ones left out."""
        return [line for line in self if line]


def context_lines(inputs: DiagnoseInputs, max_rows: int) -> ContextLines:
    """The lines that follow the diagnosis' first: the coarser grid the motion was compared on (when it was,
    :func:`stride_words`), which fold of the video is which (:func:`vfcli.diagnose.words.fold_side_words`), and a
    doubtful gap (when /flow says so, :func:`vfcli.diagnose.words.gap_doubt_words`)."""
    problem = inputs.baseline.problem
    stride = problem.meas.pixel_stride
    pose_source = str((inputs.run_attrs or {}).get("pose_source", "config"))
    return ContextLines(stride_words(stride, max_rows) if stride > 1 else "",
                        fold_side_words(problem.camera, problem.mesh, pose_source, inputs.roi_origin_px),
                        gap_doubt_words(inputs.gap_edge_disagreement, inputs.gap_level_disagreement))


def stride_words(stride: int, max_rows: int) -> str:
    """The line that says the motion was compared on a coarser grid."""
    nth = {2: "2nd", 3: "3rd"}.get(stride, f"{stride}th")
    return (f"the window's motion was compared on every {nth} pixel of every {nth} row: every pixel would give more "
            f"than diagnose.max_motion_rows = {max_rows:,} rows (the noise counts its correlation on that grid)")


def write_diagnosis(s: StageWriter, d: Diagnosis, frame_time: np.ndarray) -> None:
    """Write the diagnosis into the stage group (keys of the store layout)."""
    loc, res = d.located, d.locate.residual
    s.put("frame_time", frame_time)
    s.put("frame_phase", d.locate.cycles.phase[d.locate.window])
    s.put("frame_cycle_phase", d.locate.cycles.phase_name[d.locate.window].astype(np.int8))
    motion = loc.families["motion"]
    s.put("region_name", np.array(motion.region_names, dtype=object))
    s.put("pixel_region", res.pixel_region.astype(np.int8))
    s.put("rms_residual", grid_filled(rms_residual(res.motion), res.pixel_stride).astype(np.float32))
    for fam, dec in loc.families.items():
        if fam == "gap":
            s.put("gap_region_name", np.array(dec.region_names, dtype=object))
        for key, arr in (("phase_mean", dec.bin_mean), ("phase_sd", dec.bin_sd), ("phase_dof", dec.bin_dof),
                         ("phase_p", dec.bin_p), ("harmonic_amplitude", dec.harm_amp),
                         ("harmonic_phase", dec.harm_phase), ("harmonic_sd", dec.harm_sd),
                         ("harmonic_dof", dec.harm_dof), ("harmonic_p", dec.harm_p)):
            s.put(f"{fam}_{key}", np.asarray(arr, dtype=np.float64))
    spots = loc.hotspots
    s.put("hotspot_family", np.array([h.family for h in spots], dtype=object))
    s.put("hotspot_kind", np.array([h.kind for h in spots], dtype=object))
    s.put("hotspot_region", np.array([h.region for h in spots], dtype=np.int16))
    s.put("hotspot_component", np.array([h.component for h in spots], dtype=np.int16))
    s.put("hotspot_index", np.array([h.index for h in spots], dtype=np.int16))
    s.put("hotspot_ratio", np.array([h.ratio for h in spots], dtype=np.float64))
    s.put("hotspot_p", np.array([h.p_value for h in spots], dtype=np.float64))
    s.put("hotspot_p_adjusted", np.array([h.p_adjusted for h in spots], dtype=np.float64))
    if d.screening:
        s.put("candidate_name", np.array([c.name for c in d.screening], dtype=object))
        s.put("candidate_statistic", np.array([c.statistic for c in d.screening], dtype=np.float64))
        s.put("candidate_p", np.array([c.p_value for c in d.screening], dtype=np.float64))
        s.put("candidate_identifiable", np.array([bool(c.identifiable) for c in d.screening]))
        s.put("candidate_words", np.array([c.words for c in d.screening], dtype=object))
    if d.calibration is not None:
        cal = d.calibration.calibration
        s.put("candidate_p_calibrated", np.asarray(cal.p_value, dtype=np.float64))
        s.put("candidate_p_family", np.asarray(cal.p_family, dtype=np.float64))
        s.put("candidate_statistic_studentized", np.asarray(cal.statistic, dtype=np.float64))
        s.put("candidate_null_statistic", np.asarray(cal.null_statistics, dtype=np.float32))
        s.set_attrs(calibration_replicates=cal.n_replicates, calibration_seed=cal.seed,
                    calibration_pool_cycles=cal.n_pool_cycles, alpha_family=d.decision.alpha,
                    decision=d.decision.verdict, decision_leads_json=json.dumps(list(d.decision.leads)),
                    decision_findings_json=json.dumps(list(d.decision.findings)))
    s.set_attrs(f0_hz=loc.f0_hz, n_cycles=loc.n_cycles, alpha=loc.alpha,
                ldv_noise_density=d.locate.ldv_density, words_json=json.dumps(d.lines),
                screening=d.screening_status)


def write_confirmation(s: StageWriter, conf) -> None:
    """The confirmation refit's figures into /diagnose/<run> (:class:`vfcli.diagnose.confirmation.Confirmation`)."""
    write_refit_params(s, conf.parameter_names, conf.estimate, conf.sd)
    for h in conf.heldout:
        s.put(f"heldout_{h.kind}_baseline", np.asarray(h.baseline, dtype=np.float64))
        s.put(f"heldout_{h.kind}_extended", np.asarray(h.extended, dtype=np.float64))
    s.set_attrs(refit_candidate=conf.candidate, refit_run=conf.run, confirmation_json=json.dumps(conf.as_dict()))


def refit_run_name(run: str, candidate: str) -> str:
    """The /optimize run of the extended model: ``<run>+<candidate>`` (e.g. ``default+inertia``)."""
    return f"{run}+{candidate}"


def figure_paths(store_path: Path, run: str, map_path: str | Path | None) -> dict[str, Path]:
    """Where the before/after images go: beside --map when given, else beside the store."""
    if map_path is not None:
        m = Path(map_path)
        return {"after": m.with_name(f"{m.stem}_refit{m.suffix or '.png'}"),
                "points": m.with_name(f"{m.stem}_points{m.suffix or '.png'}")}
    base = Path(store_path).with_suffix("")
    safe = run.replace("/", "_")
    return {"before": base.with_name(f"{base.name}_{safe}_residual.png"),
            "after": base.with_name(f"{base.name}_{safe}_refit_residual.png"),
            "points": base.with_name(f"{base.name}_{safe}_refit_points.png")}


def run_diagnose(ctx: RunContext, run: str = "default", alpha: float = 0.05, n_harmonics: int = 5,
                 map_path: str | Path | None = None, refit: str = "auto") -> StageResult:
    """Locate the residual of /optimize/<run> and store it as /diagnose/<run>; confirm a lead by refit.

    map_path : the residual map image (PNG), written when given.
    refit : "auto" (refit the leads in turn, at most :data:`vfcli.diagnose.confirm.MAX_REFITS`:
        :func:`vfcli.diagnose.confirm.refit_order`; the confirmed one that predicts held-out data best is named; a
        lead whose baseline lacks its term's signature is not refitted, :func:`vfcli.diagnose.confirm.refits_to_make`),
        "none", or a candidate's name (refit it whatever the screening says).  A refit is stored as its own run
        /optimize/<run>+<candidate>, with before/after residual maps and velocity-at-point plots (PNG) beside
        --map, or beside the store without --map.
    """
    from vfcli.diagnose.candidate import available_candidates
    from vfcli.diagnose.confirm import choose, refits_to_make
    from vfcli.diagnose.confirmation import NotRefitted

    dcfg = ctx.config.diagnose
    try:
        settings = LocateSettings(alpha=alpha, n_harmonics=n_harmonics, n_replicates=dcfg.replicates, seed=dcfg.seed)
        choose([], available_candidates(), refit)
    except ValueError as exc:
        raise ConfigError(f"diagnose: {exc}") from None
    settings_used = {"alpha": alpha, "n_harmonics": n_harmonics, "refit": refit, "replicates": dcfg.replicates,
                     "seed": dcfg.seed}
    if dcfg.max_motion_rows != type(dcfg).model_fields["max_motion_rows"].default:
        settings_used["max_motion_rows"] = dcfg.max_motion_rows     # at its default: stores diagnosed before it stay fresh
    config_json = json.dumps({"diagnose": settings_used}, sort_keys=True)
    upstream: list[tuple[str, str | None]] = [("optimize", run), ("mesh", None), ("fields", None), ("flow", None)]
    if ctx.store.exists():
        with ctx.store.read() as r:
            upstream += [(name, None) for name in ("ldv", "sync") if r.has_stage(name)]
    done: dict[str, Any] = {}

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        # read, locate, screen, calibrate, profile, decide, write; a refit adds its own
        phases = Phases(ctx.progress, "diagnose", 7, log)
        phases("read")
        inputs = read_inputs(reader, ctx.config, run)
        try:
            d = diagnose_run(inputs.baseline, inputs.recording, settings, map=ctx.map or serial_map, phase=phases,
                             local_map=ctx.local_map)
        except TooFewCycles as exc:
            rec = inputs.recording
            advice = too_few_advice(rec.glottal_area, inputs.baseline.problem.dt, rec.pressure_f0_hz)
            raise InputDataError(f"diagnose: {exc}; {advice}", reader.path) from None
        stride = inputs.baseline.problem.meas.pixel_stride
        context = context_lines(inputs, ctx.config.diagnose.max_motion_rows)
        d.lines[1:1] = context.lines
        if context.stride:
            log.info("diagnose: %s", context.stride)
        if context.doubt:
            log.warning("diagnose: %s", context.doubt)
        s.set_attrs(pixel_stride=stride)
        if map_path is not None:
            from vfcli.diagnose.maps import residual_map

            phases("map")
            phases.expect(1)
            Path(map_path).parent.mkdir(parents=True, exist_ok=True)   # as the other outputs' folders (`--map`)
            residual_map(d.located, d.locate.residual, map_path, f"residual of run {run}")
        cands = available_candidates()
        profiled = d.decision.profile_leads if d.decision is not None else ()
        # with auto, every lead in turn (calibrated leads first, then profile leads); the best confirmed is named
        # a lead whose baseline lacks its term's signature cannot be confirmed: with auto its refit is not made
        tries, unrefitted = refits_to_make(inputs.baseline, d.screening, cands, refit, alpha, profiled)
        skipped = {n: NotRefitted(n, why) for n, why in unrefitted.items()}
        for c in skipped.values():
            log.info("diagnose: %s %s", c.candidate, c.shortfall)
        extra: dict[str, Any] = {}
        confs: list = []
        if tries:
            extra, confs = confirm_and_write(s, inputs, d, tries, run, settings,
                                             figure_paths(reader.path, run, map_path), done, phases, ctx.local_map)
        if tries or skipped:
            d = redecide(d, {**skipped, **{c.candidate: c for c in confs}})
        if skipped:
            extra["not_refitted"] = {n: c.as_dict() for n, c in skipped.items()}
        # the pictures the diagnosis wrote, --map's first, by absolute path: the report embeds them from anywhere
        images = {**({"before": map_path} if map_path is not None else {}), **extra.get("images", {})}
        if images:
            extra["images"] = {k: str(Path(v).absolute()) for k, v in images.items()}
        phases("write")
        write_diagnosis(s, d, inputs.baseline.problem.meas.times)
        seconds = phases.close()
        s.set_attrs(phase_seconds_json=json.dumps({k: round(v, 3) for k, v in seconds.items()}))
        summary = d.summary()
        summary.update(extra, lines=d.lines, seconds={k: round(v, 1) for k, v in seconds.items()})
        return summary

    result = run_stage(ctx, "diagnose", config_json=config_json, body=body, run=run, upstream=upstream)
    if "refit" in done:                                 # the extended model as its own run
        fitted = done["refit"]

        def write_run(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
            write_refit_run(s, fitted, done["sim_time"], done["parameter_names"], run, done["attrs"])
            return {"refit_of": run, "candidate": fitted.candidate, "E_start": float(fitted.history["total"][0]),
                    "E_final": float(fitted.history["total"][-1]), "converged": bool(fitted.converged)}

        settings_json = json.dumps({**done["config"], "refit": {"of_run": run, "candidate": fitted.candidate}},
                                   sort_keys=True)
        run_stage(ctx, "optimize", config_json=settings_json, body=write_run, run=done["name"],
                  upstream=[("optimize", run), ("mesh", None), ("fields", None), ("flow", None)])
    return result


def bound_from_lcurve(run_config: dict[str, Any]) -> bool:
    """Whether the run's ridge weight was its L-curve's corner (``optimize.ridge_weight`` null under a load model
    optimize bounds so, :data:`vfcli.inverse.setup.DEFAULT_RIDGE`): its refits then choose their own
    (:func:`vfcli.diagnose.bound.refit_at_own_bound`); a weight the lab set is kept."""
    from vfcli.inverse.setup import DEFAULT_RIDGE

    opt = run_config.get("optimize", {}) or {}
    return opt.get("ridge_weight") is None and DEFAULT_RIDGE.get(opt.get("loads", "pressure"), 0.0) is None


def confirm_and_write(s: StageWriter, inputs: DiagnoseInputs, d: Diagnosis, cands, run: str, settings, paths,
                      done: dict, phases: Phases | None = None, local_map=None) -> tuple[dict[str, Any], list]:
    """Refit each of the candidates ``cands`` (:func:`vfcli.diagnose.confirm.confirm_run`), write the figures and
    images of the confirmed one whose refit predicts held-out data best (:func:`vfcli.diagnose.decide.best_confirmed`;
    else the first's); fills ``done`` with what its extended model's /optimize run needs.  Every candidate is refitted
    even after one is confirmed: several leads are alternative explanations of one residual, and the first confirmed
    need not be the best (panel seed 2012, session 53: contact's refit, the first lead, predicted the held-out data
    0.85 % and 1.8 % better, inertia's 43 % and 61 %).  Returns the summary's additions and every
    :class:`vfcli.diagnose.confirmation.Confirmation` made; their words are appended to ``d.lines``.  phases : the
    stage's bar (:class:`vfcli.progress.Phases`): each refit is a phase of its own, ``refit <candidate>``, or, refitted
    side by side through ``local_map`` (an in-process map, :func:`vfcli.parallel.local_map`), one phase for them all,
    ``refit <candidate>, <candidate>``; a single lead's held-out fits take ``local_map`` instead."""
    import dataclasses

    from vfcli.diagnose.confirm import confirm_all, confirm_run, words
    from vfcli.diagnose.decide import best_confirmed
    from vfcli.diagnose.maps import residual_map
    from vfcli.diagnose.plots import velocity_at_points
    from vfcli.diagnose.run import locate_run

    b = inputs.baseline
    if not np.isfinite(b.f0_hz):
        b.f0_hz = float(d.located.f0_hz)             # the window's f0 from the gap area's cycle (Locate's)
    window_phase = d.locate.cycles.phase[d.locate.window]
    after = lambda ext: locate_run(ext, inputs.recording, settings)          # noqa: E731
    own = bound_from_lcurve(inputs.run_config)
    if local_map is not None and len(cands) > 1:
        if phases is not None:                          # side by side: one phase for them all
            phases.expect(1)
            phases("refit " + ", ".join(c.name for c in cands))
        tried = list(zip(cands, confirm_all(b, cands, window_phase, after, own, local_map)))
    else:
        tried = []                                      # one lead: its held-out fits side by side
        for cand in cands:
            if phases is not None:
                phases.expect(1)
                phases(f"refit {cand.name}")
            tried.append((cand, confirm_run(b, cand, window_phase, after, own_bound=own, map=local_map)))
    cand, got = tried[best_confirmed([g.confirmation for _, g in tried])]
    name = refit_run_name(run, cand.name)
    conf = dataclasses.replace(got.confirmation, run=name)
    write_confirmation(s, conf)
    if "before" in paths:
        residual_map(d.located, d.locate.residual, paths["before"], f"residual of run {run}")
    residual_map(got.after.located, got.after.residual, paths["after"], f"residual of run {name}")
    velocity_at_points(b, b.displacements, got.refit.displacements, paths["points"],
                       f"velocity at points: measured, run {run}, run {name}", name)
    pairs = [(c, g.confirmation) for c, g in tried if g is not got]
    for c, other in pairs:
        d.lines.extend(words(other, c))
    d.lines.extend(words(conf, cand))
    others = [other for _, other in pairs]
    p = b.problem
    # the extended run states the same uncertainty as the diagnosis (with the held-out fits' disagreement)
    done.update(refit=dataclasses.replace(got.refit, sd=np.asarray(conf.sd, float), uncertainty=conf.uncertainty),
                name=name, sim_time=p.sim_times, config=inputs.run_config,
                attrs={**(inputs.run_attrs or {}), "pixel_stride": p.meas.pixel_stride,
                       **({} if got.refit.ridge_weight is None else {"ridge_weight": got.refit.ridge_weight})},
                parameter_names=[str(v) for v in getattr(p.response.load_model, "parameter_names", lambda: [])()])
    extra = {"refit": conf.as_dict(), "images": {k: str(v) for k, v in paths.items()}}
    if others:
        extra["other_refits"] = [o.as_dict() for o in others]
    return extra, others + [conf]


def redecide(d: Diagnosis, confirmations: dict) -> Diagnosis:
    """The diagnosis with its decision taken again now that a lead's confirmation refit is known
    (:func:`vfcli.diagnose.decide.decide`); an uncalibrated diagnosis is returned as it is."""
    import dataclasses

    from vfcli.diagnose.decide import decide

    old = d.decision
    if old is None:
        return d
    new = decide(list(old.names), old.p_family, [r.identifiable for r in d.screening], old.n_replicates,
                 old.alpha, confirmations, old.profile_leads, old.limits)
    k = d.lines.index(old.lines[0])
    lines = d.lines[:k] + new.lines + d.lines[k + len(old.lines):]
    return dataclasses.replace(d, lines=lines, decision=new)
