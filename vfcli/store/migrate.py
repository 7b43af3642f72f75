"""Stores written before part files: their stages move to part files on the first write.

vfcli before :mod:`vfcli.store.parts` kept every stage inside the store file, so every write
copied all of it. The first write to such a store moves each stage of
:data:`vfcli.store.layout.PART_STAGES` into its own part file (:func:`move_inline_stages`,
one copy of the data, once) and the commit then writes a compact store file
(:func:`compact_copy`, which every commit writes: HDF5 never shrinks a file in place), after
which a write costs what it writes. Values, attributes, manifests and digests are copied as they are: no stage
becomes stale.
"""
from __future__ import annotations

import os
import posixpath
from pathlib import Path

import h5py

from vfcli.store import layout, parts

_SCALE_LINKS = ("DIMENSION_LIST", "REFERENCE_LIST")
_LIBVER = ("v110", "latest")


def inline_stages(f: h5py.File) -> list[str]:
    """Group paths of the stages of :data:`PART_STAGES` held inside the store file ``f``."""
    out = []
    for name in layout.PART_STAGES:
        if not isinstance(f.get(name, getlink=True), h5py.HardLink):
            continue
        if layout.STAGES[name].has_runs:
            out += [f"/{name}/{run}" for run in f[name] if isinstance(f[name].get(run, getlink=True), h5py.HardLink)]
        else:
            out.append(f"/{name}")
    return sorted(out)


def _relink_scales(g: h5py.Group, stage: layout.Stage) -> None:
    """Attach the axes of a copied stage group again (copied object references point into the
    file they were copied from)."""
    from vfcli.store.transaction import StageWriter

    for ds in g.values():
        if isinstance(ds, h5py.Dataset):
            for k in _SCALE_LINKS:
                if k in ds.attrs:
                    del ds.attrs[k]
    StageWriter(g, stage).attach_scales()


def move_inline_stages(f: h5py.File, store: Path, mode: int | None, written: list[Path]) -> None:
    """Move every stage :func:`inline_stages` finds in the (writable, temporary) store file ``f``
    of the store at real path ``store`` into a new part file, linked in its place. Appends
    each part file to ``written`` as soon as it is created (the caller removes them if its
    write aborts); they are fsynced."""
    for path in inline_stages(f):
        target = parts.new_part_name(store, path)
        part_path = store.parent / target
        part_path.parent.mkdir(exist_ok=True)
        written.append(part_path)
        with parts.writing(part_path, libver=_LIBVER) as part:
            parent = part.require_group(posixpath.dirname(path))
            f.copy(f[path], parent, name=posixpath.basename(path))
            _relink_scales(part[path], layout.stage(path.split("/")[1]))
        if mode is not None:
            os.chmod(part_path, mode)
        parts.fsync_path(part_path)
        del f[path]
        f[path] = h5py.ExternalLink(target, path)


def compact_copy(f: h5py.File, dst: Path) -> None:
    """Write a compact copy of the store file ``f`` (no stage inline but /mesh) to ``dst``:
    root attributes, the links, /mesh and the groups of runs."""
    with parts.writing(dst, fs_strategy="fsm", fs_persist=True, libver=_LIBVER) as out:
        for k, v in f.attrs.items():
            out.attrs[k] = v
        for key in f:
            link = f.get(key, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                out[key] = h5py.ExternalLink(link.filename, link.path)
            elif key in layout.STAGES and layout.STAGES[key].has_runs:
                runs = out.create_group(key)
                for k, v in f[key].attrs.items():
                    runs.attrs[k] = v
                for run in f[key]:
                    sub = f[key].get(run, getlink=True)
                    if isinstance(sub, h5py.ExternalLink):
                        runs[run] = h5py.ExternalLink(sub.filename, sub.path)
                    else:
                        f.copy(f[key][run], runs, name=run)
            else:
                f.copy(f[key], out, name=key)
                if key in layout.STAGES and isinstance(out[key], h5py.Group):
                    _relink_scales(out[key], layout.STAGES[key])
