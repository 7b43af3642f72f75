"""The ledger of a batch: what became of each recording, in ``<manifest>.ledger.json``.

The ledger is rewritten whole and atomically (a temporary file in the same folder, fsync,
``os.replace``) after each recording ends, so a batch killed at any moment leaves the
ledger of the recordings finished before. A rerun of the same manifest skips a recording
whose entry says done or up to date, when nothing that defines it changed: its manifest
entry (:meth:`RecordingEntry.key`), the files of its raw folder (names, sizes, modification
times) and its store file (size, modification time). Anything else runs again (``vfcli
run`` itself only redoes the stale stages).

One batch at a time per manifest: :meth:`Ledger.hold` takes an exclusive ``flock`` on
``.<manifest>.ledger.json.lock`` beside it for the whole batch (the kernel releases it when the
process dies), so a second `vfcli batch` of the same manifest stops at once with one line
(exit 4) instead of running the same recordings again at the same time and overwriting the
first one's ledger. Where the file system gives no locks (errno 37, 524 on some NFS and
Lustre mounts) it stops with one line too: keep the manifest, hence its ledger, on a file
system with locks (the stores may be anywhere).

Format (JSON)::

    {"format": "vfcli-batch-ledger", "version": 1, "manifest": "/abs/batch.toml",
     "recordings": {"rec01": {"status": "done", "key": "...", "raw_stamp": "...",
                              "store_stamp": [size, mtime_ns], "error": null, "exit_code": 0,
                              "attempts": 1, "seconds": 12.3, "finished_utc": "...",
                              "summary": {... RunSummary.to_json() ...}}}}
"""
from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import json
import os
import socket
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

from vfcli.batch.manifest import RecordingEntry
from vfcli.errors import StoreAccessError, StoreLockedError
from vfcli.store import locking

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

    @property
    def lock_path(self) -> Path:
        """The lock file of this ledger: ``.<ledger name>.lock`` beside it."""
        return self.path.with_name(f".{self.path.name}.lock")

    @contextmanager
    def hold(self) -> Iterator[None]:
        """Hold this ledger (hence the manifest's batch) exclusively until the block ends.

        Raises
        ------
        StoreLockedError
            Another process holds it (another `vfcli batch` of the same manifest); the
            message names that process (pid, host, start time). Exit 4.
        LockUnsupportedError
            The file system gives no ``flock`` (errno 37, 524). Exit 4.
        StoreAccessError
            The lock file cannot be created (a read-only folder). Exit 4.
        """
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise StoreAccessError(f"cannot write the batch ledger's lock file: {exc.strerror or exc}: "
                                   f"{exc.filename}", self.manifest) from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    holder = os.pread(fd, 512, 0).decode("utf-8", "replace").strip() or "a process"
                    raise StoreLockedError(f"another `vfcli batch` of this manifest is running ({holder}); wait "
                                           f"for it to end (it keeps {self.path.name}), then run again to resume",
                                           self.manifest) from None
                if locking.lock_unsupported(exc):
                    raise locking.LockUnsupportedError(
                        f"this file system gives no file locks (flock on {self.lock_path} failed: errno {exc.errno}), "
                        "so vfcli cannot keep two batches of this manifest apart; keep the manifest (its ledger "
                        "lives beside it) on a file system with locks, such as your home folder (the stores may "
                        "stay where they are)", self.manifest) from None
                raise
            started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {started}\n".encode(), 0)
            yield
        finally:
            os.close(fd)

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
