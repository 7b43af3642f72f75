"""## Unseen recordings: the whole pipeline on widened phantoms, scored against truth.h5 (issue 15).

For each seed: ``vfcli synth --set synth.panel='widened'`` (a camera at any angle and zoom, any
blur, fixture in view or not, other M5 geometry and material, its own intraglottal load,
vibrometer artefacts, a UFF with or without units record: vfcli/synth/widened.py), then the
stages as examples/demo.sh runs them (``ingest-hsc``, ``ingest-ldv``, ``sync``, ``flow``,
``mesh``, ``optimize``), each through the real CLI; a stage that fails stops the stages that
need it. Afterwards, and only then, truth.h5 is read and the products are scored with
:mod:`vfcli.synth.scoring`:

* every stage's exit code, its warnings (stderr lines naming a warning) and whether it exited 0
  with an empty product (no frames; no LDV points; no aligned point; no gap in any frame; no
  valid field pixel; an optimize gap term exactly 0);
* sync: RMS error of the epoch offsets (us), matched at the first frame, and of the instants matched to every
  frame (:func:`vfcli.synth.scoring.sync_frame_error`: what the phase-averaged velocities carry);
* gap: IoU of ``/flow/gap_mask`` against the true gap (pooled over frames); glottal area
  error: total over frames (sum of the reconstructed / sum of the true - 1) and the median
  relative error over frames open more than 10 % of the widest; the frames with a gap, and how wide the
  true gap opens in the open frames flow missed (:func:`vfcli.synth.scoring.opening_width_px`, the widest);
* LDV points: fraction whose ``/fields/ldv_px`` lies on the image, and the true fraction;
* flow: relative RMS error of ``/flow/flow`` (u, v) on the true visible surface against the true
  velocity in the model's (x, y) axes and in the image's (col, row) axes (which frame it is in);
* inferior surface (which no instrument sees), over optimize's window at the
  reconstruction mesh's inferior nodes: the oscillating part (displacement minus its mean over
  the window) RMS error relative to the RMS true oscillation; the static part (the mean over the
  window) RMS error, mm, and the true and reconstructed mean vertical displacement, mm; the
  total error relative to the RMS true displacement; the coverage of the 90 % intervals
  ``displacement +- 1.645 displacement_std`` (every inferior node, component and time; and per component), and of the
  static part's ``mean +- 1.645 displacement_std_static`` (every inferior node and component), with
  the stated standard deviation of the static vertical displacement (``inferior_static_mean_z_std_mm``);
* optimize's pose (from the config or estimated from the gap): rotation error (deg, wrapped) and
  model-origin error (mm), against the true pose or its 180-degree turn about the glottis centre
  (the same reconstruction of symmetric folds), whichever is nearer; the relative error of the motion data as optimize uses them
  (``/fields`` (u, v) turned by ``model_axes_velocity`` from /flow's rotation to the one it used) against the true
  (x, y) velocity; the final gap term (0: no gap rays);
* issue 15's targets per seed (:func:`targets`): gap IoU >= 0.9 and area within 5 %, the inferior surface
  within 10 % (oscillating), the 90 % intervals covering 85-95 %, no empty product; with flow's doubt on the gap
  as the store records it (:func:`gap_doubt`: never resolved, or a reading of the edges or of the level more than
  5 % from the product's), so a missed target reads as warned or not; and the counts over the seeds.

Reproduce::

    .venv/bin/python bench/bench_unseen.py SEED [SEED ...] [--duration 0.012] [--keep DIR]
        [--set synth.X=Y ...] [--optimize-set optimize.X=Y ...] [--until STAGE | --resume]

``--until flow --keep DIR`` runs the stages up to ``flow`` only; ``--resume --keep DIR`` later runs
the rest on the same stores (the records of the stages already run are kept), then scores.

``--duration`` must hold optimize's window (``optimize.n_frames``, one glottal cycle by default: 84 frames at 120 Hz
and 10 kHz).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.camera.camera import Camera  # noqa: E402
from vfcli.camera.pose import model_axes_velocity  # noqa: E402
from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA  # noqa: E402
from vfcli.model.mesh import FoldMesh  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.store.transaction import Store  # noqa: E402
from vfcli.store.truth import read_truth, truth_datasets  # noqa: E402
from vfcli.synth.scoring import (half_turned, interval_coverage, iou, opening_width_px, pose_half_turned,  # noqa: E402
                                 relative_rms_error, rms, side_truth, sync_frame_error,
                                 sync_offset_error)

STAGES = ["synth", "ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize"]
NEEDS = {"synth": [], "ingest-hsc": ["synth"], "ingest-ldv": ["synth"], "sync": ["ingest-hsc", "ingest-ldv"],
         "flow": ["sync"], "mesh": ["ingest-hsc"], "optimize": ["flow", "mesh"]}
#: what a user does when a stage fails with bad input and names the setting (the grid of a turned
#: camera's scan reads as 22 x 17 in the camera frame)
RETRY = {"ingest-ldv": ["ingest_ldv.grid_rows=22", "ingest_ldv.grid_cols=17"]}
WARN = re.compile(r"warn", re.IGNORECASE)


def run(args: list) -> tuple[int, float, str]:
    """(exit code, wall time s, stderr) of ``vfcli ARGS``."""
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args)], capture_output=True, text=True,
                         cwd=ROOT)
    return res.returncode, time.perf_counter() - t, res.stderr


def pipeline(seed: int, work: Path, duration: float, synth_sets: list[str], opt_sets: list[str],
             done: dict | None = None, until: str | None = None) -> dict:
    """Run every stage; {stage: (rc or None when skipped, wall s, warnings, last stderr line)}.

    ``done``: the records of stages an earlier run of this seed already ran (``--resume``), kept as
    they are and not run again; ``until``: the last stage to run (``--until``)."""
    raw, store = work / "raw", work / "recording.h5"
    sets = lambda xs: sum((["--set", s] for s in xs), [])  # noqa: E731
    cmds = {
        "synth": ["synth", raw, "--seed", seed,
                  *sets(["synth.panel='widened'", f"synth.duration_s={duration}", *synth_sets])],
        "ingest-hsc": ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                       "--config", raw / "recording.toml"],
        "ingest-ldv": ["ingest-ldv", store, raw / "scan.uff"],
        "sync": ["sync", store],
        "flow": ["flow", store],
        "mesh": ["mesh", store],
        "optimize": ["optimize", store, *sets(opt_sets)],
    }
    out = {}
    for stage in STAGES[: STAGES.index(until) + 1] if until else STAGES:
        if done and stage in done and done[stage][0] is not None:
            out.update({k: v for k, v in done.items() if k.split(" (")[0] == stage})
            continue
        if any(out.get(n, (None,))[0] != 0 for n in NEEDS[stage]):
            out[stage] = (None, 0.0, [], "skipped")
            continue
        rc, wall, err = run(cmds[stage])
        lines = [ln.strip() for ln in err.splitlines() if ln.strip()]
        out[stage] = (rc, wall, [ln for ln in lines if WARN.search(ln)], lines[-1] if lines else "")
        print(f"  seed {seed}: vfcli {stage}: exit {rc}, {wall:.0f} s" + (f" ({lines[-1][:160]})" if rc else ""),
              file=sys.stderr, flush=True)
        if rc == 3 and stage in RETRY:      # follow the error's advice once, as a user would; reported
            retry = RETRY[stage]
            rc2, wall2, err2 = run(cmds[stage] + sum((["--set", x] for x in retry), []))
            lines2 = [ln.strip() for ln in err2.splitlines() if ln.strip()]
            out[f"{stage} (first try)"] = out[stage]
            out[stage] = (rc2, wall2, [ln for ln in lines2 if WARN.search(ln)], lines2[-1] if lines2 else "")
            print(f"  seed {seed}: vfcli {stage} --set {' --set '.join(retry)}: exit {rc2}, {wall2:.0f} s", file=sys.stderr,
                  flush=True)
    return out


def empty_products(store: Path, stages: dict) -> list[str]:
    """Stages that exited 0 with an empty product (flow: also no LDV point on the image, so the
    fields' w comes from no measurement)."""
    empty = []
    with Store(store).read() as r:
        h, w = r.dataset("hsc", "frames").shape[1:] if stages["ingest-hsc"][0] == 0 else (0, 0)
        checks = {
            "ingest-hsc": lambda: r.dataset("hsc", "frames").shape[0] == 0,
            "ingest-ldv": lambda: r.dataset("ldv", "velocity").shape[0] == 0,
            "sync": lambda: not r.read("sync", "ok").any(),
            "flow": lambda: (not r.read("flow", "gap_mask").any() or not r.read("fields", "valid").any()
                             or not _on_image(r.read("fields", "ldv_px"), w, h).any()),
            "optimize": lambda: float(r.read("optimize", "history_gap", _run(r))[-1]) == 0.0,
        }
        for stage, check in checks.items():
            if stages[stage][0] == 0 and check():
                empty.append(stage)
    return empty


#: frames of the truth's per-pixel datasets scored at once
SCORE_CHUNK = 64


class RelativeError:
    """:func:`vfcli.synth.scoring.relative_rms_error` accumulated over slices: RMS(estimate - truth) / RMS(truth)
    over the entries finite in both."""

    def __init__(self) -> None:
        self.err = self.true = 0.0

    def add(self, estimate: np.ndarray, truth: np.ndarray) -> None:
        ok = np.isfinite(estimate) & np.isfinite(truth)
        self.err += float(np.sum((estimate - truth)[ok] ** 2))
        self.true += float(np.sum(truth[ok] ** 2))

    def value(self) -> float:
        return float(np.sqrt(self.err / self.true)) if self.true > 0 else float("nan")


def _run(r) -> str | None:
    """The run this benchmark made (``default``; else the store's first, for stores fitted otherwise)."""
    runs = [p.split("/")[-1] for p in r.stage_paths() if p.startswith("/optimize/")]
    return "default" if "default" in runs else (runs[0] if runs else None)


def score_inferior(t: dict, mesh: FoldMesh, disp: np.ndarray, std: np.ndarray, std_static: np.ndarray | None,
                   sim_time: np.ndarray, turned: bool = False) -> dict:
    """The inferior surface of a run against the phantom's truth.

    t : truth arrays (``frames/time``, ``frames/displacement`` and ``mesh/<key>``, :func:`read_truth`).
    disp, std : (T, N, 3) the run's displacements and stated sd at ``sim_time`` (T,), mm, the last time left out.
    std_static : (N, 3) the stated sd of the static part, mm, or None.
    turned : the run's pose is half a turn off the phantom's (the same reconstruction in a frame whose left
        fold is the phantom's right): the truth is compared in the run's frame (``half_turned``).
    """
    s: dict = {}
    truth_mesh = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    idx = np.searchsorted(t["frames/time"], sim_time - 1e-9)
    true = t["frames/displacement"][idx].astype(float)
    phantom = (truth_mesh.uv, truth_mesh.node_side, true)
    nodes, ref = side_truth(mesh.uv, mesh.node_side, *(half_turned(*phantom) if turned else phantom), 1)
    est = disp[:, nodes]
    est_mean, ref_mean = est.mean(axis=0), ref.mean(axis=0)
    osc_true = ref - ref_mean
    s["inf_osc_err"] = rms((est - est_mean) - osc_true) / rms(osc_true)
    s["inf_static_err_mm"] = rms(est_mean - ref_mean)
    s["inf_static_true_rms_mm"] = rms(ref_mean)
    s["inf_mean_z_true_mm"] = float(ref_mean[:, 2].mean())
    s["inf_mean_z_est_mm"] = float(est_mean[:, 2].mean())
    s["inf_total_err"] = rms(est - ref) / rms(ref)
    s["coverage90"] = interval_coverage(est, std[:, nodes], ref)
    s["coverage90_xyz"] = [interval_coverage(est[..., c], std[:, nodes][..., c], ref[..., c]) for c in range(3)]
    s["coverage90_static"] = (interval_coverage(est_mean, std_static[nodes], ref_mean) if std_static is not None
                              else float("nan"))
    s["stated_std_rel"] = rms(std[:, nodes]) / rms(ref)
    s["inf_nodes_scored"] = int(len(nodes))
    return s


def score(raw: Path, store: Path, stages: dict) -> dict:
    """The figures of the module docstring (NaN where a stage did not run)."""
    s: dict = {}
    t, a = read_truth(raw / "truth.h5", ["screen/gap", "screen/glottal_area", "ldv/sync_offset_s", "ldv/f0_hz",
                                         "frames/phase",
                                         "ldv/points_model_mm", "frames/time", "frames/displacement"] +
                      [f"mesh/{k}" for k in ("nodes", "tets", "tet_fold", "faces", "face_tag", "face_fold", "uv",
                                             "node_side")])
    s["draw"] = {k.removeprefix("widened_"): a[k] for k in a if k.startswith("widened_")}
    cam = Camera(a["camera_px_per_mm"], a["camera_rotation_deg"], tuple(a["camera_offset_px"]), 1, 1)
    true_px = cam.project(t["ldv/points_model_mm"])
    h, w = t["screen/gap"].shape[1:]
    s["ldv_on_image_true"] = float(np.mean(_on_image(true_px, w, h)))
    with Store(store).read() as r:
        if stages["sync"][0] == 0:
            off, ok = r.read("sync", "offset_s"), r.read("sync", "ok")
            err = sync_offset_error(off, t["ldv/sync_offset_s"], t["ldv/f0_hz"])
            s["sync_rms_us"] = 1e6 * rms(err[ok]) if ok.any() else float("nan")
            video_phase = r.read("sync", "video_phase")
            frame_err = sync_frame_error(err[ok], video_phase, t["frames/phase"][: len(video_phase)],
                                         t["ldv/f0_hz"][ok])
            s["sync_frames_rms_us"] = 1e6 * rms(frame_err)             # NaN when no point is aligned
        if stages["flow"][0] == 0:
            gap, area = r.read("flow", "gap_mask"), r.read("flow", "glottal_area")
            tg, ta = t["screen/gap"][: len(gap)], t["screen/glottal_area"][: len(area)]
            s["gap_iou"] = iou(gap, tg)
            s["area_total_err"] = float(area.sum() / ta.sum() - 1) if ta.sum() > 0 else float("nan")
            open_ = ta > 0.1 * ta.max()
            s["area_median_err"] = float(np.median(np.abs(area[open_] - ta[open_]) / ta[open_])) if open_.any() else float("nan")
            # how wide the true gap opens in the open frames flow missed (the glottis along the model's x axis)
            missed = tg.any(axis=(1, 2)) & ~gap.any(axis=(1, 2))
            widest = opening_width_px(tg[missed], cam.project_vector(np.array([1.0, 0.0])))
            s["missed_widest_px"] = float(widest.max()) if missed.any() else float("nan")
            n_found, n_true = int(gap.any(axis=(1, 2)).sum()), int(tg.any(axis=(1, 2)).sum())
            note = f"; the missed open {s['missed_widest_px']:.1f} px at most" if missed.any() else ""
            s["frames_with_gap"] = f"{n_found}/{len(gap)} (true {n_true}{note})"
            s["gap_doubt"] = gap_doubt(r.attrs("flow"))
            px = r.read("fields", "ldv_px")
            s["ldv_on_image"] = float(np.mean(_on_image(px, w, h)))
            # which axes the flow's (u, v) are in: the model's (x, y) or the image's (col, row); streamed in slices
            # of frames (a 1600-frame 384 x 384 px phantom's scoring was killed at 17 GB holding them whole)
            model_axes, image_axes = RelativeError(), RelativeError()
            flow = r.dataset("flow", "flow")
            with truth_datasets(raw / "truth.h5") as tds:
                for i in range(0, len(gap), SCORE_CHUNK):
                    j = min(i + SCORE_CHUNK, len(gap))
                    surface = tds["screen/visible"][i:j] & ~tg[i:j] & ~gap[i:j]
                    surface[[k - i for k in (0, len(gap) - 1) if i <= k < j]] = False
                    true_v = tds["screen/velocity"][i:j][surface].astype(float)
                    f_uv = np.asarray(flow[i:j], float)[surface]
                    model_axes.add(f_uv, true_v[:, :2])
                    image_axes.add(f_uv, cam.project_vector(true_v) / cam.px_per_mm)
            s["flow_err_model_axes"] = model_axes.value()
            s["flow_err_image_axes"] = image_axes.value()
        if stages["optimize"][0] == 0:
            run_name = _run(r)
            mesh = read_mesh(r)
            disp = r.read("optimize", "displacements", run_name).astype(float)[:-1]
            std = r.read("optimize", "displacement_std", run_name).astype(float)[:-1]
            g = r.group("optimize", run_name)
            std_static = r.read("optimize", "displacement_std_static", run_name).astype(float) \
                if "displacement_std_static" in g else None
            s["stated_static_mean_z_mm"] = float(r.attrs("optimize", run_name).get("inferior_static_mean_z_std_mm", np.nan))
            sim_time = r.read("optimize", "sim_time", run_name)[:-1]
            s["gap_term_final"] = float(r.read("optimize", "history_gap", run_name)[-1])
            oa = r.attrs("optimize", run_name)
            rot_used, off_used = float(oa["camera_rotation_deg"]), np.asarray(oa["camera_offset_px"], float)
            s["pose"] = str(oa.get("pose_source", "?"))
            # the folds are symmetric: the pose turned by 180 deg about the glottis centre (origin at x = L)
            # is the same reconstruction; score against the nearer of the two and say which
            rot_err = float(np.mod(rot_used - a["camera_rotation_deg"] + 180.0, 360.0) - 180.0)
            flipped = pose_half_turned(rot_used, a["camera_rotation_deg"])
            true_off = np.asarray(a["camera_offset_px"], float)
            if flipped:
                true_off = true_off + cam.project(np.array([[a["widened_length_mm"], 0.0]]))[0] - cam.project(np.zeros((1, 2)))[0]
                rot_err = float(np.mod(rot_err, 360.0) - 180.0)
            s["pose_flipped"] = flipped
            s["pose_rot_err_deg"] = rot_err
            s["pose_origin_err_mm"] = float(np.linalg.norm(off_used - true_off) / cam.px_per_mm)
            # the motion data as optimize uses them: /fields (u, v), model axes of /flow's rotation, turned by
            # the difference to the rotation used (vfcli.camera.pose.model_axes_velocity)
            fi = np.searchsorted(r.read("fields", "frame_time"), sim_time - 1e-9)
            fv = r.read("fields", "velocity")[fi].astype(float)
            valid = r.read("fields", "valid")[fi]
            at, back = np.unique(np.searchsorted(t["frames/time"], sim_time - 1e-9), return_inverse=True)
            with truth_datasets(raw / "truth.h5") as tds:
                true_w = tds["screen/velocity"][at][back]           # the window's frames only
            ok = valid & np.isfinite(true_w).all(axis=-1)
            sign = -1.0 if flipped else 1.0     # model (x, y) reversed in the flipped pose
            s["motion_data_err"] = relative_rms_error(model_axes_velocity(fv[..., :2], float(r.attrs("flow").get("rotation_deg", 0.0)), rot_used)[ok], sign * true_w[ok][:, :2])
            del true_w, fv
    if stages["optimize"][0] == 0:
        s.update(score_inferior(t, mesh, disp, std, std_static, sim_time, s["pose_flipped"]))
    return s


def gap_doubt(flow_attrs: dict) -> str:
    """flow's doubt on the gap as its stage stored it: "never resolved" (``gap_level_resolved`` false), else the
    readings more than :data:`vfcli.flow.gap.subpixel.ambiguity.AMBIGUOUS_AREA` from the product's
    (``edge_disagreement``, ``level_disagreement``), else "none" with both readings' figures."""
    edge = 100 * float(flow_attrs.get("edge_disagreement", np.nan))
    level = 100 * float(flow_attrs.get("level_disagreement", np.nan))
    if not bool(flow_attrs.get("gap_level_resolved", True)):
        return "never resolved"
    over = [f"{name} reading {v:.0f} % off" for name, v in (("edge", edge), ("level", level))
            if v > 100 * AMBIGUOUS_AREA]
    if over:
        return "; ".join(over)
    read = [f"{name} {v:.1f} %" for name, v in (("edges", edge), ("level", level)) if np.isfinite(v)]
    return f"none ({', '.join(read)})" if read else "none"


#: issue 15's proof targets: gap IoU at least, |area error| at most, inferior oscillating error at most, coverage range
GAP_IOU, AREA_ERR, INFERIOR_ERR, COVERAGE = 0.9, 0.05, 0.10, (0.85, 0.95)


def targets(s: dict, empty: list) -> dict:
    """Which of issue 15's targets the seed's figures ``s`` (:func:`score`) meet: ``gap``, ``inferior``, ``coverage``
    (True/False; None where not scored), ``no_empty`` (True when no stage exited 0 with an empty product); ``warned``:
    flow stored a doubt on the gap (:func:`gap_doubt`)."""
    def met(key, ok):
        v = s.get(key)
        return None if v is None or not np.isfinite(v) else bool(ok(v))
    gap = met("gap_iou", lambda v: v >= GAP_IOU)
    area = met("area_total_err", lambda v: abs(v) <= AREA_ERR)
    return {"gap": None if gap is None or area is None else gap and area,
            "inferior": met("inf_osc_err", lambda v: v <= INFERIOR_ERR),
            "coverage": met("coverage90", lambda v: COVERAGE[0] <= v <= COVERAGE[1]),
            "no_empty": not empty,
            "warned": not str(s.get("gap_doubt", "none")).startswith("none")}


def _on_image(px: np.ndarray, w: int, h: int) -> np.ndarray:
    px = np.asarray(px, float)
    return np.isfinite(px).all(axis=1) & (px[:, 0] >= -0.5) & (px[:, 0] <= w - 0.5) & (px[:, 1] >= -0.5) & (px[:, 1] <= h - 0.5)


def _fmt(v, pct=False, digits=2) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{100 * v:.{max(digits - 2, 0)}f}%" if pct else (f"{v:.{digits}f}" if isinstance(v, float) else str(v))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--duration", type=float, default=0.012)
    ap.add_argument("--keep", type=Path, default=None, help="folder for the phantoms and stores (else a temporary one)")
    ap.add_argument("--set", dest="sets", action="append", default=[])
    ap.add_argument("--optimize-set", dest="opt_sets", action="append", default=[])
    ap.add_argument("--until", choices=STAGES, default=None,
                    help="run the stages up to this one only (the rest with --resume later)")
    ap.add_argument("--resume", action="store_true",
                    help="in --keep DIR, keep the stages an earlier (--until) run ran and run the others")
    ap.add_argument("--rescore", action="store_true",
                    help="score the products of an earlier run in --keep DIR again (its stages.json) without rerunning")
    args = ap.parse_args()
    if (args.rescore or args.resume) and args.keep is None:
        ap.error("--rescore and --resume need --keep DIR")
    base = args.keep or Path(tempfile.mkdtemp(prefix="bench_unseen_"))
    results = []
    for seed in args.seeds:
        work = base / f"seed{seed}"
        work.mkdir(parents=True, exist_ok=True)
        if args.rescore:
            stages = {k: tuple(v) for k, v in json.loads((work / "stages.json").read_text()).items()}
        else:
            done = None
            if args.resume and (work / "stages.json").exists():
                done = {k: tuple(v) for k, v in json.loads((work / "stages.json").read_text()).items()}
            else:
                (work / "recording.h5").unlink(missing_ok=True)
            stages = pipeline(seed, work, args.duration, args.sets, args.opt_sets, done, args.until)
            (work / "stages.json").write_text(json.dumps(stages))
            if args.until:
                print(f"  seed {seed}: stopped after {args.until} (--until); score with --resume", file=sys.stderr)
                continue
        store = work / "recording.h5"
        empty = empty_products(store, stages) if store.exists() else []
        s = score(work / "raw", store, stages) if stages["synth"][0] == 0 else {}
        results.append((seed, stages, empty, s))

    fps = next((float(x.split("=", 1)[1]) for x in reversed(args.sets) if x.startswith("synth.fps_hz=")), 1e4)
    print(f"Widened phantoms, effect none, {int(round(args.duration * fps))} frames at {fps / 1e3:g} kHz; "
          f"work folder {base}\n")
    print("| seed | rotation (deg), stated | field of view / glottis length | blur (px) | fixture | UFF units | E / nominal |")
    print("| ---: | --- | ---: | ---: | --- | --- | ---: |")
    for seed, _, _, s in results:
        d = s.get("draw", {})
        if d:
            print(f"| {seed} | {d['rotation_deg']:.1f}, {'yes' if d['rotation_stated'] else 'no'} | "
                  f"{d['fov_mm']:.1f} / {d['length_mm']:.1f} mm | {d['psf_sigma_px']:.2f} | "
                  f"{'yes' if d['fixture_in_view'] else 'no'} | {'yes' if d['uff_units_record'] else 'no'} | "
                  f"{d['youngs_modulus_pa'] / 4400:.3f} |")
    print("\n| seed | " + " | ".join(STAGES) + " | exited 0 with an empty product |")
    print("| ---: |" + " --- |" * (len(STAGES) + 1))
    for seed, stages, empty, _ in results:
        cells = [("skipped" if st[0] is None else f"exit {st[0]}") + (f", {len(st[2])} warning(s)" if st[2] else "")
                 + (f" (first try exit {stages[k + ' (first try)'][0]}, retried with the advised setting)"
                    if k + " (first try)" in stages else "")
                 for k, st in ((k, stages[k]) for k in STAGES)]
        print(f"| {seed} | " + " | ".join(cells) + f" | {', '.join(empty) or 'none'} |")
    print("\n| seed | sync RMS (us): first frame / over the frames | gap IoU | area error (total) | area error (median, open) | frames with gap | "
          "LDV on image (true) | flow error in model / image axes | inferior oscillating error | inferior static error (mm) | mean z true / est (mm) | "
          "inferior total error | 90 % coverage (static part) | stated std / RMS true | stated static std of mean z (mm) |")
    print("| ---: |" + " ---: |" * 14)
    for seed, _, _, s in results:
        print(f"| {seed} | {_fmt(s.get('sync_rms_us'))} / {_fmt(s.get('sync_frames_rms_us'))} | {_fmt(s.get('gap_iou'), digits=3)} | {_fmt(s.get('area_total_err'), True, 3)} | "
              f"{_fmt(s.get('area_median_err'), True, 3)} | {s.get('frames_with_gap', '-')} | "
              f"{_fmt(s.get('ldv_on_image'))} ({_fmt(s.get('ldv_on_image_true'))}) | "
              f"{_fmt(s.get('flow_err_model_axes'), True, 2)} / {_fmt(s.get('flow_err_image_axes'), True, 2)} | {_fmt(s.get('inf_osc_err'), True, 2)} | "
              f"{_fmt(s.get('inf_static_err_mm'), digits=3)} | {_fmt(s.get('inf_mean_z_true_mm'), digits=3)} / "
              f"{_fmt(s.get('inf_mean_z_est_mm'), digits=3)} | {_fmt(s.get('inf_total_err'), True, 2)} | "
              f"{_fmt(s.get('coverage90'), True, 3)} ({_fmt(s.get('coverage90_static'), True, 3)}) | "
              f"{_fmt(s.get('stated_std_rel'), True, 2)} | {_fmt(s.get('stated_static_mean_z_mm'), digits=3)} |")
    print("\n| seed | pose source | rotation error (deg) | model origin error (mm) | optimize's (x, y) motion data error "
          "| final gap term | inferior nodes scored |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for seed, _, _, s in results:
        flip = " (turned by 180 deg: equivalent)" if s.get("pose_flipped") else ""
        print(f"| {seed} | {s.get('pose', '-')}{flip} | {_fmt(s.get('pose_rot_err_deg'), digits=1)} | "
              f"{_fmt(s.get('pose_origin_err_mm'))} | {_fmt(s.get('motion_data_err'), True, 2)} | "
              f"{_fmt(s.get('gap_term_final'), digits=3)} | {s.get('inf_nodes_scored', '-')} |")
    print("\n| seed | gap IoU / area error | flow's doubt on the gap | gap target | inferior within 10 % | "
          "coverage 85-95 % | no empty product |")
    print("| ---: | --- | --- | --- | --- | --- | --- |")
    yes = {True: "yes", False: "no", None: "-"}
    met = []
    for seed, _, empty, s in results:
        t = targets(s, empty)
        met.append(t)
        gap = yes[t["gap"]] + (" (warned)" if t["gap"] is False and t["warned"] else
                               " (unwarned)" if t["gap"] is False else "")
        cov = yes[t["coverage"]] + ((" (too wide)" if s["coverage90"] > COVERAGE[1] else " (too narrow)")
                                    if t["coverage"] is False else "")
        print(f"| {seed} | {_fmt(s.get('gap_iou'), digits=3)} / {_fmt(s.get('area_total_err'), True, 3)} | "
              f"{s.get('gap_doubt', '-')} | {gap} | {yes[t['inferior']]} | {cov} | {yes[t['no_empty']]} |")
    count = lambda key: sum(t[key] is True for t in met)  # noqa: E731
    unwarned = sum(t["gap"] is False and not t["warned"] for t in met)
    print(f"\nTargets over {len(met)} seeds: gap {count('gap')} ({unwarned} of the misses unwarned), inferior "
          f"{count('inferior')}, coverage {count('coverage')}, no empty product {count('no_empty')}.")
    print("\nWarnings and failures:")
    for seed, stages, _, _ in results:
        for k in [k for k in stages if k.split(" ")[0] in STAGES]:
            rc, _, warns, last = stages[k]
            distinct = list(dict.fromkeys(warns))
            for wline in distinct[:3]:
                print(f"- seed {seed}, {k}: {wline[:300]}")
            if len(distinct) > 3:
                print(f"- seed {seed}, {k}: ... and {len(distinct) - 3} more warning lines like these")
            if rc not in (0, None):
                print(f"- seed {seed}, {k} exit {rc}: {last[:300]}")
    more = "".join(f" --set {x}" for x in args.sets) + "".join(f" --optimize-set {x}" for x in args.opt_sets)
    print(f"\nReproduce: `.venv/bin/python bench/bench_unseen.py {' '.join(map(str, args.seeds))} "
          f"--duration {args.duration}{more}`")


if __name__ == "__main__":
    main()
