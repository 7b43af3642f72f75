"""`vfcli export` and `vfcli report`: the derived outputs of a store (read only, never written).

``export_store``: ParaView time series, the model over the video, the paper's figures and CSV
tables in a folder, with ``export.json`` listing what was written from which store groups
(their digests); rerun on an unchanged store with the same options it says so and does nothing.

``write_report`` / ``write_index``: one self-contained HTML page per recording (every picture
and the overlay video inline as ``data:`` URIs, no script, no network), and an overview page of
many. The pictures come from the same code as the export (rendered into a temporary folder,
then inlined).

The drawing is core code (vfcli/export: figures, video, paraview, loads; vfcli/report/html.py);
this module reads the store and hands it numpy arrays.
"""
from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vfcli import __version__
from vfcli.camera.camera import Camera
from vfcli.camera.pose import model_axes_velocity
from vfcli.errors import ConfigError, MissingStageError, VfcliError
from vfcli.export import figures, paraview, sampling, tables, video
from vfcli.report.html import esc, figure, fmt, kv_table, page, pretty_json, table, video_tag
from vfcli.store import layout
from vfcli.store.runs import OptimizeRun, read_mesh, read_run, run_names, stage_digests, stage_runs
from vfcli.store.vtkhdf import write_transient_tets
from vfcli.store.transaction import Store, StoreReader

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


class _Export:
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
            write_transient_tets(d / f"{run.name}.vtkhdf", pts, self.mesh.tets, run.sim_time, fields)
            self.files.append(d / f"{run.name}.vtkhdf")
            self.files += paraview.write_pvd(d / f"{run.name}.pvd", self.mesh, run.sim_time, run.displacements, fields)

    def _load(self, run: OptimizeRun) -> np.ndarray | None:
        """(T, N, 3) Pa applied surface traction of a run, or None (with a note) when it cannot be rebuilt."""
        from vfcli.export.loads import applied_traction

        pressure = None
        if self.r.has_stage("hsc") and "pressure" in self.r.group("hsc"):
            pressure = (self.r.read("hsc", "pressure_time"), self.r.read("hsc", "pressure"))
        try:
            return applied_traction(self.mesh, run.config.get("optimize", {}), run.config.get("mesh", {}),
                                    run.controls, run.sim_time, pressure)
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

    def _fig8(self, d: Path) -> list[Path]:
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
        vel = self.r.frames("fields", "velocity")[sel].astype(float)          # (F, H, W, 3) camera frame
        valid = self.r.frames("fields", "valid")[sel]
        px = np.round(pts).astype(int)
        meas = vel[:, px[:, 1], px[:, 0]]                                       # (F, P, 3)
        meas[~valid[:, px[:, 1], px[:, 0]]] = np.nan
        # /fields' (u, v) are already model axes for /flow's rotation: turn only by what the run's pose adds
        flow_rotation = float(self.r.attrs("flow").get("rotation_deg", 0.0))
        meas[..., :2] = model_axes_velocity(meas[..., :2], flow_rotation, cam0.rotation_deg)
        sim = {r.name: (r.sim_time, sampling.surface_velocity_at(self.cameras[r.name], self.mesh, r.displacements,
                                                               r.sim_time, pts)) for r in self.runs}
        return figures.velocities(ft[sel], meas, sim, labels, d / "fig8_velocities")

    def _kymogram(self, d: Path) -> list[Path]:
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
        return figures.kymogram(self.frame_time, out, names, 4.0, d / "kymogram")

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
                         "wall_time_s": f"{float(h['wall_time'][-1]):.3f}" if "wall_time" in h else "",
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
        return tables.write_ldv(path, ldv_px, grid, ok, ft[sel], meas, sims)


def export_store(path: str | Path, out_dir: str | Path, runs: list[str] | None = None,
                 what: tuple[str, ...] = WHAT, times_ms: list[float] | None = None, fps: float = 10.0,
                 force: bool = False, points_px: list[tuple[float, float]] | None = None) -> ExportResult:
    """Export a store's runs into ``out_dir`` (see the module docstring). The store is opened read-only."""
    out = Path(out_dir)
    store = Store(path)
    with store.read() as reader:
        names = run_names(reader)
        if not names:
            raise MissingStageError("no optimisation run in the store; run `vfcli optimize` first", path)
        wanted = list(dict.fromkeys(runs)) if runs else names
        missing = [n for n in wanted if n not in names]
        if missing:
            raise MissingStageError(f"run {missing[0]!r} is not in the store (runs: {', '.join(names)})", path)
        key = {"vfcli_version": __version__, "store": str(Path(path).resolve()), "digests": stage_digests(reader),
               "runs": wanted, "what": sorted(what), "times_ms": times_ms, "fps": fps,
               "points_px": [list(map(float, p)) for p in points_px] if points_px else None}
        manifest = out / MANIFEST
        if not force and manifest.exists():
            try:
                old = json.loads(manifest.read_text())
            except (OSError, ValueError):
                old = {}
            if old.get("key") == key and all((out / f).exists() for f in old.get("files", [])):
                log.info("%s is up to date (store and options unchanged); --force rewrites it", out)
                return ExportResult(str(out), "up-to-date", {"files": len(old["files"])})
        job = _Export(reader, [read_run(reader, n) for n in wanted], out, times_ms, fps, points_px)
        out.mkdir(parents=True, exist_ok=True)
        for item in WHAT:
            if item in what:
                getattr(job, item)()
    rel = [str(f.relative_to(out)) for f in job.files]
    manifest.write_text(json.dumps({"key": key, "files": rel, "notes": job.notes}, indent=2))
    for note in job.notes:
        log.warning(note)
    summary = {"runs": ",".join(wanted), "files": len(rel), **({"skipped": "; ".join(job.notes)} if job.notes else {})}
    return ExportResult(str(out), "written", summary, job.files)


# -- the report ------------------------------------------------------------

_HIDDEN = set(layout.PROVENANCE_ATTRS) | {"complete", "template_real", "template_imag"}


def _stage_attrs(reader: StoreReader, path: str) -> tuple[dict[str, Any], list[str], dict[str, Any]]:
    """(plain attributes, warnings/notes, stored summary) of a stage group."""
    parts = path.strip("/").split("/")
    attrs = reader.attrs(parts[0], parts[1] if len(parts) > 1 else None)
    notes: list[str] = []
    summary: dict[str, Any] = {}
    for key in ("notes", "warnings", "warnings_json"):
        if key in attrs:
            try:
                v = json.loads(str(attrs[key]))
                notes += [str(x) for x in (v if isinstance(v, list) else [v])]
            except ValueError:
                notes.append(str(attrs[key]))
    if "summary_json" in attrs:
        try:
            summary = json.loads(str(attrs["summary_json"]))
        except ValueError:
            pass
        if isinstance(summary, dict):
            notes += [str(w) for w in summary.pop("warnings", []) or []]
    plain = {k: v for k, v in attrs.items()
             if k not in _HIDDEN and k not in ("notes", "warnings", "warnings_json", "summary_json")}
    return plain, notes, summary


def _gap_frames(job: _Export, d: Path) -> list[Path]:
    """Four frames over one cycle with the detected glottal gap outlined (PNG)."""
    import cv2

    masks = job.r.frames("flow", "gap_mask")
    n = len(masks)
    period = 20
    if job.r.has_stage("sync"):
        f0 = float(job.r.attrs("sync").get("f0_video_hz", 0) or 0)
        fps = float(job.r.attrs("hsc").get("fps_hz", 0) or 0)
        if f0 > 0 and fps > 0:
            period = max(4, int(round(fps / f0)))
    idx = np.unique(np.clip(np.round(np.linspace(0, period, 4, endpoint=False)).astype(int), 0, n - 1))
    frames = job.frames[idx].astype(float)
    lo, hi = np.percentile(frames, [0.5, 99.5])
    out = []
    scale = 2
    for i, k in enumerate(idx):
        img = video.gray_to_rgb(frames[i], lo, hi, scale)
        m = cv2.resize(masks[int(k)].astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, contours, -1, (255, 40, 40), 1, cv2.LINE_AA)
        img = video.annotate(img, [f"frame {int(k)}", f"t = {1e3 * job.frame_time[int(k)]:.2f} ms",
                                   f"gap {int(masks[int(k)].sum())} px"], 0.0, "")[:, :-30]
        out.append(video.write_jpeg(d / f"gap_{int(k):05d}.jpg", img))
    return out


def _runs_section(job: _Export, d: Path) -> str:
    if not job.runs:
        return '<h2>Optimisation runs</h2><p class="muted">No optimisation run yet (`vfcli optimize`).</p>'
    rows = []
    for r in job.runs:
        h, a = r.history, r.attrs
        rows.append([r.name, a.get("setup", ""), a.get("loads", ""), a.get("method", ""),
                     int(h["iteration"][-1]) if len(h.get("iteration", [])) else 0,
                     f"{float(h['total'][0]):.4g}", f"{float(h['total'][-1]):.4g}",
                     f"{float(h['wall_time'][-1]):.1f}" if "wall_time" in h else "", a.get("converged", ""),
                     f"{1e3 * r.sim_time[0]:.2f}-{1e3 * r.sim_time[-1]:.2f}",
                     fmt(a.get("inferior_uncertainty_rel", "not stated")), fmt(a.get("superior_uncertainty_rel", "not stated"))])
    parts = ["<h2>Optimisation runs</h2>",
             table(rows, ["run", "setup", "loads", "method", "iterations", "E start", "E final", "time (s)",
                          "converged", "window (ms)", "inferior uncertainty (rel.)", "superior uncertainty (rel.)"]),
             '<p class="muted">Uncertainty: RMS stated standard deviation / RMS reconstructed displacement of the surface.</p>']
    fig_dir = d / "figures"
    fig_dir.mkdir(exist_ok=True)
    try:
        job.video()
        mp4 = d / "video" / "overlay.mp4"
        parts.append("<h3>The model over the video</h3>" + video_tag(
            mp4, "Projected superior surface of each run (colour: |displacement|, mm) over the high-speed frames, "
                 "camera pose of the fit; one panel per run."))
    except ConfigError as exc:
        parts.append(f'<p class="warn">Overlay video not made: {esc(exc)}</p>')
    parts.append(figure(figures.convergence({r.name: r.history for r in job.runs}, fig_dir / "fig7")[0],
                        "Convergence of E per run (paper, fig. 7)", 700))
    fig8 = job._fig8(fig_dir)
    if fig8:
        parts.append(figure(fig8[0], "Surface velocity at a point of each fold: measurement and runs (paper, fig. 8)"))
    for r in job.runs:
        if r.displacement_std is not None:
            f = figures.uncertainty_on_folds(job.mesh, r.displacement_std, r.name, fig_dir / f"unc_{r.name}")[0]
            parts.append(figure(f, f"Stated uncertainty of run {r.name} on the fold geometry (mm)"))
        else:
            parts.append(f'<p class="muted">Run {esc(r.name)} states no uncertainty (optimize.uncertainty = false).</p>')
    return "\n".join(parts)


def build_report(reader: StoreReader, work: Path) -> str:
    """The report page (HTML text) of an open store; pictures are rendered into ``work``."""
    names = run_names(reader)
    runs = [read_run(reader, n) for n in names]
    title = reader.path.name
    parts = [f"<h1>Recording {esc(title)}</h1>",
             f'<p class="muted">{esc(reader.path.resolve())} &middot; report by vfcli {esc(__version__)}, '
             f'{_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}</p>']
    # -- metadata and calibration
    parts.append("<h2>Recording and calibration</h2>")
    meta: dict[str, Any] = {"store format": f"{reader.root_attrs().get('format')} v{reader.root_attrs().get('format_version')}"}
    for name, keys in (("hsc", ("source", "fps_hz", "n_frames", "bit_depth", "px_per_mm", "rotation_deg", "offset_px", "roi_px",
                                "pressure_fs_hz")),
                       ("ldv", ("source", "grid_shape", "fs_hz"))):
        if reader.has_stage(name):
            a = reader.attrs(name)
            meta.update({f"{name}: {k}": a[k] for k in keys if k in a})
    parts.append(kv_table(meta))
    parts.append("<details><summary>Recording configuration (as stored)</summary>"
                 + pretty_json(reader.recording_config_json()) + "</details>")
    # -- stages
    parts.append("<h2>Stages</h2>")
    rows = []
    details = []
    for path in reader.stage_paths():
        st = reader.status(path)
        plain, notes, summary = _stage_attrs(reader, path) if st.complete else ({}, [], {})
        rows.append([path, "yes" if st.complete else "NO (interrupted)", st.provenance.get("created_utc", ""),
                     st.provenance.get("command", ""), "; ".join(st.stale_because) or "current",
                     f"{st.size_bytes / 1e6:.2f} MB", len(notes)])
        body = kv_table({**summary, **plain}) if (summary or plain) else ""
        warn = "".join(f'<li class="warn">{esc(n)}</li>' for n in notes)
        details.append(f"<details><summary>{esc(path)}{' &middot; ' + str(len(notes)) + ' warning(s)' if notes else ''}"
                       f"</summary>{body}{'<ul>' + warn + '</ul>' if warn else ''}</details>")
    missing = [n for n in layout.STAGES if not any(p.split("/")[1] == n for p in reader.stage_paths())]
    parts.append(table(rows, ["group", "complete", "written (UTC)", "command", "upstream", "size", "warnings"]))
    parts += details
    if missing:
        parts.append(f'<p class="muted">Not in this store: {esc(", ".join("/" + m for m in missing))}.</p>')
    job = _Export(reader, runs, work, None, 10.0)
    d = work / "figures"
    d.mkdir(parents=True, exist_ok=True)
    # -- sync
    parts.append("<h2>Synchronisation of the vibrometer</h2>")
    if reader.has_stage("sync") and reader.has_stage("ldv"):
        ok = np.asarray(reader.read("sync", "ok"), bool)
        q = np.asarray(reader.read("sync", "quality"), float)
        parts.append(f"<p>{int(ok.sum())} of {len(ok)} points aligned; median quality {np.median(q):.3f}; "
                     f"video f0 {fmt(reader.attrs('sync').get('f0_video_hz', ''))} Hz.</p>")
        parts.append(figure(figures.sync_quality_map(reader.read("ldv", "grid_index"), q, ok, reader.read("ldv", "dropout"),
                                                     d / "sync")[0], "Alignment quality of every scan point", 650))
    else:
        parts.append('<p class="muted">No /sync yet (`vfcli sync`).</p>')
    # -- flow and gap
    parts.append("<h2>Glottal gap and flow</h2>")
    if reader.has_stage("flow"):
        t = np.asarray(reader.read("flow", "frame_time"), float)
        area = np.asarray(reader.read("flow", "glottal_area"), float)
        windows = {r.name: (float(r.sim_time[0]), float(r.sim_time[-1])) for r in runs}
        parts.append(f"<p>Glottal area {area.min():.3f}-{area.max():.3f} mm²; gap open in {int((area > 0).sum())} "
                     f"of {len(area)} frames.</p>")
        parts.append(figure(figures.glottal_area(t, area, windows, d / "area")[0], "Glottal area waveform", 800))
        parts.append('<div class="grid">' + "".join(figure(p, p.stem.replace("_", " ") + ": detected gap in red", 400)
                                                    for p in _gap_frames(job, d)) + "</div>")
        ky = job._kymogram(d)
        if ky:
            parts.append(figure(ky[0], "Kymogram across the glottis at three positions along it", 800))
    else:
        parts.append('<p class="muted">No /flow yet (`vfcli flow`).</p>')
    # -- mesh
    parts.append("<h2>Model mesh</h2>")
    if job.mesh is not None:
        from vfcli.model.preview import render_mesh_png

        m = job.mesh
        parts.append(f"<p>{m.n_nodes} nodes, {len(m.tets)} tetrahedra, volume left {m.fold_volume(0):.1f} mm³, "
                     f"right {m.fold_volume(1):.1f} mm³.</p>")
        try:
            import cv2

            render_mesh_png(m, d / "mesh.png")
            video.write_jpeg(d / "mesh.jpg", cv2.imread(str(d / "mesh.png"))[..., ::-1], 88)
            parts.append(figure(d / "mesh.jpg", "The M5 model of both folds, boundary tags in colour", 800))
        except (OSError, RuntimeError) as exc:
            parts.append(f'<p class="warn">Mesh picture not rendered: {esc(exc)}</p>')
    else:
        parts.append('<p class="muted">No /mesh yet (`vfcli mesh`).</p>')
    # -- runs
    parts.append(_runs_section(job, work))
    # -- diagnosis
    parts.append("<h2>Diagnosis</h2>")
    diag = [layout.stage("diagnose").group_path(n) for n in stage_runs(reader, "diagnose")]
    if diag:
        for p in diag:
            plain, notes, summary = _stage_attrs(reader, p)
            parts.append(f"<h3>{esc(p)}</h3>" + kv_table({**summary, **plain}))
    else:
        parts.append('<p class="muted">No diagnosis in this store (`vfcli diagnose` has not run on it).</p>')
    for note in job.notes:
        log.info("report: %s", note)
    return page(f"vfcli report: {title}", "\n".join(parts))


def write_report(path: str | Path, out: str | Path | None = None) -> ExportResult:
    """Write the report of the store ``path`` to ``out`` (default: ``<store stem>.html`` beside it)."""
    store = Store(path)
    out = Path(out) if out else store.path.with_suffix(".html")
    with tempfile.TemporaryDirectory(prefix="vfcli-report-") as tmp, store.read() as reader:
        text = build_report(reader, Path(tmp))
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(out.name + f".tmp-{os.getpid()}")
    part.write_text(text, encoding="utf-8")
    part.replace(out)
    return ExportResult(str(out), "written", {"size_kb": round(out.stat().st_size / 1024)}, [out])


def _report_of(store_path: Path) -> Path | None:
    for cand in (store_path.with_suffix(".html"), store_path.parent / "report.html"):
        if cand.exists():
            return cand
    return None


def write_index(folder: str | Path, out: str | Path | None = None) -> ExportResult:
    """An overview page of every vfcli store under ``folder``: one line each, linked to its report."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError("--index: not a folder", folder)
    out = Path(out) if out else folder / "index.html"
    rows = []
    for p in sorted(folder.rglob("*.h5")):
        try:
            with Store(p).read() as r:
                paths = r.stage_paths()
                best = []
                for n in run_names(r):
                    e = r.read("optimize", "history_total", n)
                    best.append(f"{n}: E {float(e[-1]):.3g}")
                created = r.root_attrs().get("created_utc", "")
        except VfcliError:
            continue
        rep = _report_of(p)
        link = (f'<a href="{esc(os.path.relpath(rep, out.parent))}">{esc(p.relative_to(folder))}</a>' if rep
                else f"{esc(p.relative_to(folder))} <span class=\"muted\">(no report: vfcli report {esc(p.name)})</span>")
        rows.append([link, esc(created), esc(", ".join(s.strip("/") for s in paths)), esc("; ".join(best) or "no run")])
    body = (f"<h1>Recordings under {esc(folder.resolve())}</h1><p class=\"muted\">{len(rows)} store(s); "
            f"index by vfcli {esc(__version__)}</p>"
            + table(rows, ["recording", "created (UTC)", "stages", "runs"], raw=True))
    out.write_text(page(f"vfcli recordings: {folder.name}", body), encoding="utf-8")
    return ExportResult(str(out), "written", {"recordings": len(rows)}, [out])
