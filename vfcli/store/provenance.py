"""Provenance of a stage: hashes of raw input files and the digest of a stage.

File hashes are cached by (size, mtime_ns, ctime_ns): a file whose size, modification time
and status-change time are unchanged since the last run is not hashed again, so re-running a
pipeline over a 4 GB video does not cost a full read to find out that nothing changed. The
ctime is what makes the cache safe against a file edited and its mtime restored (``touch -d``,
``os.utime``): the kernel sets the ctime to the current time on every write and on every
change of the mtime, and no call sets it back. Any doubt (a record without a ctime, a file
copied or moved) costs one hash, never a missed change.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Mapping

_CHUNK = 8 << 20


def sha256_file(path: str | Path) -> str:
    """SHA-256 hex digest of a file, read in 8 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_CHUNK):
            h.update(block)
    return h.hexdigest()


def describe_inputs(
    paths: list[str | Path], previous: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, dict[str, Any]]:
    """Identify raw input files: ``{absolute path: {sha256, size, mtime_ns, ctime_ns}}``.

    Folders (a folder of numbered images) are described by every file in them.
    A file whose size, mtime and ctime match ``previous`` reuses the previous hash.
    """
    previous = previous or {}
    out: dict[str, dict[str, Any]] = {}
    files: list[Path] = []
    for p in paths:
        p = Path(p).resolve()
        files.extend(sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p])
    for f in files:
        st = os.stat(f)
        key = str(f)
        old = previous.get(key)
        if old and (old.get("size"), old.get("mtime_ns"), old.get("ctime_ns")) == (st.st_size, st.st_mtime_ns, st.st_ctime_ns):
            digest = old["sha256"]
        else:
            digest = sha256_file(f)
        out[key] = {"sha256": digest, "size": st.st_size, "mtime_ns": st.st_mtime_ns, "ctime_ns": st.st_ctime_ns}
    return out


def same_inputs(a: Mapping[str, Mapping[str, Any]], b: Mapping[str, Mapping[str, Any]]) -> bool:
    """True when two input descriptions name the same files with the same content."""
    return {k: v["sha256"] for k, v in a.items()} == {k: v["sha256"] for k, v in b.items()}


def stage_digest(record: Mapping[str, Any]) -> str:
    """Digest identifying one write of a stage (changes whenever the stage is rewritten)."""
    blob = json.dumps(record, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]
