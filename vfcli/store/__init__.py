"""The experiment store: one HDF5 file plus a parts folder per recording; the only package that imports h5py.

Modules: :mod:`~vfcli.store.layout` (every group and dataset, the only place HDF5 paths are
spelt), :mod:`~vfcli.store.transaction` (lock, atomic commit), :mod:`~vfcli.store.stage_writer` (:class:`StageWriter`),
:mod:`~vfcli.store.parts` (the part files beside the store file; :func:`copy_store`),
:mod:`~vfcli.store.migrate` (stores of an earlier vfcli), :mod:`~vfcli.store.signals`,
:mod:`~vfcli.store.netcdf` (xarray views of the groups, :func:`open_dataset`),
:mod:`~vfcli.store.precision` (stored float precision),
:mod:`~vfcli.store.reader` (:class:`StoreReader`), :mod:`~vfcli.store.frames` (per-frame
datasets, :class:`FrameReader`, N-bit), :mod:`~vfcli.store.chunks` (chunk encoding),
:mod:`~vfcli.store.provenance`, :mod:`~vfcli.store.info`, :mod:`~vfcli.store.truth` (a
phantom's truth file), and the typed readers :mod:`~vfcli.store.mesh` (/mesh) and
:mod:`~vfcli.store.runs` (/optimize/<run>).

The public names below are imported on first use (``from vfcli.store import Store``), so
importing :mod:`vfcli.store.layout` alone does not load h5py.
"""
from __future__ import annotations

import importlib
from typing import Any

_PUBLIC = {
    "Store": "transaction", "StoreWriter": "transaction", "StageWriter": "transaction",
    "StoreReader": "reader", "StageStatus": "reader",
    "FrameReader": "frames", "COMPRESSIONS": "frames", "CHUNK_CODECS": "frames",
    "read_truth": "truth", "write_truth": "truth", "TruthWriter": "truth",
    "StoredMesh": "mesh", "read_mesh": "mesh", "read_stored_mesh": "mesh",
    "OptimizeRun": "runs", "read_run": "runs", "run_names": "runs",
    "store_info": "info", "copy_store": "parts", "open_dataset": "netcdf",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(importlib.import_module(f"vfcli.store.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module 'vfcli.store' has no attribute {name!r}")
