"""A phantom's ``truth.h5`` (written by `vfcli synth`; read by tests and benchmarks only)."""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from vfcli import __version__
from vfcli.store import layout
from vfcli.store.frames import COMPRESSIONS
from vfcli.store.parts import writing

_COMPRESSION = COMPRESSIONS["gzip"]


class TruthWriter:
    """Writes a phantom's ``truth.h5`` (keys from :data:`vfcli.store.layout.TRUTH`)."""

    def __init__(self, f: h5py.File) -> None:
        self._f = f

    def _decorate(self, ds: h5py.Dataset, key: str) -> h5py.Dataset:
        spec = layout.TRUTH[key]
        ds.attrs["units"] = spec.units
        ds.attrs["description"] = spec.description
        return ds

    def put(self, key: str, data: Any) -> h5py.Dataset:
        arr = np.asarray(data)
        spec = layout.TRUTH[key]
        kw = dict(chunks=(1, *arr.shape[1:]), **_COMPRESSION) if spec.frame_chunked and arr.ndim >= 2 else {}
        return self._decorate(self._f.create_dataset(key, data=arr, **kw), key)

    def create(self, key: str, shape: tuple[int, ...], dtype: Any) -> h5py.Dataset:
        """An empty per-frame dataset to fill frame by frame."""
        ds = self._f.create_dataset(key, shape=shape, dtype=dtype, chunks=(1, *shape[1:]), **_COMPRESSION)
        return self._decorate(ds, key)

    def set_attrs(self, **attrs: Any) -> None:
        for k, v in attrs.items():
            self._f.attrs[k] = v


@contextmanager
def write_truth(path: str | Path) -> Iterator[TruthWriter]:
    """Create ``truth.h5`` (overwrites).  A failed write (e.g. a full disk) closes the file with
    :func:`vfcli.store.parts.close_discarding` (libhdf5 would otherwise crash at exit flushing it
    again); the caller removes it."""
    with writing(Path(path), libver=("v110", "latest")) as f:
        f.attrs["format"] = "vfcli-phantom-truth"
        f.attrs["generated_by"] = f"vfcli {__version__}"
        yield TruthWriter(f)


def read_truth(path: str | Path, keys: list[str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """(datasets, root attributes) of a phantom's ``truth.h5`` (tests and benchmarks only)."""
    with h5py.File(path, "r") as f:
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
        wanted = keys if keys is not None else [k for k in layout.TRUTH if k in f]
        return {k: f[k][()] for k in wanted}, attrs


@contextmanager
def truth_datasets(path: str | Path) -> Iterator[dict[str, h5py.Dataset]]:
    """The per-frame datasets of a phantom's ``truth.h5`` (keys of :data:`vfcli.store.layout.TRUTH` present), open
    for reading in slices of frames: a scorer of a long large-frame phantom streams them rather than holding
    ``screen/velocity`` whole (1600 frames of 384 x 384 px: 2.8 GB as stored).  Tests and benchmarks only."""
    with h5py.File(path, "r") as f:
        yield {k: f[k] for k in layout.TRUTH if k in f}
