"""One batch task: a whole recording, run where a worker is (a process of a Dask cluster, or
this one).

:func:`run_entry` takes and returns plain JSON-able dicts (small to ship), never raises
for what a recording can cause: a user error (:class:`vfcli.errors.VfcliError`: bad data,
a locked store, a bad config value) and a bug alike end as a ``failed`` outcome with the
error's line, so the engine does not retry them (they would fail the same way). Only the
death of the worker process itself (killed, out of memory) reaches the engine, which
resubmits the recording; the store is untouched by a killed writer
(:mod:`vfcli.store.transaction`).
"""
from __future__ import annotations

import os
import resource
import time
import traceback
from pathlib import Path
from typing import Any, Mapping

from vfcli.batch.manifest import RecordingEntry
from vfcli.errors import EXIT_INTERNAL, VfcliError


def outcome_status(summary: Mapping[str, Any]) -> str:
    """'done' when a stage ran, 'up to date' when every stage was current, 'failed' when not ok."""
    if not summary.get("ok", False):
        return "failed"
    actions = {s.get("action") for s in summary.get("stages", [])}
    return "done" if "ran" in actions else "up to date"


def run_entry(entry_json: Mapping[str, Any], inner_map: bool = False) -> dict[str, Any]:
    """Run one recording (:func:`vfcli.stages.run.run_recording`) and say how it ended.

    Parameters
    ----------
    entry_json : :meth:`RecordingEntry.to_json` of the recording.
    inner_map : spread the recording's own independent pieces (optimize's basis solves) over
        the cluster this task runs on (:func:`vfcli.batch.cluster.worker_map`); only inside a
        Dask task. The store ends the same either way.

    Returns
    -------
    dict
        ``name``, ``status`` ("done" | "up to date" | "failed"), ``error`` (one line, or
        None), ``exit_code`` (the code `vfcli run` would exit with), ``seconds`` (wall time),
        ``pid`` (the process that ran it), ``max_rss_mb`` (the peak resident memory of that
        process so far, MB: an upper bound for this recording's), ``inner_map`` (whether the
        cluster ran its pieces), ``summary`` (:meth:`RunSummary.to_json`, None on
        error) and ``traceback`` (only for a bug).
    """
    from vfcli.allocator import keep_freed_blocks
    from vfcli.stages.run import keep_overrides, run_recording

    keep_freed_blocks()             # the worker's allocator as the CLI sets it (vfcli.allocator); idempotent
    entry = RecordingEntry.from_json(entry_json)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"name": entry.name, "store": str(entry.store), "pid": os.getpid(), "inner_map": inner_map,
                           "error": None, "exit_code": 0, "summary": None, "traceback": None}
    try:
        mapper = None
        if inner_map:
            from vfcli.batch.cluster import worker_map

            mapper = worker_map()
        summary = run_recording(Path(entry.store), Path(entry.raw), until=entry.until,
                                overrides=dict(entry.overrides), config_path=entry.config,
                                command=f"vfcli batch ({entry.name})", map=mapper).to_json()
        out["summary"] = summary
        out["status"] = outcome_status(summary)
        if out["status"] == "failed":
            out["error"], out["exit_code"] = "the run did not complete", EXIT_INTERNAL
        else:   # the manifest's `set` is the recording's config from now on (info and a later run see it)
            keep_overrides(Path(entry.store), dict(entry.overrides), f"vfcli batch ({entry.name})")
    except VfcliError as exc:
        partial = getattr(exc, "partial", None)   # the steps that ran before the one that failed
        out.update(status="failed", error=str(exc), exit_code=exc.exit_code,
                   summary=partial.to_json() if partial is not None else None)
    except Exception as exc:  # a bug in one recording must not stop the others
        out.update(status="failed", error=f"internal error: {type(exc).__name__}: {exc}", exit_code=EXIT_INTERNAL,
                   traceback=traceback.format_exc())
    out["seconds"] = round(time.perf_counter() - t0, 3)
    out["max_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)  # Linux: KiB
    return out
