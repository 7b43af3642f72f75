"""What a store holds: the library behind `vfcli info`."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from vfcli.store import layout
from vfcli.store.transaction import Store


def store_info(path: str | Path, verify: bool = False) -> dict[str, Any]:
    """Stages with provenance, sizes, staleness, damage; leftovers of interrupted writes.
    ``verify``: check every dataset's SHA-256 too (reads the whole store)."""
    store = Store(path)
    with store.read() as r:
        if verify:
            for p in r.stage_paths():
                r.problems(p, contents=True)
        root = r.root_attrs()
        stages = [r.status(p).to_json() for p in r.stage_paths()]
        present = {p.split("/")[1] for p in r.stage_paths()}
        return {
            "path": str(store.path),
            "size_bytes": os.path.getsize(store.path),
            "format": str(root.get("format")),
            "format_version": int(root.get("format_version")),
            "created_utc": str(root.get("created_utc", "")),
            "stages": stages,
            "missing_stages": [n for n in layout.STAGES if n not in present],
            "interrupted_writes": [str(p) for p in store.interrupted_writes()],
            "recording_config": r.recording_config_json(),
        }
