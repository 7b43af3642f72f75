"""The ledger of a batch: what became of each recording, in ``<manifest>.ledger.json``.

The ledger is rewritten whole and atomically (a temporary file in the same folder, fsync,
``os.replace``) after each recording ends, so a batch killed at any moment leaves the
ledger of the recordings finished before. A rerun of the same manifest skips a recording
whose entry says done or up to date, when nothing that defines it changed: its manifest
entry (:meth:`RecordingEntry.key`), the files of its raw folder (names, sizes, modification
times) and its store file (size, modification time). Anything else runs again (``vfcli
run`` itself only redoes the stale stages).

Format (JSON)::

    {"format": "vfcli-batch-ledger", "version": 1, "manifest": "/abs/batch.toml",
     "recordings": {"rec01": {"status": "done", "key": "...", "raw_stamp": "...",
                              "store_stamp": [size, mtime_ns], "error": null, "exit_code": 0,
                              "attempts": 1, "seconds": 12.3, "finished_utc": "...",
                              "summary": {... RunSummary.to_json() ...}}}}
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from pathlib import Path
from typing import Any, Mapping

from vfcli.batch.manifest import RecordingEntry

FORMAT = "vfcli-batch-ledger"
VERSION = 1
#: Statuses a rerun does not run again (when nothing changed).
FINISHED = ("done", "up to date")


def raw_stamp(raw: Path) -> str:
    """SHA-256 over the (relative name, size, mtime_ns) of every file under ``raw`` (stat only;
    '' when the folder does not exist)."""
    if not raw.is_dir():
        return ""
    h = hashlib.sha256()
    for p in sorted(raw.rglob("*")):
        if p.is_file():
            st = p.stat()
            h.update(f"{p.relative_to(raw)}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def store_stamp(store: Path) -> list[int] | None:
    """[size in bytes, mtime_ns] of the store file, None when it does not exist."""
    try:
        st = store.stat()
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns]


class Ledger:
    """The recordings' outcomes of one manifest, kept in a JSON file (see the module docstring)."""

    def __init__(self, path: Path, manifest: Path, recordings: Mapping[str, dict[str, Any]] | None = None) -> None:
        self.path = Path(path)
        self.manifest = Path(manifest)
        self.recordings: dict[str, dict[str, Any]] = dict(recordings or {})

    @classmethod
    def load(cls, path: Path, manifest: Path) -> "Ledger":
        """The ledger at ``path``; an empty one when the file is missing or is not a ledger
        (an unreadable ledger only costs a rerun, which ``vfcli run`` keeps cheap)."""
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return cls(path, manifest)
        if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("recordings"), dict):
            return cls(path, manifest)
        return cls(path, manifest, doc["recordings"])

    def is_finished(self, entry: RecordingEntry) -> bool:
        """Whether ``entry`` ended done or up to date and nothing that defines it changed since."""
        rec = self.recordings.get(entry.name)
        return bool(
            rec
            and rec.get("status") in FINISHED
            and rec.get("key") == entry.key()
            and rec.get("raw_stamp") == raw_stamp(entry.raw)
            and rec.get("store_stamp") == store_stamp(entry.store)
        )

    def record(self, entry: RecordingEntry, outcome: Mapping[str, Any]) -> None:
        """Add ``outcome`` (a :func:`vfcli.batch.task.run_entry` result plus ``attempts``) for
        ``entry`` and rewrite the file atomically."""
        self.recordings[entry.name] = {
            **dict(outcome),
            "key": entry.key(),
            "raw_stamp": raw_stamp(entry.raw),
            "store_stamp": store_stamp(entry.store),
            "finished_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        }
        self.save()

    def save(self) -> None:
        """Write the ledger: temporary file beside it, fsync, atomic rename."""
        doc = {"format": FORMAT, "version": VERSION, "manifest": str(self.manifest), "recordings": self.recordings}
        tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        try:
            with open(tmp, "w", encoding="utf-8") as fh:
                json.dump(doc, fh, indent=1, sort_keys=True, default=str)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
