"""`vfcli export`: the derived outputs of a store in a folder (read only, never written).

ParaView time series, the model over the video, the paper's figures and CSV tables, with
``export.json`` listing what was written from which store groups (their digests); rerun on an
unchanged store with the same options it says so and does nothing. The work is
:class:`vfcli.stages.export_job.ExportJob`.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from vfcli import __version__
from vfcli.errors import ConfigError, MissingStageError
from vfcli.store.runs import read_run, run_names, stage_digests
from vfcli.store.transaction import Store

from vfcli.stages.export_job import MANIFEST, WHAT, ExportJob, ExportResult

log = logging.getLogger(__name__)


def check_times_ms(times_ms: list[float] | None, sim_time_s: np.ndarray, run: str) -> None:
    """Refuse an overlay time (``--time-ms``, ms) that is not a number or lies outside the window of the run the
    overlay follows (its ``sim_time_s``, s; half a frame of slack at each end): it was moved to the nearest end
    without a word, and a NaN was written into export.json.

    Raises
    ------
    ConfigError
        One line naming the time and the run's window.
    """
    t = 1e3 * np.asarray(sim_time_s, dtype=float)
    half = 0.5 * float(np.median(np.diff(t))) if t.size > 1 else 0.0
    lo, hi = float(t[0]) - half, float(t[-1]) + half
    for value in times_ms or []:
        if not (np.isfinite(value) and lo <= value <= hi):
            raise ConfigError(f"--time-ms {value:g}: outside run {run}'s window, {t[0]:g}-{t[-1]:g} ms")


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
        loaded = [read_run(reader, n) for n in wanted]
        check_times_ms(times_ms, loaded[0].sim_time, loaded[0].name)
        job = ExportJob(reader, loaded, out, times_ms, fps, points_px)
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
