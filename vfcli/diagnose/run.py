"""Locate on a whole recording: the one call of the diagnose stage.

:func:`locate_run` takes the fitted window (a :class:`vfcli.diagnose.candidate.Baseline`) and
the whole recording around it (:class:`Recording`, arrays or array-likes the stage hands in;
the large per-frame ones are read here in slices of frames, so memory does not grow with the
recording), and returns what Locate found (:class:`LocateResult`); :func:`diagnose_run` adds the
candidates' screening (:func:`vfcli.diagnose.candidate.screen`) and the plain-words lines.
"""
from __future__ import annotations

import builtins
import dataclasses
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from vfcli.camera.pose import model_axes_velocity
from vfcli.diagnose.calibrate_run import calibrate_run
from vfcli.diagnose.candidate import available_candidates, screenings
from vfcli.diagnose.candidates.blocks import screen_run_columns
from vfcli.diagnose.profile import leads_by_fall, profile_screens
from vfcli.diagnose.cycles import PHASE_NAMES, Cycles, TooFewCycles, floor_cycles, glottal_cycles
from vfcli.diagnose.locate import Located, decompose, rank_hotspots
from vfcli.diagnose.noise import cycle_floor, ldv_known_variance, ldv_noise_density
from vfcli.diagnose.regions import (COMPONENT_NAMES, GAP_COMPONENT_NAMES, N_GAP_REGIONS, N_REGIONS,
                                    gap_region_names, region_names)
from vfcli.diagnose.residual import WindowResidual, medial_silhouettes, region_means, window_residual
from vfcli.diagnose.calibrate import smallest_detectable
from vfcli.diagnose.decide import decide, detection_words
from vfcli.diagnose.words import summary_lines
from vfcli.flow.gap.opening import measured_silhouettes
from vfcli.progress import no_phase

#: frames read at once from the per-frame arrays
CHUNK_FRAMES = 64


@dataclass(frozen=True)
class LocateSettings:
    """alpha : family-wise false-alarm rate of the hotspots and of the candidates' decision.
    n_harmonics : harmonics of f0 tested (K).  n_replicates, seed : the calibration's bootstrap
    (:mod:`vfcli.diagnose.calibrate`)."""

    alpha: float = 0.05
    n_harmonics: int = 5
    n_replicates: int = 199
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.alpha < 1 or not 1 <= self.n_harmonics <= 20 or self.n_replicates < 1:
            raise ValueError(f"alpha in (0, 1), n_harmonics in 1..20 and n_replicates >= 1, got {self.alpha}, "
                             f"{self.n_harmonics}, {self.n_replicates}")


@dataclass(frozen=True)
class Recording:
    """The whole recording the window was cut from.

    glottal_area : (F_all,) mm^2 at the video frames (uniform, the window's frame interval).
    velocity : (F_all, H, W, 3) array-like, mm/s, /fields' (u, v, w) (u, v turned by velocity_rotation_deg).
    valid : (F_all, H, W) array-like bool.  gap_masks : (F_all, H, W) array-like bool.
    velocity_rotation_deg : rotation /flow turned the image velocities by, degrees.
    window_start : index of the window's first frame in the recording.
    ldv_velocity : (P, S) raw vibrometer records, mm/s, or None.  ldv_fs_hz : their rate, Hz.
    ldv_used : (P,) bool points the field uses.  ldv_px : (P, 2) their screen positions (col, row) px.
    ldv_record_s : seconds of record averaged per point (n_cycles / f0, median over points).
    pressure_f0_hz : f0 of the subglottal pressure (``/sync``, median over the points aligned), Hz, or NaN:
        the cycles are counted with it (:func:`vfcli.diagnose.cycles.glottal_cycles`).
    """

    glottal_area: np.ndarray
    velocity: Any
    valid: Any
    gap_masks: Any
    velocity_rotation_deg: float
    window_start: int
    ldv_velocity: np.ndarray | None = None
    ldv_fs_hz: float = float("nan")
    ldv_used: np.ndarray | None = None
    ldv_px: np.ndarray | None = None
    ldv_record_s: float = float("nan")
    pressure_f0_hz: float = float("nan")


@dataclass(frozen=True)
class LocateResult:
    """located : the decomposition and hotspots.  residual : the window's residual and its regions.
    cycles : the recording's glottal cycles.  window : (F,) indices of the window's frames in the recording.
    ldv_density : the vibrometer's noise density above the band of motion, (mm/s)^2/Hz (NaN: none).
    """

    located: Located
    residual: WindowResidual
    cycles: Cycles
    window: np.ndarray
    ldv_density: float


def measured_motion_series(rec: Recording, camera_rotation_deg: float, pixel_region: np.ndarray,
                           frames: slice) -> np.ndarray:
    """(F, 18, 3) measured velocity in model axes, mean over each region's valid pixels per frame, mm/s,
    for the recording's ``frames``."""
    n = frames.stop - frames.start
    out = np.full((n, N_REGIONS, 3), np.nan)
    for i in range(frames.start, frames.stop, CHUNK_FRAMES):
        j = min(i + CHUNK_FRAMES, frames.stop)
        v = np.array(rec.velocity[i:j], dtype=np.float64)
        v[..., :2] = model_axes_velocity(v[..., :2], rec.velocity_rotation_deg, camera_rotation_deg)
        v[~np.asarray(rec.valid[i:j], bool)] = np.nan
        out[i - frames.start:j - frames.start] = region_means(v, pixel_region, N_REGIONS)
    return out


def ldv_points_per_region(ldv_px: np.ndarray | None, used: np.ndarray | None, pixel_region: np.ndarray,
                          pixel_stride: int = 1) -> np.ndarray:
    """(18,) scan points (used ones) whose screen position falls on each region (on a ``pixel_stride`` grid's
    regions: at its nearest grid pixel)."""
    out = np.zeros(N_REGIONS)
    if ldv_px is None:
        return out
    px = np.asarray(ldv_px, float)
    keep = np.all(np.isfinite(px), axis=1) & (np.ones(len(px), bool) if used is None else np.asarray(used, bool))
    h, w = pixel_region.shape
    col = np.rint(px[keep, 0] / pixel_stride).astype(int) * pixel_stride
    row = np.rint(px[keep, 1] / pixel_stride).astype(int) * pixel_stride
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    reg = pixel_region[row[inside], col[inside]]
    np.add.at(out, reg[reg >= 0], 1.0)
    return out


def locate_run(baseline, rec: Recording, settings: LocateSettings | None = None) -> LocateResult:
    """Locate the residual of the baseline's window against the noise floor of the whole recording."""
    settings = settings or LocateSettings()
    p = baseline.problem
    k = settings.n_harmonics
    res = window_residual(baseline)
    cycles = glottal_cycles(np.asarray(rec.glottal_area, float), p.dt, rec.pressure_f0_hz)
    window = np.arange(rec.window_start, rec.window_start + p.n_frames)
    span, around, exclude = floor_cycles(cycles, window)

    motion_all = measured_motion_series(rec, p.camera.rotation_deg, res.pixel_region, span)
    floor = cycle_floor(motion_all, around, k, exclude)
    density = float("nan")
    if rec.ldv_velocity is not None and len(rec.ldv_velocity):
        density = ldv_noise_density(rec.ldv_velocity, rec.ldv_fs_hz, cycles.f0_hz, rec.ldv_used)
        widths = floor.frames_per_bin / max(floor.frames_per_bin.sum(), 1e-12)
        kb, kh = ldv_known_variance(density, rec.ldv_record_s,
                                    ldv_points_per_region(rec.ldv_px, rec.ldv_used, res.pixel_region, res.pixel_stride),
                                    2, 3, widths, k)
        floor = floor.with_known(kb, kh)
    families = {"motion": decompose(region_means(res.motion, res.pixel_region, N_REGIONS), cycles.phase[window],
                                    cycles.phase_name[window], floor, region_names(), COMPONENT_NAMES, "mm/s")}

    if np.any(res.gap_region >= 0):
        masks = np.concatenate([np.asarray(rec.gap_masks[i:min(i + CHUNK_FRAMES, span.stop)], bool)
                                for i in range(span.start, span.stop, CHUNK_FRAMES)])
        lo, hi = measured_silhouettes(masks, p.settings.lateral_axis)
        sil = medial_silhouettes(lo, hi)[..., None] / p.camera.px_per_mm             # (F, rays, 2, 1) mm
        gap_all = region_means(sil, res.gap_region, N_GAP_REGIONS)
        gap_floor = cycle_floor(gap_all, around, k, exclude)
        families["gap"] = decompose(region_means(res.gap[..., None], res.gap_region, N_GAP_REGIONS),
                                    cycles.phase[window], cycles.phase_name[window], gap_floor,
                                    gap_region_names(), GAP_COMPONENT_NAMES, "mm")
    located = Located(families, rank_hotspots(families, settings.alpha), settings.alpha, cycles.f0_hz, floor.n_cycles)
    return LocateResult(located, res, cycles, window, density)


@dataclass(frozen=True)
class Diagnosis:
    """What `vfcli diagnose` found: Locate's result, the candidates' screening and the plain-words lines."""

    locate: LocateResult
    screening: list
    screening_status: str
    lines: list[str]
    calibration: Any = None
    decision: Any = None
    profiles: tuple = ()

    @property
    def located(self) -> Located:
        return self.locate.located

    def verdict(self) -> str:
        """The decision in words ("missing physics: asymmetry", "no missing physics detected"), or, where it could
        not be calibrated, the line that says why ("not calibrated: ...")."""
        if self.decision is not None:
            return self.decision.verdict
        return next((x[len("decision: "):] for x in self.lines if x.startswith("decision: not ")), "not decided")

    def summary(self) -> dict[str, Any]:
        """The figures the command prints and stores (JSON-ready): the decision first (``decision``, its
        ``findings`` and the unconfirmed and confirmed ``leads``), then Locate's figures."""
        loc = self.located
        top = []
        for h in loc.hotspots[:10]:
            d = loc.families[h.family]
            top.append({"family": h.family, "kind": h.kind, "region": d.region_names[h.region],
                        "component": d.component_names[h.component],
                        ("harmonic" if h.kind == "harmonic" else "phase"):
                            (h.index if h.kind == "harmonic" else PHASE_NAMES[h.index]),
                        "size": round(h.size, 6), "units": d.units, "ratio": round(h.ratio, 3),
                        "p": float(f"{h.p_value:.4g}"), "p_adjusted": float(f"{h.p_adjusted:.4g}")})
        return {"decision": self.verdict(), "findings": list(self.decision.findings) if self.decision else [],
                "leads": ([*self.decision.leads, *self.decision.profile_leads] if self.decision else []),
                "f0_hz": round(loc.f0_hz, 2), "noise_cycles": loc.n_cycles, "parts_tested": len(loc.hotspots),
                "above_noise": len(loc.significant), "alpha": loc.alpha,
                # the hotspots are ranked by their ratio to the noise floor, not by p (hotspots[0] was reported)
                "smallest_p_adjusted": (float(f"{min(h.p_adjusted for h in loc.hotspots):.4g}") if loc.hotspots
                                        else None),
                "screening": self.screening_status, "lines": self.lines, "hotspots": top,
                **({"profiles": [p.as_dict() for p in self.profiles]} if self.profiles else {}),
                **({"candidates": calibration_summary(self)} if self.calibration is not None else {})}


def calibration_summary(d: Diagnosis) -> dict[str, Any]:
    """The calibrated screening's figures (JSON-ready): per candidate the naive and calibrated p-values, and the
    smallest size the screening would name (:func:`detection_limits`'s candidates)."""
    cal = d.calibration.calibration
    limits = smallest_detectable(cal, d.calibration.information, d.decision.alpha)
    return {"alpha_family": d.decision.alpha, "replicates": cal.n_replicates, "seed": cal.seed,
            "pool_cycles": cal.n_pool_cycles, "verdict": d.decision.verdict, "leads": list(d.decision.leads),
            "findings": list(d.decision.findings),
            "tests": [{"name": n, "p_naive": float(f"{pn:.4g}"), "p_calibrated": float(f"{pc:.4g}"),
                       # the calibrated test's studentized statistic (as /diagnose's candidate_statistic_studentized),
                       # not the chi2 behind p_naive: named so (it was "statistic" beside p_naive)
                       "p_family": float(f"{pf:.4g}"), "statistic_studentized": float(f"{st:.4g}"),
                       **({"smallest_detectable": None if not np.isfinite(lim) else float(f"{lim:.4g}")}
                          if n in d.decision.limits else {})}
                      for n, pn, pc, pf, st, lim in zip(d.calibration.names, d.calibration.naive_p, cal.p_value,
                                                        cal.p_family, cal.statistic, limits)]}


def detection_limits(cands, cal, alpha: float) -> dict[str, str]:
    """Candidate name -> :func:`vfcli.diagnose.decide.detection_words` for the one-parameter candidates with a
    physical full strength (``full_value``: contact) that only the calibrated screening can find (not screened by
    a profile); from :func:`vfcli.diagnose.calibrate.smallest_detectable` at family-wise ``alpha``.  Others get
    no such line: asymmetry's limit in the calibration's linear model (0.001-0.005 of softening on three panel
    recordings) says nothing of the in-phase model error that raises its leads on nulls, which only the
    confirmation refit rejects (docs/diagnose.md)."""
    limit = smallest_detectable(cal.calibration, cal.information, alpha)
    return {c.name: detection_words(c.parameter_names[0], float(lim), c.full_value, c.full_meaning,
                                    bool(getattr(c, "one_sided", False)))
            for c, lim in zip(cands, limit)
            if len(c.parameter_names) == 1 and getattr(c, "full_value", None) is not None
            and not getattr(c, "profile_screening", False)}


def diagnose_run(baseline, rec: Recording, settings: LocateSettings | None = None, map: Callable = builtins.map,
                 confirmations: dict | None = None, profile: bool = True,
                 phase: Callable[[str], None] = no_phase, local_map: Callable | None = None) -> Diagnosis:
    """Locate the baseline's residual (:func:`locate_run`), screen the candidate physics terms, calibrate
    their null distribution by bootstrap (:mod:`vfcli.diagnose.calibrate_run`), profile the candidates the
    score test cannot reach (:mod:`vfcli.diagnose.profile`; ``profile=False`` skips it) and decide
    (:mod:`vfcli.diagnose.decide`).  map : applied to the bootstrap's chunks of replicates.  phase : called with
    each step's name as it starts (locate, screen, calibrate, profile, decide; :class:`vfcli.progress.Phases`).
    local_map : an in-process map (:func:`vfcli.parallel.local_map`) for the profiles' pieces (they share the
    baseline); default one after the other."""
    settings = settings or LocateSettings()
    phase("locate")
    loc = locate_run(baseline, rec, settings)
    cands = available_candidates()
    if not cands:
        status = "not built yet"
        return Diagnosis(loc, [], status, summary_lines(loc.located) + [f"candidate screening: {status}"])
    if not np.isfinite(baseline.f0_hz):
        # the window's f0 from the gap area's cycle: the steady-state candidates (inertia) work per harmonic of it
        baseline.f0_hz = float(loc.located.f0_hz)
    phase("screen")
    tests, columns, model = screen_run_columns(cands, baseline)
    results = screenings(cands, tests, baseline)
    status = f"{len(results)} candidates screened"
    lines = summary_lines(loc.located) + [f"candidate screening: {status}"] + [r.words for r in results if r.words]
    phase("calibrate")
    try:
        cal = calibrate_run(cands, baseline, rec, loc.cycles, loc.window, tests, columns, model,
                            settings.n_replicates, settings.seed, map)
    except TooFewCycles as exc:
        # too short a recording to calibrate: no lead can be claimed (the naive p-values are not a decision)
        return Diagnosis(loc, results, status, lines + [f"decision: not calibrated ({exc}); no missing physics "
                                                        "can be claimed: record more glottal cycles around the "
                                                        "run's window"])
    results = [dataclasses.replace(r, p_calibrated=float(pc), p_family=float(pf))
               for r, pc, pf in zip(results, cal.calibration.p_value, cal.calibration.p_family)]
    if profile:
        phase("profile")
    profiles = tuple(profile_screens(baseline, cands, map=local_map)) if profile else ()
    phase("decide")
    lines += [p.words() for p in profiles]
    decision = decide([c.name for c in cands], cal.calibration.p_family, [r.identifiable for r in results],
                      cal.calibration.n_replicates, settings.alpha, confirmations,
                      profile_leads=leads_by_fall(profiles),
                      limits=detection_limits(cands, cal, settings.alpha))
    return Diagnosis(loc, results, status, lines + decision.lines, cal, decision, profiles)
