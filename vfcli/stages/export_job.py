"""What `vfcli export` and `vfcli report` share: one export job over an open store.

:class:`ExportJob` reads the store (read only) and hands numpy arrays to the drawing core
(vfcli/export: figures, video, paraview, sampling, tables; vfcli/report/html.py). It is not a
stage of its own: the export stage (:mod:`vfcli.stages.export`) and the report stage
(:mod:`vfcli.stages.report`) both drive it, the way every stage uses :mod:`vfcli.stages.base`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.camera.pose import model_axes_velocity
from vfcli.errors import ConfigError, VfcliError
from vfcli.export import figures, paraview, sampling, tables, video
from vfcli.export.figures import FORMATS as FIGURE_FORMATS
from vfcli.store.runs import OptimizeRun, read_mesh
from vfcli.store.vtkhdf import write_transient_tets
from vfcli.store.transaction import StoreReader


log = logging.getLogger(__name__)

WHAT = ("paraview", "video", "figures", "tables")
MANIFEST = "export.json"

@dataclass
class ExportResult:
    """What an export did (printed by the CLI like a stage result)."""

    stage: str
    status: Literal["written", "up-to-date"]
    summary: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"stage": self.stage, "status": self.status, **self.summary}


def parse_what(text: str) -> tuple[str, ...]:
    """``"paraview,video"`` -> ('paraview', 'video'); ConfigError naming an unknown item."""
    items = tuple(dict.fromkeys(s.strip() for s in text.split(",") if s.strip()))
    bad = [s for s in items if s not in WHAT]
    if bad or not items:
        raise ConfigError(f"--what {text!r}: choose from {', '.join(WHAT)} (comma separated)")
    return items


def parse_point(text: str) -> tuple[float, float]:
    """``"120,64"`` -> (120.0, 64.0) screen pixel (col, row); ConfigError otherwise."""
    try:
        col, row = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--point {text!r}: expected COL,ROW in pixels, e.g. 120,64") from None
    return col, row


def run_camera(run: OptimizeRun, shape: tuple[int, int]) -> Camera:
    """The camera pose a run was fitted with, on frames of ``shape`` (rows, cols)."""
    a = run.attrs
    return Camera(float(a["px_per_mm"]), float(a["camera_rotation_deg"]),
                  tuple(np.asarray(a["camera_offset_px"], float)), shape[1], shape[0])


class ExportJob:
    """One export: the open store, the runs and the output folder."""

    def __init__(self, reader: StoreReader, runs: list[OptimizeRun], out: Path, times_ms: list[float] | None,
                 fps: float, points_px: list[tuple[float, float]] | None = None) -> None:
        self.r, self.runs, self.out, self.fps = reader, runs, out, fps
        self.points_px = points_px
        self.times_ms = times_ms
        self.mesh = read_mesh(reader) if reader.has_stage("mesh") else None
        self.frames = reader.frames("hsc", "frames")
        self.frame_time = np.asarray(reader.read("hsc", "frame_time"), float)
        self.shape = tuple(self.frames[0].shape)
        self.cameras = {run.name: run_camera(run, self.shape) for run in runs}
        self.files: list[Path] = []
        self.notes: list[str] = []
        h, w = self.shape[:2]
        bad = [p for p in (points_px or []) if not (0 <= p[0] < w and 0 <= p[1] < h)]
        if bad:
            raise ConfigError(f"--point {bad[0][0]:g},{bad[0][1]:g}: outside the {w} x {h} px frames")

    # -- ParaView ---------------------------------------------------------
    def paraview(self) -> None:
        d = self.out / "paraview"
        d.mkdir(parents=True, exist_ok=True)
        for run in self.runs:
            fields = paraview.motion_fields(run.sim_time, run.displacements, run.displacement_std, self._load(run))
            pts = self.mesh.nodes[None].astype(np.float64) + run.displacements.astype(np.float64)
            fold = np.broadcast_to(paraview.node_fold(self.mesh), pts.shape[:2])   # as the .vtu files have it
            write_transient_tets(d / f"{run.name}.vtkhdf", pts, self.mesh.tets, run.sim_time, {**fields, "fold": fold})
            self.files.append(d / f"{run.name}.vtkhdf")
            self.files += paraview.write_pvd(d / f"{run.name}.pvd", self.mesh, run.sim_time, run.displacements, fields)

    def _load(self, run: OptimizeRun) -> np.ndarray | None:
        """(T, N, 3) Pa applied surface traction of a run, or None (with a note) when it cannot be rebuilt."""
        from vfcli.export.loads import applied_traction
        from vfcli.store.fit import video_f0_hz

        pressure = None
        if self.r.has_stage("hsc") and "pressure" in self.r.group("hsc"):
            pressure = (self.r.read("hsc", "pressure_time"), self.r.read("hsc", "pressure"))
        try:
            return applied_traction(self.mesh, run.config.get("optimize", {}), run.config.get("mesh", {}),
                                    run.controls, run.sim_time, pressure, video_f0_hz(self.r))
        except (ValueError, KeyError, VfcliError) as exc:
            self.notes.append(f"run {run.name}: applied load not exported ({exc})")
            return None

    # -- the model over the video -----------------------------------------
    def overlay_frames(self, scale: int = 2) -> tuple[list[np.ndarray], list[float]]:
        """Side-by-side overlay images (one panel per run) at the first run's model times."""
        sup = self.mesh.faces[self.mesh.face_tag == 2]
        t_ref = self.runs[0].sim_time
        all_idx = np.concatenate([sampling.nearest_frames(self.frame_time, r.sim_time) for r in self.runs])
        sample = self.frames[np.unique(all_idx)].astype(float)
        lo, hi = np.percentile(sample, [0.5, 99.5])
        vmax = max(float(np.max(np.linalg.norm(r.displacements, axis=2)[:, np.unique(sup)])) for r in self.runs)
        images, times = [], []
        for k in range(len(t_ref)):
            panels = []
            for run in self.runs:
                kk = min(k, len(run.sim_time) - 1)
                fi = int(sampling.nearest_frames(self.frame_time, run.sim_time[kk:kk + 1])[0])
                base = video.gray_to_rgb(self.frames[fi], lo, hi, scale)
                verts = self.mesh.nodes + run.displacements[kk]
                mag = np.linalg.norm(run.displacements[kk], axis=1)
                img = video.draw_mesh(base, self.cameras[run.name], verts, sup, mag, vmax, scale)
                panels.append(video.annotate(img, [f"run {run.name}", f"t = {1e3 * run.sim_time[kk]:.2f} ms",
                                                   "colour: displacement magnitude"], vmax))
            images.append(video.side_by_side(panels))
            times.append(float(t_ref[k]))
        return images, times

    def video(self) -> None:
        d = self.out / "video"
        d.mkdir(parents=True, exist_ok=True)
        images, times = self.overlay_frames()
        self.files.append(video.write_mp4(d / "overlay.mp4", images, self.fps))
        if self.times_ms:
            chosen = sorted({int(np.argmin(np.abs(1e3 * np.asarray(times) - t))) for t in self.times_ms})
        else:
            chosen = sorted(set(np.linspace(0, len(images) - 1, min(4, len(images))).round().astype(int)))
        for k in chosen:
            self.files.append(video.write_png(d / f"overlay_t{1e3 * times[k]:07.3f}ms.png", images[k]))

    # -- figures ----------------------------------------------------------
    def figures(self) -> None:
        d = self.out / "figures"
        d.mkdir(parents=True, exist_ok=True)
        self.files += figures.convergence({r.name: r.history for r in self.runs}, d / "fig7_convergence")
        self.files += self._fig8(d)
        if self.r.has_stage("flow"):
            t = np.asarray(self.r.read("flow", "frame_time"), float)
            windows = {r.name: (float(r.sim_time[0]), float(r.sim_time[-1])) for r in self.runs}
            self.files += figures.glottal_area(t, self.r.read("flow", "glottal_area"), windows, d / "glottal_area")
            self.files += self._kymogram(d)
        else:
            self.notes.append("no /flow: glottal area and kymogram skipped")
        if self.r.has_stage("sync") and self.r.has_stage("ldv"):
            self.files += figures.sync_quality_map(self.r.read("ldv", "grid_index"), self.r.read("sync", "quality"),
                                                   self.r.read("sync", "ok"), self.r.read("ldv", "dropout"),
                                                   d / "sync_quality")
        else:
            self.notes.append("no /sync: sync quality map skipped")
        for run in self.runs:
            if run.displacement_std is None:
                self.notes.append(f"run {run.name} states no uncertainty: its map is skipped")
                continue
            self.files += figures.uncertainty_on_folds(self.mesh, run.displacement_std, run.name,
                                                       d / f"uncertainty_{run.name}")

    def _fig8(self, d: Path, formats: tuple[str, ...] = FIGURE_FORMATS) -> list[Path]:
        if not self.r.has_stage("fields"):
            self.notes.append("no /fields: figure 8 skipped")
            return []
        cam0 = self.cameras[self.runs[0].name]
        if self.points_px:
            pts = np.asarray(self.points_px, float)
            labels = [f"screen point (px {p[0]:.0f}, {p[1]:.0f})" for p in pts]
        else:
            pts, labels = sampling.screen_points(cam0, self.mesh)
        ft = np.asarray(self.r.read("fields", "frame_time"), float)
        lo = min(float(r.sim_time[0]) for r in self.runs)
        hi = max(float(r.sim_time[-1]) for r in self.runs)
        sel = np.flatnonzero((ft >= lo - 1e-9) & (ft <= hi + 1e-9))
        vel = self.r.frames("fields", "velocity")[sel].astype(float)          # (F, H, W, 3), model axes of /flow
        valid = self.r.frames("fields", "valid")[sel]
        px = np.round(pts).astype(int)
        meas = vel[:, px[:, 1], px[:, 0]]                                       # (F, P, 3)
        meas[~valid[:, px[:, 1], px[:, 0]]] = np.nan
        # /fields' (u, v) are already model axes for /flow's rotation: turn only by what the run's pose adds
        flow_rotation = float(self.r.attrs("flow").get("rotation_deg", 0.0))
        meas[..., :2] = model_axes_velocity(meas[..., :2], flow_rotation, cam0.rotation_deg)
        sim = {r.name: (r.sim_time, sampling.surface_velocity_at(self.cameras[r.name], self.mesh, r.displacements,
                                                               r.sim_time, pts)) for r in self.runs}
        return figures.velocities(ft[sel], meas, sim, labels, d / "fig8_velocities", formats)

    def _kymogram(self, d: Path, formats: tuple[str, ...] = FIGURE_FORMATS) -> list[Path]:
        masks = self.r.frames("flow", "gap_mask")
        counts = np.zeros(masks[0].shape)
        for i in range(0, len(masks), 128):
            counts += masks[i:i + 128].sum(axis=0)
        px_per_mm = float(self.r.attrs("flow")["px_per_mm"])
        left = None
        if self.runs:
            left = self.cameras[self.runs[0].name].project(self.mesh.nodes[self.mesh.fold_nodes(0)].mean(axis=0))
        else:
            self.notes.append("no run (no camera pose): the kymogram's left/right are not checked against the model")
        lines, names = sampling.glottis_lines(counts, px_per_mm, left)
        if lines is None:
            self.notes.append("no glottal gap detected: kymogram skipped")
            return []
        out = np.zeros((len(lines), len(self.frames), lines.shape[1]))
        for i in range(0, len(self.frames), 128):
            out[:, i:i + 128] = sampling.sample_lines(self.frames[i:i + 128], lines)
        return figures.kymogram(self.frame_time, out, names, 4.0, d / "kymogram", formats)

    # -- tables -----------------------------------------------------------
    def tables(self) -> None:
        d = self.out / "tables"
        d.mkdir(parents=True, exist_ok=True)
        self.files.append(self._runs_table(d / "runs.csv"))
        if self.r.has_stage("sync") and self.r.has_stage("fields"):
            self.files.append(self._ldv_table(d / "ldv_velocities.csv"))
        else:
            self.notes.append("no /sync or /fields: vibrometer table skipped")

    def _runs_table(self, path: Path) -> Path:
        rows = []
        for r in self.runs:
            h, a = r.history, r.attrs
            rows.append({"run": r.name, "setup": a.get("setup", ""), "loads": a.get("loads", ""),
                         "method": a.get("method", ""),
                         "iterations": int(h["iteration"][-1]) if len(h.get("iteration", [])) else 0,
                         "E_start": f"{float(h['total'][0]):.6g}", "E_final": f"{float(h['total'][-1]):.6g}",
                         "wall_time_s": "" if r.wall_time_s is None else f"{r.wall_time_s:.3f}",
                         "fit_time_s": f"{float(h['wall_time'][-1]):.3f}" if "wall_time" in h else "",
                         "converged": bool(a.get("converged", False)), "n_frames": len(r.sim_time) - 1,
                         "t_start_s": f"{r.sim_time[0]:.6f}", "t_end_s": f"{r.sim_time[-1]:.6f}",
                         "inferior_uncertainty_rel": a.get("inferior_uncertainty_rel", ""),
                         "superior_uncertainty_rel": a.get("superior_uncertainty_rel", "")})
        return tables.write_runs(path, rows)

    def _ldv_table(self, path: Path) -> Path:
        """Long table: one row per vibrometer point and video frame inside any run's window."""
        ldv_px = np.asarray(self.r.read("fields", "ldv_px"), float)         # (P, 2) col, row
        grid = np.asarray(self.r.read("ldv", "grid_index"), int)
        ok = np.asarray(self.r.read("sync", "ok"), bool)
        w_meas = self.r.dataset("sync", "aligned_w")
        ft = np.asarray(self.r.read("sync", "frame_time"), float)
        lo = min(float(r.sim_time[0]) for r in self.runs)
        hi = max(float(r.sim_time[-1]) for r in self.runs)
        sel = np.flatnonzero((ft >= lo - 1e-9) & (ft <= hi + 1e-9))
        meas = np.asarray(w_meas[:, sel[0]:sel[-1] + 1], float) if sel.size else np.zeros((len(ldv_px), 0))
        sims = {}
        for r in self.runs:
            v = sampling.surface_velocity_at(self.cameras[r.name], self.mesh, r.displacements, r.sim_time,
                                             ldv_px)[..., 2]                     # (T, P) mm/s
            on = np.full((len(sel), len(ldv_px)), np.nan)
            for j, t in enumerate(ft[sel]):
                k = np.flatnonzero(np.abs(r.sim_time - t) < 1e-7)
                if k.size:
                    on[j] = v[k[0]]
            sims[r.name] = on
        return tables.write_ldv(path, ldv_px, grid, ok, ft[sel], meas, sims,
                                dropout=np.asarray(self.r.read("ldv", "dropout"), bool),
                                used=np.asarray(self.r.read("fields", "ldv_used"), bool))
