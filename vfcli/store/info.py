"""What a store holds: the library behind `vfcli info`."""
from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any, Callable

from vfcli.store import layout, parts
from vfcli.store.checkpoint import resume_flags, stopped_fits
from vfcli.store.transaction import Store

_LOG_PREFIX = re.compile(r"^(?:WARNING|ERROR|INFO|DEBUG) [\w.]+: ")


def plain_warnings(messages: list[str]) -> list[str]:
    """A stage's stored warnings as a reader wants them: without the logger's "WARNING vfcli.module: " prefix
    (kept in the store, for whoever debugs), and once (a stage may store a warning both as its note and as its
    command's logged line, which names the file first)."""
    texts = [_LOG_PREFIX.sub("", str(m)).strip() for m in messages]
    out: list[str] = []
    for i, t in enumerate(texts):
        if t and t not in out and not any(j != i and len(u) > len(t) and u.endswith(t) for j, u in enumerate(texts)):
            out.append(t)
    return out


#: ``(stage name, run) -> settings JSON`` the stage would record now (None: not compared).
ExpectedConfig = Callable[[str, "str | None"], "str | None"]


def store_info(path: str | Path, expected_config: Callable[[str | None], ExpectedConfig] | None = None,
               verify: bool = False, defaults: ExpectedConfig | None = None) -> dict[str, Any]:
    """Stages with provenance, sizes, staleness (transitive; config changes count when
    ``expected_config(recording config JSON)`` is given, settings added since a stage was written as their
    ``defaults(name, run)``: :func:`vfcli.store.reader.settings_change`), damage (``verify``: every dataset's
    SHA-256 too, reading the whole store), figures and warnings; whether a writer is at work
    now, or the leftovers of interrupted writes; the parts folder the store file links to (the
    stages' files) and the size of the files it links to."""
    store = Store(path)
    with store.read() as r:
        for p in r.stage_paths() if verify else []:
            r.problems(p, contents=True)
        root = r.root_attrs()
        config_json = r.recording_config_json()
        # a store without a recording config was not written by the stages: nothing to compare
        expected = expected_config(config_json) if expected_config and config_json is not None else None
        stages = [st.to_json() for st in r.statuses(expected, defaults)]
        present = {p.split("/")[1] for p in r.stage_paths()}
    writing = store.writer_active()
    linked = [p for p in parts.linked_files(store.real_path) if p.is_file()]
    folders = sorted({p.parent for p in linked})  # a hand copy not yet written to: the original's folder
    leftovers = [str(p) for p in store.interrupted_writes()]
    stopped = [] if writing else stopped_fits(store.path)    # a writer at work keeps its checkpoint current
    for fit in stopped:
        # the --set options that resume it: its settings against the run's under the recording config
        # (the default run's settings are those every run starts from)
        now = expected("optimize", "default") if expected is not None else None
        fit["resume_flags"] = resume_flags(fit["settings"], now) if fit["settings"] is not None else []
    return {
        "path": str(store.path),
        "size_bytes": os.path.getsize(store.path),
        "parts_folder": str(folders[0]) if folders else None,
        "parts_bytes": sum(p.stat().st_size for p in linked),
        "format": str(root.get("format")),
        "format_version": int(root.get("format_version")),
        "created_utc": str(root.get("created_utc", "")),
        "stages": stages,
        "missing_stages": [n for n in layout.STAGES if n not in present],
        "writer_active": writing,
        "write_in_progress": leftovers if writing else [],
        "interrupted_writes": [] if writing else leftovers,
        "stopped_fits": stopped,
        "recording_config": None if config_json is None else json.loads(config_json),
    }
