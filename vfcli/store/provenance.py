"""Provenance of a stage: hashes of raw input files and the digest of a stage's content.

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

import h5py
import numpy as np

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
    """True when two input descriptions hold files of the same content, wherever they are: the
    files are matched by SHA-256, not by path (a recording moved to another disk is the same)."""
    return sorted(v["sha256"] for v in a.values()) == sorted(v["sha256"] for v in b.values())


#: Attributes left out of a stage's content digest: the dimension-scale bookkeeping (object
#: references, which depend on where the file put things) and the provenance itself.
_NOT_CONTENT = {"DIMENSION_LIST", "REFERENCE_LIST", "CLASS", "NAME", "complete", "summary_json",
                "stage", "vfcli_version", "command", "created_utc", "config_json", "inputs_json",
                "upstream_json", "digest", "method_version",   # vfcli.store.layout.METHOD_ATTR
                "manifest_json"}   # hashes of the datasets and attrs (summary_json: warnings quote paths as typed)


def _update_attrs(h: "hashlib._Hash", attrs: Any) -> None:
    for k in sorted(attrs):
        if k not in _NOT_CONTENT:
            v = attrs[k]
            if isinstance(v, (np.ndarray, np.generic)) and np.asarray(v).dtype.kind != "O":
                blob = np.asarray(v).dtype.str.encode() + np.asarray(v).tobytes()
            else:  # text and object arrays by value (their bytes are pointers)
                blob = repr(v.tolist() if isinstance(v, np.ndarray) else v).encode()
            h.update(k.encode() + b"=" + blob + b";")


def content_digest(group: h5py.Group, dataset_sha256: Mapping[str, str] | None = None) -> str:
    """Digest of what a stage group holds: every dataset's name, type, shape, attributes and
    stored bytes (chunks as stored, so no decompression), and the group's own attributes
    except its provenance. Rewriting a stage with the same content gives the same digest, so
    the stages that use it stay current (it costs one read of the stage's stored bytes).

    ``dataset_sha256`` : name -> SHA-256 of the stored bytes of datasets already hashed (the stage's
    integrity manifest, written just before), so a commit reads and hashes each chunk once."""
    known = dataset_sha256 or {}
    h = hashlib.sha256()
    _update_attrs(h, group.attrs)
    names: list[str] = []
    group.visit(names.append)
    for name in sorted(names):
        obj = group[name]
        h.update(b"\0" + name.encode())
        _update_attrs(h, obj.attrs)
        if not isinstance(obj, h5py.Dataset):
            continue
        h.update(f"{obj.dtype.str}|{h5py.check_string_dtype(obj.dtype)}|{obj.shape}|{obj.chunks}".encode())
        if name in known:
            h.update(known[name].encode())
        elif obj.chunks is not None:
            for i in range(obj.id.get_num_chunks()):
                info = obj.id.get_chunk_info(i)
                mask, chunk = obj.id.read_direct_chunk(info.chunk_offset)
                h.update(f"{info.chunk_offset}|{mask}|".encode())
                h.update(chunk)
        elif h5py.check_string_dtype(obj.dtype):
            h.update(json.dumps(np.asarray(obj.asstr()[()]).tolist()).encode())
        elif obj.size:
            h.update(np.ascontiguousarray(obj[()]).tobytes())
    return h.hexdigest()[:16]
