"""`vfcli report`: one self-contained HTML page per recording, and an index of many.

Every picture and the overlay video are inline as ``data:`` URIs (no script, no network). The
pictures come from the export's code (:class:`vfcli.stages.export_job.ExportJob`, rendered into a
temporary folder, then inlined).
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from vfcli import __version__
from vfcli.errors import ConfigError, VfcliError
from vfcli.export import figures, video
from vfcli.report.html import esc, figure, fmt, kv_table, page, pretty_json, table, video_tag
from vfcli.store import layout
from vfcli.store.info import plain_warnings
from vfcli.store.runs import read_run, run_names, stage_runs
from vfcli.store.transaction import Store, StoreReader

from vfcli.stages.base import default_settings, expected_configs
from vfcli.stages.export_job import ExportJob, ExportResult

log = logging.getLogger(__name__)

#: the page embeds each figure's PNG: no SVG is drawn for it
PNG = ("png",)

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
    if layout.SUMMARY_ATTR in attrs:
        try:
            summary = json.loads(str(attrs[layout.SUMMARY_ATTR]))
        except ValueError:
            pass
        if isinstance(summary, dict):
            notes += [str(w) for w in summary.pop("warnings", []) or []]
    plain = {k: v for k, v in attrs.items()
             if k not in _HIDDEN and k not in ("notes", "warnings", "warnings_json", layout.SUMMARY_ATTR)}
    return plain, plain_warnings(notes), summary


def _statuses(reader: StoreReader):
    """(status, plain attributes, warnings, stored summary) of every stage group, staleness as `vfcli info` says it:
    config changes and stale upstream stages count (transitively); an interrupted group has no attributes to show."""
    config_json = reader.recording_config_json()
    for st in reader.statuses(expected_configs(config_json) if config_json is not None else None, default_settings):
        yield (st, *(_stage_attrs(reader, st.path) if st.complete else ({}, [], {})))


def _words(diag_attrs: dict[str, Any]) -> list[str]:
    """The lines a diagnosis printed (its ``words_json``; none when unreadable)."""
    try:
        lines = json.loads(diag_attrs.get("words_json") or "[]")
    except (TypeError, ValueError):
        return []
    return [str(x) for x in lines] if isinstance(lines, list) else []


def _verdict(diag_attrs: dict[str, Any]) -> str:
    """The diagnosis' verdict in words, with the run its refit was stored as: its calibrated decision, or the
    line that says why it could not decide ("" when it stored neither)."""
    verdict = str(diag_attrs.get("decision", "") or "")
    if verdict:   # the printed line, which names the unconfirmed leads too ("... detected (unconfirmed lead: x)")
        verdict = next((x for x in reversed(_words(diag_attrs)) if x.startswith(verdict)), verdict)
    else:
        verdict = next((x[len("decision: "):] for x in _words(diag_attrs) if x.startswith("decision: not ")), "")
    if verdict and diag_attrs.get("refit_run"):
        verdict += f" (refit with {diag_attrs.get('refit_candidate', '?')} stored as run {diag_attrs['refit_run']})"
    return verdict


def phase_times(seconds: dict[str, float]) -> str:
    """A stage's time step by step, in the order run, and in all: "read 6.5 s, profile 108 s; 123 s in all"."""
    parts = [f"{name} {v:.2g} s" if v < 10 else f"{name} {v:.0f} s" for name, v in seconds.items()]
    return f"{', '.join(parts)}; {sum(seconds.values()):.0f} s in all"


def _diagnosis_fields(fields: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the short figures shown in the page, the long ones: JSON texts and nested records) of a diagnosis' attributes
    (its words and verdict are shown above them)."""
    short, long_ = {}, {}
    if "phase_seconds_json" in fields:
        short["time by step"] = phase_times(json.loads(fields["phase_seconds_json"]))
    for k, v in fields.items():
        if k in ("lines", "words_json", "decision"):
            continue
        text = fmt(v)
        (long_ if k.endswith("_json") or isinstance(v, (dict, list)) or len(text) > 120 else short)[k] = v
    return short, long_


#: the pictures a diagnosis writes beside the store or its --map (its stored "images"), in the page's order, and their
#: captions ({run}: the diagnosed run; {refit}: its refit's run, {candidate}: the term the refit added, confirmed or not)
_DIAGNOSIS_IMAGES = {"before": "Residual map of run {run} (where, and when in the cycle, against the noise floor)",
                     "after": "Residual map of run {refit}: run {run} refitted with {candidate}",
                     "points": "Velocity at points: measured, run {run} and run {refit}"}


def _diagnosis_pictures(reader: StoreReader, path: str, images: Any, d: Path) -> str:
    """The diagnosis' pictures in the page: the RMS residual of the run it diagnosed (drawn from the stored
    ``rms_residual``), then each picture it wrote and named in its stored "images" (residual maps before and after
    its refit, the velocity at points), embedded when the file is still where it wrote it, else named as missing."""
    run = path.strip("/").split("/", 1)[1]
    attrs = reader.attrs("diagnose", run)
    words = {"run": run, "refit": attrs.get("refit_run", "?"), "candidate": attrs.get("refit_candidate", "?")}
    out = []
    if "rms_residual" in reader.group("diagnose", run):
        png = figures.residual_rms(reader.read("diagnose", "rms_residual", run), run, d / f"rms_{run.replace('/', '_')}", PNG)[0]
        out.append(figure(png, f"Where run {run} and the recording disagree: RMS residual over its window (mm/s)", 650))
    missing = []
    for key, caption in _DIAGNOSIS_IMAGES.items():
        name = images.get(key) if isinstance(images, dict) else None
        if not name:
            continue
        f = Path(str(name))
        if f.is_file():
            out.append(figure(f, f"{caption.format(**words)} ({f.name})", 900))
        else:
            missing.append(str(f))
    if missing:
        out.append(f'<p class="muted">Pictures the diagnosis wrote and that are no longer there (moved or deleted): '
                   f'{esc(", ".join(missing))}.</p>')
    return "".join(out)


def _at_a_glance(reader: StoreReader, glance: dict[str, list], missing: list[str]) -> str:
    """The section at the top of the page: every stored warning (with its stage), the stages that are stale,
    interrupted or not written yet, and each diagnosis' verdict, so nothing needs unfolding to be seen."""
    out = ["<h2>At a glance</h2>"]
    notes = glance["notes"]
    if notes:
        out.append(f'<p class="warn">{len(notes)} warning(s) stored by the stages:</p><ul>'
                   + "".join(f'<li class="warn"><code>{esc(path)}</code> {esc(n)}</li>' for path, n in notes)
                   + "</ul>")
    else:
        out.append("<p>No stage stored a warning.</p>")
    for path, why in glance["stale"]:
        out.append(f'<p class="warn"><code>{esc(path)}</code> is STALE: {esc(why)} (rerun it, or <code>vfcli run</code>).</p>')
    for path in glance["incomplete"]:
        out.append(f'<p class="warn"><code>{esc(path)}</code> was interrupted: it holds no complete result.</p>')
    if missing:
        out.append(f'<p class="muted">Not written yet: {esc(", ".join("/" + m for m in missing))}.</p>')
    for run in stage_runs(reader, "diagnose"):
        path = layout.stage("diagnose").group_path(run)
        verdict = _verdict(reader.attrs("diagnose", run))
        if verdict:
            out.append(f"<p>Diagnosis <code>{esc(path)}</code>: <strong>{esc(verdict)}</strong>.</p>")
    return "\n".join(out)


def _gap_frames(job: ExportJob, d: Path) -> list[tuple[Path, str]]:
    """Four frames over one cycle with the detected glottal gap outlined (JPEG), each with its caption: the
    frame, its time and the gap's size in the page's own text (burned into a 2x thumbnail shown at a quarter
    of the page's width, the same words were a few pixels high)."""
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
        mask = masks[int(k)]
        m = cv2.resize(mask.astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, contours, -1, (255, 40, 40), 1, cv2.LINE_AA)
        px = int(mask.sum())
        gap = f"the detected gap ({px} px) outlined in red" if px else "no gap detected"
        caption = f"frame {int(k)}, t = {1e3 * job.frame_time[int(k)]:.2f} ms: {gap}"
        out.append((video.write_jpeg(d / f"gap_{int(k):05d}.jpg", img), caption))
    return out


def _runs_section(job: ExportJob, d: Path) -> str:
    if not job.runs:
        return '<h2>Optimisation runs</h2><p class="muted">No optimisation run yet (`vfcli optimize`).</p>'
    rows = []
    for r in job.runs:
        h, a = r.history, r.attrs
        rows.append([r.name, a.get("setup", ""), a.get("loads", ""), a.get("method", ""),
                     int(h["iteration"][-1]) if len(h.get("iteration", [])) else 0,
                     f"{float(h['total'][0]):.4g}", f"{float(h['total'][-1]):.4g}",
                     "" if r.wall_time_s is None else f"{r.wall_time_s:.1f}", a.get("converged", ""),
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
    parts.append(figure(figures.convergence({r.name: r.history for r in job.runs}, fig_dir / "fig7", PNG)[0],
                        "Convergence of E per run (paper, fig. 7)", 700))
    fig8 = job._fig8(fig_dir, PNG)
    if fig8:
        parts.append(figure(fig8[0], "Surface velocity at a point of each fold: measurement and runs (paper, fig. 8)"))
    for r in job.runs:
        if r.displacement_std is not None:
            f = figures.uncertainty_on_folds(job.mesh, r.displacement_std, r.name, fig_dir / f"unc_{r.name}", PNG)[0]
            parts.append(figure(f, f"Stated uncertainty of run {r.name} on the fold geometry (mm)"))
        elif "refit_of" in r.attrs:
            # diagnose's refit states its candidate's parameter with its interval, not each displacement's sd
            parts.append(f'<p class="muted">Run {esc(r.name)} is the diagnosis\' refit of run {esc(r.attrs["refit_of"])} '
                         f'with {esc(r.attrs.get("refit_candidate", ""))}: it states the uncertainty of its parameter, '
                         f'{esc(r.attrs.get("refit_theta_text", ""))}, not of each displacement.</p>')
        else:
            parts.append(f'<p class="muted">Run {esc(r.name)} states no uncertainty (optimize.uncertainty = false).</p>')
    return "\n".join(parts)


def build_report(reader: StoreReader, work: Path) -> str:
    """The report page (HTML text) of an open store; pictures are rendered into ``work``."""
    with contextlib.ExitStack() as stack:     # the mesh picture's process ends with the report, whole or failed
        return _build_report(reader, work, stack)


def _build_report(reader: StoreReader, work: Path, stack: contextlib.ExitStack) -> str:
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
    glance: dict[str, list] = {"notes": [], "stale": [], "incomplete": []}
    for st, plain, notes, summary in _statuses(reader):
        path = st.path
        glance["notes"] += [(path, n) for n in notes]
        if not st.complete:
            glance["incomplete"].append(path)
        elif st.stale_because:
            glance["stale"].append((path, "; ".join(st.stale_because)))
        rows.append([path, "yes" if st.complete else "NO (interrupted)", st.provenance.get("created_utc", ""),
                     st.provenance.get("command", ""), "; ".join(st.stale_because) or "current",
                     f"{st.size_bytes / 1e6:.2f} MB", len(notes)])
        body = kv_table({**summary, **plain}) if (summary or plain) else ""
        warn = "".join(f'<li class="warn">{esc(n)}</li>' for n in notes)
        details.append(f"<details><summary>{esc(path)}{' &middot; ' + str(len(notes)) + ' warning(s)' if notes else ''}"
                       f"</summary>{body}{'<ul>' + warn + '</ul>' if warn else ''}</details>")
    missing = [n for n in layout.STAGES if not any(p.split("/")[1] == n for p in reader.stage_paths())]
    parts.insert(2, _at_a_glance(reader, glance, missing))
    parts.append(table(rows, ["group", "complete", "written (UTC)", "command", "current or stale", "size", "warnings"]))
    parts += details
    job = ExportJob(reader, runs, work, None, 10.0)
    d = work / "figures"
    d.mkdir(parents=True, exist_ok=True)
    picture = None
    if job.mesh is not None:
        from vfcli.model.preview import MeshPicture

        picture = stack.enter_context(MeshPicture(job.mesh, d / "mesh.png"))   # pyvista draws it meanwhile
    # -- sync
    parts.append("<h2>Synchronisation of the vibrometer</h2>")
    if reader.has_stage("sync") and reader.has_stage("ldv"):
        ok = np.asarray(reader.read("sync", "ok"), bool)
        q = np.asarray(reader.read("sync", "quality"), float)
        parts.append(f"<p>{int(ok.sum())} of {len(ok)} points aligned; median quality {np.median(q):.3f}; "
                     f"video f0 {fmt(reader.attrs('sync').get('f0_video_hz', ''))} Hz.</p>")
        parts.append(figure(figures.sync_quality_map(reader.read("ldv", "grid_index"), q, ok, reader.read("ldv", "dropout"),
                                                     d / "sync", PNG)[0], "Alignment quality of every scan point", 650))
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
        parts.append(figure(figures.glottal_area(t, area, windows, d / "area", PNG)[0], "Glottal area waveform", 800))
        parts.append('<div class="grid">' + "".join(figure(p, caption, 400)
                                                    for p, caption in _gap_frames(job, d)) + "</div>")
        ky = job._kymogram(d, PNG)
        if ky:
            parts.append(figure(ky[0], "Kymogram across the glottis at three positions along it", 800))
    else:
        parts.append('<p class="muted">No /flow yet (`vfcli flow`).</p>')
    # -- mesh
    parts.append("<h2>Model mesh</h2>")
    if picture is not None:
        m = job.mesh
        parts.append(f"<p>{m.n_nodes} nodes, {len(m.tets)} tetrahedra, volume left {m.fold_volume(0):.1f} mm³, "
                     f"right {m.fold_volume(1):.1f} mm³.</p>")
        try:
            import cv2

            picture.result()
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
            words = "".join(f"<li>{esc(line)}</li>" for line in _words(plain))
            figures_, stored = _diagnosis_fields({**summary, **plain})
            verdict = _verdict(plain)
            parts.append(f"<h3>{esc(p)}</h3>"
                         + (f"<p><strong>{esc(verdict)}</strong></p>" if verdict else "")
                         + (f"<ul>{words}</ul>" if words else "")
                         + _diagnosis_pictures(reader, p, (summary.get("figures") or {}).get("images"), d)
                         + kv_table(figures_)
                         + "<details><summary>Everything the diagnosis stored (JSON)</summary>"
                         + kv_table(stored) + "</details>")
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
                warned, stale = [], []
                for st, _, notes, _ in _statuses(r):
                    name = st.path.strip("/")
                    if notes:
                        warned.append((name, len(notes)))
                    if not st.complete:
                        stale.append(f"{name} (interrupted)")
                    elif st.stale_because:
                        stale.append(name)
                verdicts = [f"{run}: {_verdict(r.attrs('diagnose', run)) or 'no verdict'}" for run in stage_runs(r, "diagnose")]
        except VfcliError:
            continue
        rep = _report_of(p)
        link = (f'<a href="{esc(os.path.relpath(rep, out.parent))}">{esc(p.relative_to(folder))}</a>' if rep
                else f"{esc(p.relative_to(folder))} <span class=\"muted\">(no report: vfcli report {esc(p.name)})</span>")
        rows.append([link, esc(created), esc(", ".join(s.strip("/") for s in paths)), esc("; ".join(best) or "no run"),
                     esc(f"{sum(n for _, n in warned)}: {', '.join(f'{w} {n}' for w, n in warned)}" if warned else "none"),
                     esc(", ".join(stale) or "none"), esc("; ".join(verdicts) or "not diagnosed")])
    body = (f"<h1>Recordings under {esc(folder.resolve())}</h1><p class=\"muted\">{len(rows)} store(s); "
            f"index by vfcli {esc(__version__)}</p>"
            + table(rows, ["recording", "created (UTC)", "stages", "runs", "warnings (by stage)", "stale", "diagnosis"],
                    raw=True))
    out.write_text(page(f"vfcli recordings: {folder.name}", body), encoding="utf-8")
    return ExportResult(str(out), "written", {"recordings": len(rows)}, [out])
