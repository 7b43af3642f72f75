"""Integrity of a stage: its manifest (the structure and checksums vfcli relies on) and the checks.

When a stage is committed, :func:`manifest` records in the stage group's
:data:`vfcli.store.layout.MANIFEST_ATTR` attribute, as JSON,

* every dataset of the stage: its shape, its dtype and the SHA-256 of what it stores
  (:func:`dataset_sha256`: the stored bytes of each chunk of a chunked dataset, as HDF5 keeps
  them, so checking a compressed video costs no decompression; the values of any other);
* the names and SHA-256 of the stage's own attributes at that moment (sampling rates,
  calibration, summary; not the provenance, which is checked by parsing it).

:func:`check_structure` (cheap: opens the datasets, reads no data) checks that the provenance
attributes are all there and parse, and that every dataset of the manifest is there with its
shape and dtype, plus the attributes' checksum; :func:`check_contents` also checks the
datasets' checksums (reads every stored byte). Both return a list of problems, one line
each, naming the stage and the dataset; they never raise on a damaged file.
:class:`vfcli.store.reader.StoreReader` runs them (see ``docs/input-checks.md``, "Store integrity").
"""
from __future__ import annotations

import hashlib
import json
from typing import Any

import h5py
import numpy as np

from vfcli.store import layout

#: What reading a damaged HDF5 file can raise (h5py turns libhdf5 errors into these).
H5_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError, IndexError, UnicodeDecodeError)

_NOT_HASHED_ATTRS = frozenset((*layout.PROVENANCE_ATTRS, "complete", layout.MANIFEST_ATTR, layout.METHOD_ATTR))


def dataset_sha256(ds: h5py.Dataset) -> str:
    """SHA-256 of what ``ds`` stores: for a chunked dataset, each written chunk's filter mask and
    stored (filtered) bytes in the order of its offsets; for any other, its values in C order
    (text as UTF-8, each value ended by a NUL)."""
    h = hashlib.sha256()
    if ds.chunks is not None:
        dsid = ds.id
        offsets = sorted(dsid.get_chunk_info(i).chunk_offset for i in range(dsid.get_num_chunks()))
        for off in offsets:
            mask, chunk = dsid.read_direct_chunk(off)
            h.update(np.asarray(off, np.int64).tobytes())
            h.update(int(mask).to_bytes(4, "little"))
            h.update(chunk)
    elif h5py.check_string_dtype(ds.dtype):
        for s in np.asarray(ds.asstr()[()], dtype=object).reshape(-1):
            h.update(str(s).encode() + b"\0")
    else:
        h.update(np.ascontiguousarray(ds[()]).tobytes())
    return h.hexdigest()


def _plain(value: Any) -> Any:
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value if isinstance(value, (str, int, float, bool)) or value is None else repr(value)


def hashed_attrs(g: h5py.Group) -> list[str]:
    """Names of the stage group's attributes the manifest covers: all but the provenance and manifest."""
    return sorted(k for k in g.attrs if k not in _NOT_HASHED_ATTRS)


def attrs_sha256(g: h5py.Group, names: list[str]) -> str:
    """SHA-256 of the stage group's attributes ``names`` (a missing one counts as damage: KeyError)."""
    items = {k: _plain(g.attrs[k]) for k in names}
    return hashlib.sha256(json.dumps(items, sort_keys=True, default=repr).encode()).hexdigest()


def manifest(g: h5py.Group) -> str:
    """The manifest of a stage group as written (JSON; see the module's docstring)."""
    datasets = {}
    for key, obj in g.items():
        if isinstance(obj, h5py.Dataset):
            datasets[key] = {"shape": list(obj.shape), "dtype": obj.dtype.str, "sha256": dataset_sha256(obj)}
    names = hashed_attrs(g)
    return json.dumps({"datasets": datasets, "attrs": names, "attrs_sha256": attrs_sha256(g, names)}, sort_keys=True)


def _json_attr(g: h5py.Group, name: str, kind: type) -> Any:
    value = g.attrs[name]
    parsed = json.loads(value.decode() if isinstance(value, bytes) else str(value))
    if not isinstance(parsed, kind):
        raise ValueError(f"not a JSON {kind.__name__}")
    return parsed


def _read_manifest(f: h5py.File, path: str) -> tuple[h5py.Group | None, dict[str, Any] | None, list[str]]:
    """The stage group, its parsed manifest (None for a stage written before manifests) and the
    problems of its provenance."""
    try:
        g = f[path]
        if not isinstance(g, h5py.Group):
            return None, None, [f"{path} is not a group"]
        names = set(g.attrs)
    except H5_ERRORS as exc:
        return None, None, [f"{path} cannot be read ({why(exc)})"]
    problems = [f"{path} has no '{a}' attribute" for a in layout.PROVENANCE_ATTRS if a not in names]
    for name, kind in (("config_json", dict), ("inputs_json", dict), ("upstream_json", dict),
                       (layout.SUMMARY_ATTR, dict), (layout.MANIFEST_ATTR, dict)):
        if name in names:
            try:
                _json_attr(g, name, kind)
            except H5_ERRORS + (json.JSONDecodeError,) as exc:
                problems.append(f"{path}: attribute '{name}' is not valid ({why(exc)})")
    if problems or layout.MANIFEST_ATTR not in names:
        return g, None, problems
    return g, _json_attr(g, layout.MANIFEST_ATTR, dict), problems


def why(exc: BaseException) -> str:
    """The first line of an exception's message (a KeyError's without its quotes), at most 160 characters."""
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return (text.splitlines() or [""])[0][:160] or type(exc).__name__


def check_structure(f: h5py.File, path: str) -> list[str]:
    """Problems of stage group ``path`` that reading no data finds (empty when none)."""
    g, man, problems = _read_manifest(f, path)
    if g is None or man is None:
        return problems
    try:
        g.visititems(lambda _name, _obj: None)  # every object header and link of the group opens
        for key, want in man.get("datasets", {}).items():
            where = f"{path}/{key}"
            if key not in g:
                problems.append(f"{where} is missing (deleted or damaged)")
                continue
            ds = g[key]
            if not isinstance(ds, h5py.Dataset):
                problems.append(f"{where} is not a dataset")
            elif list(ds.shape) != want["shape"] or ds.dtype.str != want["dtype"]:
                problems.append(f"{where} is {ds.dtype.str} {list(ds.shape)}, the stage wrote "
                                f"{want['dtype']} {want['shape']}")
        names = man.get("attrs", [])
        missing = [k for k in names if k not in g.attrs]
        if missing:
            problems.append(f"{path} has no '{missing[0]}' attribute (deleted)")
        elif attrs_sha256(g, names) != man.get("attrs_sha256"):
            problems.append(f"{path}: its attributes differ from what the stage wrote (checksum)")
    except H5_ERRORS as exc:
        problems.append(f"{path} cannot be read ({why(exc)})")
    return problems


def check_dataset(ds: h5py.Dataset, path: str, man: dict[str, Any] | None) -> str | None:
    """The problem of one dataset's checksum against the manifest ``man`` (None when it matches
    or the stage has no manifest)."""
    want = (man or {}).get("datasets", {}).get(ds.name.rsplit("/", 1)[-1])
    if want is None:
        return None
    try:
        got = dataset_sha256(ds)
    except H5_ERRORS as exc:
        return f"{ds.name} cannot be read ({why(exc)})"
    return None if got == want["sha256"] else f"{ds.name}: its stored bytes differ from what the stage wrote (SHA-256)"


def check_contents(f: h5py.File, path: str) -> list[str]:
    """Problems of stage group ``path``: :func:`check_structure`, then every dataset's checksum."""
    problems = check_structure(f, path)
    if problems:
        return problems
    g, man, _ = _read_manifest(f, path)
    for key in (man or {}).get("datasets", {}):
        problem = check_dataset(g[key], path, man)
        if problem:
            problems.append(problem)
    return problems


def stage_manifest(f: h5py.File, path: str) -> dict[str, Any] | None:
    """The parsed manifest of a stage group that :func:`check_structure` passed (None: none)."""
    return _read_manifest(f, path)[1]


def h5py_damage(exc: BaseException) -> str | None:
    """The one-line reason when ``exc`` was raised by h5py/libhdf5 reading a damaged file (the
    innermost frame is in h5py, and it is not a name that does not exist: that is a bug of
    the caller); None otherwise."""
    if not isinstance(exc, H5_ERRORS):
        return None
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    if tb is None or "h5py" not in tb.tb_frame.f_code.co_filename.replace("\\", "/").split("/"):
        return None
    reason = why(exc)
    return None if "doesn't exist" in reason or "does not exist" in reason else reason
