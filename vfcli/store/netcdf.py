"""xarray views of a store's groups, whatever netCDF engine reads them.

A store is its file plus its parts folder (:mod:`vfcli.store.parts`): every stage but /mesh
lives in a part file, reached from the store file by an HDF5 external link. libhdf5 follows
the link, and so do the readers built on it: h5py, HDFView, MATLAB and netCDF-C, so
``xr.open_dataset("rec.h5", group="hsc", engine="netcdf4")`` opens every group of the store
file with its named dimensions (tests/test_store_sharing.py).

xarray's h5netcdf engine cannot: to name a dataset's dimensions it reads the object
references of the dataset's ``DIMENSION_LIST`` attribute and dereferences them against the
file it opened (h5netcdf 1.8, ``core.py``, ``BaseVariable._lookup_dimensions``:
``self._root._h5file[ref]``), while an HDF5 object reference is an address inside the file
that holds the dataset, here the part file, so the look-up lands on an unrelated address of
the store file ("bad object header version number", "address of object past end of
allocation"). No layout of a store with part files avoids it: the references resolve in the
store file only if the datasets are in it (a store that copies its stages on every write,
what part files removed) or are virtual datasets mapped onto the part files, which every
reader fills silently with zeros when the parts folder is missing. :func:`open_dataset` opens
a group from the file that holds it, for every engine.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py

from vfcli.errors import ConfigError, MissingStageError
from vfcli.store import layout
from vfcli.store.parts import refuse_missing
from vfcli.store.reader import check_format, open_h5

if TYPE_CHECKING:
    import xarray


def locate(store: str | Path, group: str) -> tuple[Path, str]:
    """The file that holds ``group`` of ``store`` ("hsc", "/optimize/run1", "optimize") and its
    path there: ``(part file, "/hsc")`` for a stage in a part file, ``(store file, group)``
    otherwise.

    Raises
    ------
    ConfigError
        No such store file.
    StoreFormatError
        Not a vfcli store, or its parts folder is missing (one line, as every command says it).
    MissingStageError
        The store has no such group.
    """
    shown = Path(store)
    real = Path(os.path.realpath(store))
    if not real.exists():
        raise ConfigError("no such store file", shown)
    path = "/" + group.strip("/")
    with open_h5(real, "r") as f:
        check_format(f, shown)
        refuse_missing(f, real, shown)
        names = path.strip("/").split("/")
        st = layout.STAGES.get(names[0])
        depth = 2 if st is not None and st.has_runs and len(names) > 1 else 1
        stage_path = "/" + "/".join(names[:depth])
        try:
            link = f.get(stage_path, getlink=True) if path != "/" else None
        except KeyError:
            link = None
        if path != "/" and (link is None or path not in f):
            raise MissingStageError(f"the store has no group {path}", shown)
        if isinstance(link, h5py.ExternalLink):
            return real.parent / link.filename, link.path.rstrip("/") + path[len(stage_path):]
    return real, path


def open_dataset(store: str | Path, group: str, engine: str = "h5netcdf", **kwargs: Any) -> "xarray.Dataset":
    """Group ``group`` of ``store`` ("hsc", "flow", "optimize/run1") as an :class:`xarray.Dataset`
    with the layout's named dimensions (:data:`vfcli.store.layout.AXES`), read lazily from the
    file that holds it (:func:`locate`): works with every xarray engine, h5netcdf included.

    ``kwargs`` go to :func:`xarray.open_dataset`. The dataset reads the version of the stage
    stored now: a later write of that stage puts it in a new part file and deletes this one
    once no reader holds the store (an open dataset keeps reading the old file on Linux and
    macOS); ``.load()`` what you keep, or open it again after a write.

    >>> from vfcli.store import open_dataset                       # doctest: +SKIP
    >>> open_dataset("rec.h5", "flow")["flow"].sel(uv="u")         # doctest: +SKIP
    """
    try:
        import xarray as xr
    except ImportError:
        raise ImportError("vfcli.store.open_dataset needs xarray and a netCDF engine: "
                          "pip install xarray h5netcdf (or netCDF4)") from None
    file, path = locate(store, group)
    return xr.open_dataset(file, group=path, engine=engine, **kwargs)
