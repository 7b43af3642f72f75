"""## Phantom accuracy of ingest, sync and flow (scored against truth.h5).

Writes a phantom with `vfcli synth`, runs `ingest-hsc`, `ingest-ldv`, `sync` and `flow`
(once with the paper's SparseToDense flow, once with DIS) through the real CLI, and scores:

* sync: RMS error of every LDV epoch's offset (us);
* flow: end-point error of the horizontal flow on the visible fold surface (px/frame and
  mm/s; mean and 95th percentile), gap-mask IoU (pooled over frames), glottal-area error;
* fields: RMS error of w against the true vertical surface velocity inside the LDV hull,
  relative to the RMS true w;
* wall time of each command.

Reproduce::

    .venv/bin/python bench/bench_phantom_pipeline.py [--seed 1] [--duration 0.05] [--set synth.X=Y ...]
        [--flow-set flow.X=Y ...] [--raw DIR]

``--raw DIR`` reuses (or, when DIR is empty, writes) the phantom there instead of a temporary
directory; ``--flow-set`` passes overrides to ``vfcli flow`` (e.g. ``flow.subpixel_edges=false``
for the paper's binary gap mask).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.camera.camera import Camera  # noqa: E402
from vfcli.synth.scoring import end_point_error, iou, relative_rms_error, sync_offset_error  # noqa: E402
from vfcli.store import Store, read_truth  # noqa: E402


def vfcli(*args) -> float:
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args), "-q"], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"vfcli {args[0]} failed: {res.stderr}")
    return time.perf_counter() - t


def score(store: Path, truth_path: Path) -> dict[str, float]:
    t, a = read_truth(truth_path, ["screen/velocity", "screen/gap", "screen/visible", "screen/glottal_area",
                                    "ldv/sync_offset_s", "ldv/f0_hz"])
    cam = Camera(a["camera_px_per_mm"], a["camera_rotation_deg"], tuple(a["camera_offset_px"]), 1, 1)
    with Store(store).read() as r:
        fps = float(r.attrs("hsc")["fps_hz"])
        px_per_mm = float(r.attrs("hsc")["px_per_mm"])
        flow = r.read("flow", "flow")  # mm/s in camera axes (config rotation 0)
        gap = r.read("flow", "gap_mask")
        area = r.read("flow", "glottal_area")
        w = r.read("fields", "velocity")[..., 2]
        valid = r.read("fields", "valid")
        off, ok = r.read("sync", "offset_s"), r.read("sync", "ok")
    true_v = t["screen/velocity"]
    true_px = cam.project_vector(true_v) / fps  # px/frame
    flow_px = flow * px_per_mm / fps
    surface = t["screen/visible"] & ~t["screen/gap"] & ~gap
    surface[[0, -1]] = False  # first and last frames are extrapolated
    epe, epe95 = end_point_error(flow_px, true_px, surface)
    err = sync_offset_error(off, t["ldv/sync_offset_s"], t["ldv/f0_hz"])
    open_frames = t["screen/glottal_area"] > 0.5
    return {
        "sync_rms_us": 1e6 * float(np.sqrt(np.mean(err[ok] ** 2))),
        "epe_px": epe, "epe95_px": epe95, "epe_mm_s": epe * fps / px_per_mm,
        "gap_iou": iou(gap, t["screen/gap"]),
        "area_err_rel": float(np.median(np.abs(area[open_frames] - t["screen/glottal_area"][open_frames])
                                        / t["screen/glottal_area"][open_frames])) if open_frames.any() else float("nan"),
        "w_err_rel": relative_rms_error(np.where(valid & surface, w, np.nan), np.where(valid & surface, true_v[..., 2], np.nan)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=0.05)
    ap.add_argument("--set", dest="sets", action="append", default=[])
    ap.add_argument("--flow-set", dest="flow_sets", action="append", default=[])
    ap.add_argument("--raw", type=Path, default=None, help="phantom directory to reuse (written if missing)")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp())
    raw = args.raw if args.raw is not None else work / "raw"
    sets = sum((["--set", s] for s in [f"synth.duration_s={args.duration}", *args.sets]), [])
    times = {}
    if not (raw / "truth.h5").exists():
        times["synth"] = vfcli("synth", raw, "--seed", args.seed, *sets)
    flow_sets = sum((["--set", s] for s in args.flow_sets), [])
    rows = []
    for method in ("sparse_to_dense", "dis"):
        store = work / f"{method}.h5"
        times["ingest-hsc"] = vfcli("ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                                    "--config", raw / "recording.toml")
        times["ingest-ldv"] = vfcli("ingest-ldv", store, raw / "scan.uff")
        times["sync"] = vfcli("sync", store)
        times[f"flow ({method})"] = vfcli("flow", store, "--set", f"flow.method={method!r}", *flow_sets)
        rows.append((method, score(store, raw / "truth.h5")))
    n_frames = int(round(args.duration * 10000))
    extra = f", flow overrides {', '.join(args.flow_sets)}" if args.flow_sets else ""
    print(f"Phantom seed {args.seed}, effect none, {n_frames} frames of 256 x 256, 374 LDV points{extra}\n")
    print("| flow method | sync RMS (us) | EPE mean (px/frame) | EPE 95% (px/frame) | EPE mean (mm/s) | gap IoU | area error (median, open frames) | w error (rel. RMS) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for m, s in rows:
        print(f"| {m} | {s['sync_rms_us']:.2f} | {s['epe_px']:.3f} | {s['epe95_px']:.3f} | {s['epe_mm_s']:.1f} | "
              f"{s['gap_iou']:.3f} | {100 * s['area_err_rel']:.1f}% | {100 * s['w_err_rel']:.1f}% |")
    print("\n| command | wall time (s) |\n| --- | ---: |")
    for k, v in times.items():
        print(f"| vfcli {k} | {v:.1f} |")
    more = "".join(f" --flow-set {s}" for s in args.flow_sets)
    print(f"\nReproduce: `.venv/bin/python bench/bench_phantom_pipeline.py --seed {args.seed} --duration {args.duration}{more}`")


if __name__ == "__main__":
    main()
