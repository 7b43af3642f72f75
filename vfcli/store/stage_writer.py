"""The writer of one stage group: datasets with their units, axes and descriptions from the
layout, video frames encoded in threads, attributes and the stage's summary figures.

:class:`StageWriter` is handed out by :meth:`vfcli.store.transaction.StoreWriter.stage`
inside a write transaction (:mod:`vfcli.store.transaction`); it never commits anything itself.
"""
from __future__ import annotations

import json
from collections import deque
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping

import h5py
import numpy as np

from vfcli.store import layout
from vfcli.store.chunks import encode_frames
from vfcli.store.frames import CHUNK_CODECS, COMPRESSIONS, nbit_dataset

if TYPE_CHECKING:
    from vfcli.io.video.base import FrameBatch

_COMPRESSION = COMPRESSIONS["gzip"]


def _jsonable(value: Any) -> Any:
    """``value`` (not a JSON type) as JSON can hold it: numpy scalars and arrays as numbers and lists."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    return str(value)


class StageWriter:
    """Writes the datasets of one stage inside an open write transaction."""

    def __init__(self, group: h5py.Group, stage: layout.Stage) -> None:
        self._g = group
        self._stage = stage
        # every dataset written stays open until the transaction closes its file: libhdf5 writes a
        # dataset's cached chunks when its last handle closes, and a failure there (a full disk)
        # is swallowed by h5py and leaves libhdf5 unable to close the file (it crashes at exit);
        # held open, the chunks are written by the file's flush, whose failure aborts the write
        self._held: list[h5py.Dataset] = []

    def _spec(self, key: str) -> layout.Dataset | None:
        if self._stage.datasets:
            if key not in self._stage.datasets:
                raise KeyError(f"stage {self._stage.name!r} declares no dataset {key!r} (see vfcli/store/layout.py)")
            return self._stage.datasets[key]
        return None

    def _decorate(self, ds: h5py.Dataset, key: str, units: str | None, description: str | None) -> None:
        spec = self._spec(key)
        self._held.append(ds)
        ds.attrs["units"] = units or (spec.units if spec else "1")
        ds.attrs["description"] = description or (spec.description if spec else key)

    def put(
        self,
        key: str,
        data: Any,
        *,
        units: str | None = None,
        description: str | None = None,
        attrs: Mapping[str, Any] | None = None,
    ) -> h5py.Dataset:
        """Write a whole array (strings become variable-length UTF-8 text)."""
        spec = self._spec(key)
        arr = np.asarray(data)
        if arr.dtype.kind in "UO":
            arr = arr.astype(object)
            ds = self._g.create_dataset(key, data=arr, dtype=h5py.string_dtype())
        elif spec is not None and spec.frame_chunked and arr.ndim >= 2:
            ds = self._g.create_dataset(key, data=arr, chunks=(1, *arr.shape[1:]), **_COMPRESSION)
        else:
            ds = self._g.create_dataset(key, data=arr)
        self._decorate(ds, key, units, description)
        for k, v in (attrs or {}).items():
            ds.attrs[k] = v
        return ds

    def create(
        self,
        key: str,
        shape: tuple[int, ...],
        dtype: Any,
        *,
        units: str | None = None,
        description: str | None = None,
        attrs: Mapping[str, Any] | None = None,
        compression: str = "gzip",
    ) -> h5py.Dataset:
        """An empty dataset to fill frame by frame (chunked one frame per chunk, compressed
        with one of :data:`COMPRESSIONS`).

        Raises
        ------
        ValueError
            "nbit" for another dtype than uint16 (it stores 12-bit values only, for now).
        """
        chunks = (1, *shape[1:]) if len(shape) >= 2 else True
        opts = dict(COMPRESSIONS[compression])
        bits = opts.pop("nbit", None)
        if bits is None:
            ds = self._g.create_dataset(key, shape=shape, dtype=dtype, chunks=chunks, **opts)
        else:
            ds = nbit_dataset(self._g, key, shape, dtype, chunks, bits)
        self._decorate(ds, key, units, description)
        for k, v in (attrs or {}).items():
            ds.attrs[k] = v
        return ds

    def write_frames(
        self,
        key: str,
        shape: tuple[int, ...],
        dtype: Any,
        batches: Iterable[FrameBatch],
        *,
        units: str | None = None,
        description: str | None = None,
        attrs: Mapping[str, Any] | None = None,
        compression: str = "gzip",
        on_frames: Callable[[int], None] | None = None,
        workers: int | None = None,
    ) -> h5py.Dataset:
        """A per-frame dataset filled from a stream of frame batches, encoded in parallel.

        The dataset is the one :meth:`create` makes (one frame per chunk, the filters of
        :data:`COMPRESSIONS`); vfcli encodes each chunk itself (:data:`CHUNK_CODECS`, in
        threads, while the caller's iterator reads the next batch) and writes it unfiltered
        with ``write_direct_chunk``. Readers see an ordinary shuffle + gzip (or N-bit) dataset.

        Parameters
        ----------
        key : str
            Dataset name in the stage (declared in :mod:`vfcli.store.layout`).
        shape : (n_frames, H, W) or (n_frames, ...)
            Full dataset shape; one chunk is one ``shape[1:]`` frame.
        dtype : numpy dtype
            Stored element type; frames are converted to it (the file keeps its byte order).
        batches : iterable of (k, *shape[1:]) arrays or lazy FrameBatch
            The frames in order, ``shape[0]`` in all. Lazy batches
            (:meth:`vfcli.io.video.base.VideoSource.iter_lazy_frames`) are decoded in the worker
            threads. Memory stays about two batches plus
            :data:`vfcli.store.chunks.DEFAULT_PENDING_BYTES`, whatever ``n_frames``.
        compression : str
            One of :data:`COMPRESSIONS`.
        on_frames : callable, optional
            Called with the number of frames written after each batch's last frame (progress).
        workers : int, optional
            Decoding and encoding threads (default: one per core, at most 4).

        Returns
        -------
        h5py.Dataset

        Raises
        ------
        ValueError
            A batch of another frame shape, or more or fewer than ``shape[0]`` frames;
            "nbit" for another dtype than uint16.
        vfcli.store.chunks.ValueRangeError
            "nbit": a frame value above 4095 (the error names the frame, counted from 0).
        """
        if len(shape) < 2:
            raise ValueError(f"write_frames needs (n_frames, ...) with frames of >= 1 axis, got {shape}")
        ds = self.create(key, shape, dtype, units=units, description=description, attrs=attrs,
                         compression=compression)
        n = shape[0]
        ends: deque[int] = deque()  # frame count at the end of each batch read so far

        def checked() -> Iterator[FrameBatch]:
            total = 0
            for batch in batches:
                if tuple(batch.shape[1:]) != tuple(shape[1:]):
                    raise ValueError(f"{key}: a batch of frames {tuple(batch.shape[1:])}, the dataset's are {tuple(shape[1:])}")
                if len(batch) == 0:
                    continue
                total += len(batch)
                if total > n:
                    raise ValueError(f"{key}: more than the {n} frames declared")
                ends.append(total)
                yield batch

        zeros = (0,) * (len(shape) - 1)
        written = reported = 0
        # ds.dtype is the file's element type (byte order included): chunks are written as is
        for index, chunk in encode_frames(checked(), ds.dtype, CHUNK_CODECS[compression], workers=workers):
            ds.id.write_direct_chunk((index, *zeros), chunk)
            written = index + 1
            if ends and written == ends[0]:
                ends.popleft()
                if on_frames is not None:
                    on_frames(written - reported)
                reported = written
        if written != n:
            raise ValueError(f"{key}: {written} frames written, {n} declared")
        return ds

    def set_attrs(self, **attrs: Any) -> None:
        """Stage-level attributes (sampling rates, calibration ...)."""
        for k, v in attrs.items():
            self._g.attrs[k] = v

    def set_summary(self, figures: Mapping[str, Any], warnings: Iterable[str] = ()) -> None:
        """Store what the run reports (:data:`vfcli.store.layout.SUMMARY_ATTR`): the figures the
        command prints and the warnings it logged. Numpy scalars and arrays become JSON numbers
        and lists; anything else JSON cannot hold, its text."""
        self._g.attrs[layout.SUMMARY_ATTR] = json.dumps(
            {"figures": dict(figures), "warnings": list(warnings)}, sort_keys=True, default=_jsonable)

    def attach_scales(self) -> None:
        """Make every axis an HDF5 dimension scale (:data:`vfcli.store.layout.AXES`): an axis
        named after a dataset of this stage is that dataset; any other is stored beside the
        datasets under its own name (text labels or the 0-based index). An axis that cannot
        be (a time axis whose dataset was not written, a length that disagrees with the
        labels or with another dataset's) keeps its name only."""
        if not self._stage.datasets:
            return
        for key, spec in self._stage.datasets.items():
            if key not in self._g:
                continue
            ds = self._g[key]
            for axis, dim in enumerate(spec.dims[: ds.ndim]):
                ds.dims[axis].label = dim
                if dim == key:
                    if ds.ndim == 1 and not ds.is_scale:
                        ds.make_scale(dim)
                    continue
                scale = self._axis(dim, ds.shape[axis])
                if scale is not None:
                    ds.dims[axis].attach_scale(scale)

    def _axis(self, dim: str, n: int) -> h5py.Dataset | None:
        """The dimension scale of axis ``dim`` (length ``n``), created when missing; None
        when there is none of that length."""
        if dim not in self._g:
            ax = layout.AXES.get(dim)
            if ax is None or (ax.labels and len(ax.labels) != n):
                return None
            data = np.array(ax.labels, dtype=object) if ax.labels else np.arange(n, dtype=np.int64)
            scale = self._g.create_dataset(dim, data=data, dtype=h5py.string_dtype() if ax.labels else None)
            self._held.append(scale)
            scale.attrs["units"] = "1" if ax.labels else "index"
            scale.attrs["description"] = ax.description
        scale = self._g[dim]
        if not isinstance(scale, h5py.Dataset) or scale.ndim != 1 or scale.shape[0] != n:
            return None
        if not scale.is_scale:
            scale.make_scale(dim)
        return scale
