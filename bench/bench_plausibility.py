"""What the plausibility checks of session 36 measure on stores: one line per store.

For every store given (or found under the folders given) that holds the stages a check needs:

* ``gap/L``: the gap's extent over the recording against the folds' length (vfcli.flow.plausibility.gap_length_share;
  `flow` warns above GAP_LONGER_WARN = 1.1, plus 2 px at each end);
* ``area f0 / p f0``: the glottal area's f0 on the video's time base against /sync's (vfcli.flow.plausibility.area_f0;
  `flow` warns beyond sync.max_drift);
* ``levels``: "ok" or the pressure levels that differ beside the video and the scan (vfcli.sync.levels);
* ``vert/horiz``: the vibrometer's vertical RMS velocity against the video's horizontal one over the valid pixels of
  24 frames spread over /fields (`fields` warns beyond VELOCITY_ORDER = 30 either way).

Reproduce: ``.venv/bin/python bench/bench_plausibility.py DIR_OR_STORE ...`` (docs/benchmarks.md, "Plausibility checks").
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from vfcli.flow.plausibility import area_f0, gap_length_share
from vfcli.store import Store
from vfcli.sync.levels import cycle_levels, level_mismatch


def _stores(args: list[str]) -> list[Path]:
    out = []
    for a in map(Path, args):
        out += [p for p in sorted(a.rglob("*.h5")) if ".parts" not in str(p) and p.name != "truth.h5"] if a.is_dir() \
            else [a]
    return out


def measure(path: Path) -> dict:
    row: dict = {"store": str(path)}
    with Store(path).read() as r:
        if r.has_stage("flow"):
            ds = r.dataset("flow", "gap_mask")
            counts = np.zeros(ds.shape[1:], int)
            for k in range(0, ds.shape[0], 64):
                counts += np.asarray(ds[k:k + 64]).astype(bool).sum(axis=0)
            length_mm = json.loads(r.recording_config_json() or "{}").get("mesh", {}).get("length_mm", 15.0)
            length_px = length_mm * float(r.attrs("hsc")["px_per_mm"])
            if (counts > 0).sum() >= 3:
                row["gap/L"] = gap_length_share(counts, length_px)[0] / length_px
        if r.has_stage("flow") and r.has_stage("sync"):
            f0 = float(r.attrs("sync")["f0_video_hz"])
            fa = area_f0(r.read("flow", "glottal_area"), float(r.attrs("hsc")["fps_hz"]), (50.0, 500.0), f0)
            row["area f0 / p f0"] = None if fa is None else fa / f0
        if r.has_stage("sync") and str(r.dataset("ldv", "reference").attrs.get("units", "")) == "Pa":
            video = cycle_levels(r.read("hsc", "pressure"), float(r.attrs("hsc")["pressure_fs_hz"]),
                                 float(r.attrs("sync")["f0_video_hz"]))
            ref, fs = r.read("ldv", "reference").astype(float), float(r.attrs("ldv")["fs_hz"])
            ok, f0s = r.read("sync", "ok").astype(bool), r.read("sync", "f0_hz")
            pts = [cycle_levels(ref[i], fs, f0s[i]) for i in np.flatnonzero(ok)]
            pts = np.array([p for p in pts if p is not None])
            if video is not None and len(pts):
                row["levels"] = [m[0] for m in level_mismatch(video, pts)] or "ok"
        if r.has_stage("fields"):
            vel, valid = r.dataset("fields", "velocity"), r.dataset("fields", "valid")
            idx = np.unique(np.linspace(0, vel.shape[0] - 1, min(vel.shape[0], 24)).astype(int))
            v, ok = np.asarray(vel[idx], float), np.asarray(valid[idx], bool)
            sel = ok & np.isfinite(v).all(axis=-1)
            if sel.any():
                row["vert/horiz"] = float(np.sqrt(np.mean(v[..., 2][sel] ** 2) /
                                                  np.mean(np.sum(v[..., :2][sel] ** 2, axis=-1))))
    return row


def main(argv: list[str]) -> None:
    for path in _stores(argv):
        try:
            row = measure(path)
        except Exception as exc:                       # a scratch store of another layout: say so, go on
            print(f"{path}: not measured ({type(exc).__name__}: {exc})")
            continue
        print("  ".join(f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))


if __name__ == "__main__":
    main(sys.argv[1:])
