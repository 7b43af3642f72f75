"""`vfcli sync`: map every LDV epoch onto the video's time base through the pressure."""
from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from vfcli.errors import InputDataError
from vfcli.store import StageWriter, StoreReader
from vfcli.stages.base import RunContext, StageResult, run_stage, stage_config_json

log = logging.getLogger(__name__)

#: Fewest aligned points `sync` accepts: the thin-plate spline of `flow`'s /fields needs 3
#: (vfcli.flow.pipeline.good_ldv_points); fewer is an empty product (issue 15), refused with exit 3.
MIN_ALIGNED = 3


@dataclass(frozen=True)
class SyncInputs:
    """What `vfcli sync` reads from the store.

    pressure : (n_p,) subglottal pressure recorded with the video, Pa; sampled at ``fs_pressure``
        Hz from ``t0_pressure`` s.  frame_time : (F,) video frame times, s.
    reference, velocity : (P, n) the LDV epochs' reference pressure and vertical velocity (mm/s),
        sampled at ``fs_ldv`` Hz.  source : where the pressure came from, ldv_source : the scan file
        (for messages).
    """

    pressure: np.ndarray
    fs_pressure: float
    t0_pressure: float
    frame_time: np.ndarray
    reference: np.ndarray
    velocity: np.ndarray
    fs_ldv: float
    source: str
    ldv_source: str


def read_inputs(reader: StoreReader) -> SyncInputs:
    """Everything sync needs, from /hsc and /ldv (InputDataError when no pressure was recorded)."""
    if not reader.has_stage("hsc") or "pressure" not in reader.group("hsc"):
        raise InputDataError("no pressure was recorded with the video: rerun `vfcli ingest-hsc` with --pressure", reader.path)
    p_time = reader.read("hsc", "pressure_time")
    return SyncInputs(pressure=reader.read("hsc", "pressure"), fs_pressure=float(reader.attrs("hsc")["pressure_fs_hz"]),
                      t0_pressure=float(p_time[0]), frame_time=reader.read("hsc", "frame_time"),
                      reference=reader.read("ldv", "reference").astype(np.float64),
                      velocity=reader.read("ldv", "velocity").astype(np.float64),
                      fs_ldv=float(reader.attrs("ldv")["fs_hz"]), source=f"{reader.path}:/hsc/pressure",
                      ldv_source=_ldv_file(reader))


def _ldv_file(reader: StoreReader) -> str:
    """The scan file /ldv was read from (its recorded input), else the store's /ldv."""
    return next(iter(reader.previous_inputs("ldv")), f"{reader.path}:/ldv")


def check_aligned(aligned: int, points: int, reasons: Counter, f0_video_hz: float, ldv_source: str) -> None:
    """Refuse a sync that aligned fewer than :data:`MIN_ALIGNED` of ``points`` LDV points (InputDataError,
    naming the commonest reasons); ``reasons`` counts each reason a point was not aligned."""
    if aligned >= MIN_ALIGNED:
        return
    why = "; ".join(f"{n} x {r}" for r, n in reasons.most_common(2))
    hint = ("; the scan's reference pressure matches the video's at no point: check that the scan and the video are "
            "of the same recording and that the scan's reference channel holds the pressure (ingest_ldv.reference_id1; "
            "a swapped or disconnected channel)" if aligned == 0 else "")
    raise InputDataError(f"sync: only {aligned} of {points} LDV points could be aligned to the video (f0 "
                         f"{f0_video_hz:.2f} Hz), `flow` needs at least {MIN_ALIGNED}; commonest reasons: {why}{hint}",
                         ldv_source)


def _check_levels(reader: StoreReader, inp: SyncInputs, res) -> None:
    """Warn when the pressure beside the video and beside the scan differ in mean or swing
    (:mod:`vfcli.sync.levels`): another operating point or another recording. Only a reference stored in Pa
    is compared (a scan's reference in volts says nothing of the level)."""
    from vfcli.sync.levels import cycle_levels, level_mismatch

    if str(reader.dataset("ldv", "reference").attrs.get("units", "")) != "Pa":
        return
    video = cycle_levels(inp.pressure, inp.fs_pressure, res.f0_video_hz)
    points = [cycle_levels(inp.reference[i], inp.fs_ldv, res.f0_hz[i]) for i in np.flatnonzero(res.ok)]
    points = np.array([p for p in points if p is not None])
    if video is None or not len(points):
        return
    differ = [f"its {'mean' if name == 'mean' else 'swing (RMS of its oscillating part)'} is {v:.0f} Pa beside the "
              f"video, {scan:.0f} Pa beside the scan ({lo:.0f}-{hi:.0f} Pa over its {len(points)} aligned points)"
              for name, v, scan, lo, hi in level_mismatch(video, points)]
    if differ:
        log.warning("the subglottal pressure differs between the video and the scan: %s; they were recorded at "
                    "different operating points, or are files of different recordings, or one pressure's unit is "
                    "wrong (%s): the fit assumes one oscillation", "; ".join(differ), inp.ldv_source)


def run_sync(ctx: RunContext) -> StageResult:
    """Phase-lock every LDV point to the video (/hsc pressure) and store the aligned velocities
    (the alignment, and scipy with it, is imported only when /sync is written)."""
    cfg = ctx.config.sync

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        from vfcli.sync.align import sync_scan

        inp = read_inputs(reader)
        res = sync_scan(
            inp.pressure, inp.fs_pressure, inp.t0_pressure, inp.frame_time, inp.reference, inp.velocity, inp.fs_ldv,
            f_range=(cfg.f0_min_hz, cfg.f0_max_hz), n_harmonics=cfg.n_harmonics, knot_cycles=cfg.knot_cycles,
            max_f0_deviation=cfg.max_drift, min_quality=cfg.min_quality, min_cycles=cfg.min_cycles,
            smooth=cfg.smooth, phase_reference=cfg.phase_reference, source=inp.source,
            ldv_source=inp.ldv_source,
        )
        reasons = Counter(r for r in res.reason if r)
        check_aligned(int(res.ok.sum()), int(res.ok.size), reasons, res.f0_video_hz, inp.ldv_source)
        for key in ("offset_s", "f0_hz", "drift", "drift_rate_per_s", "quality", "ok", "n_cycles"):
            s.put(key, getattr(res, key))
        s.put("reason", np.asarray(res.reason, dtype=object))
        s.put("aligned_w", res.aligned_w.astype(np.float32))
        s.put("frame_time", inp.frame_time)
        s.put("video_phase", res.video_phase)
        s.set_attrs(f0_video_hz=res.f0_video_hz, template_real=res.template.real, template_imag=res.template.imag)
        for why, n in reasons.items():
            log.warning("%d LDV point(s) not aligned: %s", n, why)
        _check_levels(reader, inp, res)
        return {
            "points": int(res.ok.size),
            "aligned": int(res.ok.sum()),
            "f0_video_hz": round(float(res.f0_video_hz), 4),
            "not_aligned": dict(reasons),
        }

    config_json = stage_config_json("sync", ctx.config)
    return run_stage(ctx, "sync", config_json=config_json, body=body, upstream=[("hsc", None), ("ldv", None)])
