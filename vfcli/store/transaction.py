"""The experiment store: one HDF5 file per recording, the only module that opens HDF5.

Crash safety
------------
A write never touches the store file itself. The writer takes an exclusive lock
(``flock`` on the sidecar ``.<name>.lock``, released by the kernel if the process
dies), copies the store to ``<name>.tmp-<pid>``, writes the stage there, flushes and
fsyncs it, and atomically renames it over the store. A process killed at any moment
therefore leaves either the old file or the new one, never a half-written stage; a
leftover ``.tmp-`` file is the only trace and is removed by the next writer (``vfcli
info`` reports it as an interrupted write). Readers open the store read-only and keep
the version they opened. Files are created with persistent free-space tracking, so a
stage that is rewritten reuses the space of its previous version.

Video frames
------------
:meth:`StageWriter.write_frames` streams a video into a one-frame-per-chunk dataset with
standard filters (shuffle + gzip, or N-bit for 12-bit video), but encodes the chunks
itself, in worker threads (:mod:`vfcli.store.chunks`), and writes them with
``write_direct_chunk``: several times faster than HDF5's own single-threaded filters, and
read by every HDF5 reader as usual. :class:`FrameReader` reads such datasets back; N-bit
frames it unpacks itself, about 4x faster than libhdf5's N-bit filter.

Provenance and idempotence
--------------------------
Every stage group records its validated config (JSON), the vfcli version, the command
line, the time, the SHA-256 of each raw input file, and the digest of each upstream
stage it used. :meth:`StoreReader.is_current` tells a command that its inputs, config
and upstream stages are unchanged, so it can skip the work; a stage whose upstream was
rewritten since is reported as stale.
"""
from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import json
import os
import secrets
import shutil
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping

import h5py
import numpy as np

from vfcli import __version__

from vfcli.store import layout
from vfcli.errors import ConfigError, MissingStageError, StoreAccessError, StoreFormatError, StoreLockedError
from vfcli.store.chunks import NBIT_BITS, ChunkCodec, encode_frames, unpack_nbit12
from vfcli.store.provenance import same_inputs, stage_digest

if TYPE_CHECKING:
    from vfcli.io.video.base import FrameBatch

_TMP_MARK = ".tmp-"
#: Filters of large per-frame datasets, by name: h5py ``create_dataset`` options, except
#: "nbit", HDF5's built-in N-bit filter on uint16 of 12 bits of precision (lossless for
#: 12-bit video, 75 % of uint16, no compression work; :meth:`StageWriter.create`). Every
#: HDF5 reader opens all of them without plugins (HDFView, MATLAB, h5py). "gzip" (deflate
#: level 1 + shuffle) is the default; see docs/benchmarks.md ("Ingest") for the measured
#: speed of each.
COMPRESSIONS: dict[str, dict[str, Any]] = {
    "gzip": {"compression": "gzip", "compression_opts": 1, "shuffle": True},
    "gzip4": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
    "nbit": {"nbit": NBIT_BITS},
    "none": {},
}
_COMPRESSION = COMPRESSIONS["gzip"]
#: How :meth:`StageWriter.write_frames` encodes the chunks of each of :data:`COMPRESSIONS`
#: itself (the dataset keeps the filters above, so every reader decodes them with plain
#: zlib). Each byte plane is deflated on its own and incompressible planes are stored
#: (:func:`vfcli.store.chunks.deflate_planes`): "gzip" with ISA-L at level 1 (files the
#: size of zlib's level 1, several times faster), "gzip4" with zlib's level 4. "nbit" packs
#: the 12 bits of each pixel (12-bit packed MRAW frames are copied as they are).
CHUNK_CODECS: dict[str, ChunkCodec] = {
    "gzip": ChunkCodec(shuffle=True, deflate="isal", level=1, per_plane=True),
    "gzip4": ChunkCodec(shuffle=True, deflate="zlib", level=4, per_plane=True),
    "nbit": ChunkCodec(nbit=NBIT_BITS),
    "none": ChunkCodec(),
}


def _nbit_dataset(
    group: h5py.Group, key: str, shape: tuple[int, ...], dtype: Any, chunks: Any, bits: int
) -> h5py.Dataset:
    """An empty dataset of unsigned integers of ``bits`` bits of precision under HDF5's
    N-bit filter (what ``H5Pset_nbit`` makes; the library fills in the filter's parameters).

    Raises
    ------
    ValueError
        Another dtype than uint16 or another precision than :data:`NBIT_BITS`.
    """
    if np.dtype(dtype) != np.uint16 or bits != NBIT_BITS:
        raise ValueError(f"the nbit frame filter stores {NBIT_BITS}-bit values in uint16 only (for now), "
                         f"got {np.dtype(dtype)} of {bits} bits; use gzip")
    tid = h5py.h5t.STD_U16LE.copy()
    tid.set_precision(bits)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_filter(h5py.h5z.FILTER_NBIT, h5py.h5z.FLAG_OPTIONAL, ())
    return group.create_dataset(key, shape=shape, dtype=tid, chunks=chunks, dcpl=dcpl)


def _is_nbit12_frames(ds: h5py.Dataset) -> bool:
    """Whether ``ds`` is (n, ...) little-endian uint16 of 12 bits of precision, one frame per
    chunk, every chunk written, under the N-bit filter alone: chunks :func:`unpack_nbit12` reads."""
    if ds.ndim < 2 or ds.chunks != (1, *ds.shape[1:]) or ds.dtype != np.dtype("<u2"):
        return False
    tid, dcpl = ds.id.get_type(), ds.id.get_create_plist()
    if (tid.get_precision(), tid.get_offset()) != (NBIT_BITS, 0) or dcpl.get_nfilters() != 1:
        return False
    return dcpl.get_filter(0)[0] == h5py.h5z.FILTER_NBIT and ds.id.get_num_chunks() == ds.shape[0]


class FrameReader:
    """Frames of a one-frame-per-chunk dataset, indexed along the first axis, read fast.

    N-bit 12-bit datasets (:data:`COMPRESSIONS` "nbit") are read chunk by chunk as stored
    (``read_direct_chunk``) and unpacked with numpy (:func:`vfcli.store.chunks.unpack_nbit12`),
    several times faster than libhdf5's N-bit filter; any other dataset, and any other key,
    is read by h5py. Same values either way.

    Attributes
    ----------
    shape, dtype, ndim
        The dataset's.
    """

    def __init__(self, ds: h5py.Dataset) -> None:
        self._ds = ds
        self.shape: tuple[int, ...] = ds.shape
        self.dtype: np.dtype = ds.dtype
        self.ndim: int = ds.ndim
        self._nbit = _is_nbit12_frames(ds)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        """Frames by ``key``: an int ((H, W) frame), a slice or a 1-D integer array of frame
        indices, in any order ((k, H, W); numpy's rules), or ``()``/``...`` (all); any other
        key as h5py indexes."""
        idx = self._indices(key)
        if idx is None:
            return self._ds[key]
        if self._nbit:
            frames = self._read(idx)
        elif isinstance(key, slice) and (key.step or 1) > 0:
            frames = self._ds[key]
        else:                                   # h5py reads increasing indices only
            unique, inverse = np.unique(idx, return_inverse=True)
            frames = self._ds[unique][inverse]
        return frames[0] if isinstance(key, (int, np.integer)) else frames

    def _indices(self, key: Any) -> np.ndarray | None:
        """Frame indices (k,), each in 0..n-1, that ``key`` selects; None where h5py reads
        the key as it is (not a frame selection; all frames of a dataset not unpacked here).

        Raises
        ------
        IndexError
            Indices outside the dataset.
        """
        if self.ndim == 0:
            return None
        n = len(self)
        if isinstance(key, slice):
            return np.arange(*key.indices(n))
        if key is Ellipsis or (isinstance(key, tuple) and key == ()):
            return np.arange(n) if self._nbit else None
        idx = None if isinstance(key, tuple) else np.asarray(key)
        if idx is None or idx.ndim > 1 or idx.dtype.kind not in "iu":
            return None
        idx = idx.reshape(-1)
        if idx.size and (idx.min() < -n or idx.max() >= n):
            raise IndexError(f"frame index out of range for {n} frames")
        return idx % n

    def _read(self, idx: np.ndarray) -> np.ndarray:
        """Frames ``idx`` (k,), each in 0..n-1, of an N-bit dataset as a (k, *frame shape) array."""
        out = np.empty((idx.size, *self.shape[1:]), self.dtype)
        pixels = int(np.prod(self.shape[1:]))
        flat = out.reshape(idx.size, pixels)
        zeros = (0,) * (self.ndim - 1)
        for k, i in enumerate(idx.tolist()):
            mask, chunk = self._ds.id.read_direct_chunk((i, *zeros))
            if mask:                      # the optional filter was skipped: not packed
                out[k] = self._ds[i]
            else:
                unpack_nbit12(chunk, pixels, out=flat[k])
        return out


def _lock_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.lock")


def _leftover_tmp_files(path: Path) -> list[Path]:
    return sorted(path.parent.glob(f"{path.name}{_TMP_MARK}*"))


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _open_h5(path: Path, mode: str) -> h5py.File:
    if path.exists() and not path.is_file():  # a FIFO would block the open; a directory is no store
        raise StoreFormatError("not a regular file, so not a store", path)
    try:
        return h5py.File(path, mode)
    except OSError as exc:
        raise StoreFormatError(f"cannot open as an HDF5 store ({exc})", path) from None


def _check_format(f: h5py.File, path: Path) -> None:
    if f.attrs.get("format") != layout.FORMAT_NAME:
        raise StoreFormatError("not a vfcli store (no 'format' attribute)", path)
    version = int(f.attrs.get("format_version", -1))
    if version > layout.FORMAT_VERSION:
        raise StoreFormatError(
            f"written by a newer vfcli (store format {version}, this vfcli reads up to "
            f"{layout.FORMAT_VERSION}); upgrade vfcli",
            path,
        )


@dataclass
class StageStatus:
    """What ``vfcli info`` shows of one stage."""

    path: str
    complete: bool
    provenance: dict[str, Any]
    size_bytes: int
    stale_because: list[str] = field(default_factory=list)

    @property
    def stale(self) -> bool:
        return bool(self.stale_because)

    def to_json(self) -> dict[str, Any]:
        prov = dict(self.provenance)
        for k in ("config_json", "inputs_json", "upstream_json"):
            if k in prov:
                prov[k.removesuffix("_json")] = json.loads(prov.pop(k))
        return {
            "path": self.path,
            "complete": self.complete,
            "stale": self.stale,
            "stale_because": self.stale_because,
            "size_bytes": self.size_bytes,
            "provenance": prov,
        }


def _group_size(g: h5py.Group) -> int:
    total = 0

    def visit(_name: str, obj: Any) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += obj.id.get_storage_size()

    g.visititems(visit)
    return total


class StoreReader:
    """Read-only view of a store (an open HDF5 file)."""

    def __init__(self, f: h5py.File, path: Path) -> None:
        self._f = f
        self.path = path

    # -- stages -----------------------------------------------------------
    def stage_paths(self) -> list[str]:
        """Paths of every stage group present (``/hsc``, ``/optimize/run1`` ...)."""
        out = []
        for name, st in layout.STAGES.items():
            if name not in self._f:
                continue
            if st.has_runs:
                out.extend(f"/{name}/{run}" for run in self._f[name])
            else:
                out.append(f"/{name}")
        return out

    def has_stage(self, name: str, run: str | None = None, complete: bool = True) -> bool:
        path = layout.stage(name).group_path(run)
        if path not in self._f:
            return False
        return bool(self._f[path].attrs.get("complete", False)) or not complete

    def group(self, name: str, run: str | None = None) -> h5py.Group:
        """The stage group; :class:`MissingStageError` when it is absent or incomplete."""
        st = layout.stage(name)
        if not self.has_stage(name, run):
            raise MissingStageError(
                f"stage {st.group_path(run) if (run or not st.has_runs) else '/' + name} is missing; "
                f"run `vfcli {st.written_by}` first",
                self.path,
            )
        return self._f[st.group_path(run)]

    def read(self, name: str, key: str, run: str | None = None) -> np.ndarray:
        """A whole dataset as a numpy array (text datasets as ``str``)."""
        ds = self.dataset(name, key, run)
        if h5py.check_string_dtype(ds.dtype):
            return ds.asstr()[()]
        return FrameReader(ds)[()]

    def frames(self, name: str, key: str, run: str | None = None) -> FrameReader:
        """A per-frame dataset, lazily, for reading frames by index (:class:`FrameReader`)."""
        return FrameReader(self.dataset(name, key, run))

    def dataset(self, name: str, key: str, run: str | None = None) -> h5py.Dataset:
        """A dataset, lazily (for streaming frame by frame)."""
        g = self.group(name, run)
        path = layout.dataset_path(name, key, run)
        if path not in self._f:
            raise MissingStageError(f"{path} is missing from the stage", self.path)
        return g[key]

    def attrs(self, name: str, run: str | None = None) -> dict[str, Any]:
        return dict(self.group(name, run).attrs)

    def digest(self, name: str, run: str | None = None) -> str:
        return str(self.group(name, run).attrs["digest"])

    def root_attrs(self) -> dict[str, Any]:
        """The store's own attributes (format, version, creation time ...)."""
        return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in self._f.attrs.items()}

    def recording_config_json(self) -> str | None:
        v = self._f.attrs.get(layout.ROOT_CONFIG_ATTR)
        return None if v is None else str(v)

    # -- provenance checks ---------------------------------------------------
    def status(self, path: str) -> StageStatus:
        g = self._f[path]
        prov = {k: g.attrs[k] for k in layout.PROVENANCE_ATTRS if k in g.attrs}
        prov = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in prov.items()}
        stale = []
        for up_path, up_digest in json.loads(prov.get("upstream_json", "{}")).items():
            if up_path not in self._f:
                stale.append(f"{up_path} is gone")
            elif str(self._f[up_path].attrs.get("digest")) != up_digest:
                stale.append(f"{up_path} was rewritten")
        return StageStatus(path, bool(g.attrs.get("complete", False)), prov, _group_size(g), stale)

    def is_current(
        self,
        name: str,
        config_json: str,
        inputs: Mapping[str, Mapping[str, Any]] | None = None,
        upstream: list[tuple[str, str | None]] | None = None,
        run: str | None = None,
    ) -> bool:
        """True when the stage exists, is complete, and its config, inputs and upstream are unchanged."""
        if not self.has_stage(name, run):
            return False
        st = self.status(layout.stage(name).group_path(run))
        if st.stale or st.provenance.get("config_json") != config_json:
            return False
        if inputs is not None and not same_inputs(json.loads(st.provenance["inputs_json"]), inputs):
            return False
        recorded = json.loads(st.provenance.get("upstream_json", "{}"))
        wanted = self.upstream_digests(upstream or [])
        return recorded == wanted

    def previous_inputs(self, name: str, run: str | None = None) -> dict[str, Any]:
        if not self.has_stage(name, run):
            return {}
        return json.loads(self.group(name, run).attrs.get("inputs_json", "{}"))

    def upstream_digests(self, upstream: list[tuple[str, str | None]]) -> dict[str, str]:
        """``{group path: digest}`` of the upstream stages ``[(name, run), ...]`` (must be present)."""
        return {layout.stage(n).group_path(r): self.digest(n, r) for n, r in upstream}


class StageWriter:
    """Writes the datasets of one stage inside an open write transaction."""

    def __init__(self, group: h5py.Group, stage: layout.Stage) -> None:
        self._g = group
        self._stage = stage

    def _spec(self, key: str) -> layout.Dataset | None:
        if self._stage.datasets:
            if key not in self._stage.datasets:
                raise KeyError(f"stage {self._stage.name!r} declares no dataset {key!r} (see vfcli/store/layout.py)")
            return self._stage.datasets[key]
        return None

    def _decorate(self, ds: h5py.Dataset, key: str, units: str | None, description: str | None) -> None:
        spec = self._spec(key)
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
            ds = _nbit_dataset(self._g, key, shape, dtype, chunks, bits)
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

    def attach_scales(self) -> None:
        """Attach every axis named after a dataset of this stage as an HDF5 dimension scale."""
        if not self._stage.datasets:
            return
        for key, spec in self._stage.datasets.items():
            if key not in self._g:
                continue
            ds = self._g[key]
            for axis, dim in enumerate(spec.dims[: ds.ndim]):
                ds.dims[axis].label = dim
                if dim != key and dim in self._g and self._g[dim].ndim == 1 and self._g[dim].shape[0] == ds.shape[axis]:
                    scale = self._g[dim]
                    if not scale.is_scale:
                        scale.make_scale(dim)
                    ds.dims[axis].attach_scale(scale)


class StoreWriter:
    """A write transaction on a store copy; committed by an atomic rename."""

    def __init__(self, f: h5py.File, path: Path, command: str) -> None:
        self._f = f
        self.path = path
        self.command = command
        self.reader = StoreReader(f, path)

    def set_recording_config(self, config_json: str) -> None:
        self._f.attrs[layout.ROOT_CONFIG_ATTR] = config_json

    @contextmanager
    def stage(
        self,
        name: str,
        *,
        config_json: str,
        inputs: Mapping[str, Mapping[str, Any]] | Callable[[], Mapping[str, Mapping[str, Any]]] | None = None,
        upstream: list[tuple[str, str | None]] | None = None,
        run: str | None = None,
    ) -> Iterator[StageWriter]:
        """Replace stage ``name`` (and ``run``) with what the block writes.

        The provenance is recorded when the block ends without an exception; a block that
        raises aborts the whole transaction (nothing reaches the store file). ``inputs``
        may be a function returning them, called when the block has ended (so the raw
        files can be hashed while the block reads them).
        """
        st = layout.stage(name)
        path = st.group_path(run)
        upstream_digests = self.reader.upstream_digests(upstream or [])
        if path in self._f:
            del self._f[path]
        g = self._f.require_group(path)
        g.attrs["complete"] = False
        writer = StageWriter(g, st)
        yield writer
        writer.attach_scales()
        if callable(inputs):
            inputs = inputs()
        record = {
            "stage": path,
            "vfcli_version": __version__,
            "command": self.command,
            "created_utc": _now(),
            "config_json": config_json,
            "inputs_json": json.dumps(dict(inputs or {}), sort_keys=True),
            "upstream_json": json.dumps(upstream_digests, sort_keys=True),
        }
        record["digest"] = stage_digest({**record, "nonce": secrets.token_hex(8)})
        for k, v in record.items():
            g.attrs[k] = v
        g.attrs["complete"] = True


class Store:
    """A recording's store file.

    >>> store = Store("rec.h5")                                   # doctest: +SKIP
    >>> with store.write("vfcli mesh rec.h5") as w:               # doctest: +SKIP
    ...     with w.stage("mesh", config_json=cfg.model_dump_json()) as s:
    ...         s.put("nodes", nodes)
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def exists(self) -> bool:
        return self.path.exists()

    @contextmanager
    def read(self) -> Iterator[StoreReader]:
        """Open read-only; :class:`StoreFormatError` if it is not a vfcli store."""
        if not self.path.exists():
            raise ConfigError("no such store file; the first writing command creates it", self.path)
        f = _open_h5(self.path, "r")
        try:
            _check_format(f, self.path)
            yield StoreReader(f, self.path)
        finally:
            f.close()

    def interrupted_writes(self) -> list[Path]:
        """Leftovers of writers that died (cleaned up by the next writer)."""
        return _leftover_tmp_files(self.path)

    @contextmanager
    def _lock(self) -> Iterator[None]:
        try:  # a read-only folder, an unwritable lock file, a lock path that is a directory
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if not os.access(self.path.parent, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, "folder not writable", str(self.path.parent))
            fd = os.open(_lock_path(self.path), os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise StoreAccessError(f"cannot write the store: {exc.strerror or exc}: {exc.filename}", self.path) from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise StoreLockedError(
                        "another vfcli process is writing this store; try again when it has finished",
                        self.path,
                    ) from None
                raise
            yield
        finally:
            os.close(fd)

    @contextmanager
    def write(self, command: str) -> Iterator[StoreWriter]:
        """An exclusive write transaction: all of it reaches the store, or none of it."""
        with self._lock():
            for leftover in _leftover_tmp_files(self.path):
                leftover.unlink(missing_ok=True)
            tmp = self.path.with_name(f"{self.path.name}{_TMP_MARK}{os.getpid()}")
            if self.path.exists():
                with self.read():  # refuses files that are not vfcli stores
                    pass
                shutil.copyfile(self.path, tmp)
                f = _open_h5(tmp, "r+")
            else:
                f = h5py.File(tmp, "w", fs_strategy="fsm", fs_persist=True, libver=("v110", "latest"))
                f.attrs["format"] = layout.FORMAT_NAME
                f.attrs["format_version"] = layout.FORMAT_VERSION
                f.attrs["created_utc"] = _now()
                f.attrs["generated_by"] = f"vfcli {__version__}"
            try:
                yield StoreWriter(f, self.path, command)
                f.flush()
                f.close()
                with open(tmp, "rb+") as fh:
                    os.fsync(fh.fileno())
                os.replace(tmp, self.path)
                dfd = os.open(self.path.parent, os.O_RDONLY)
                try:
                    os.fsync(dfd)
                finally:
                    os.close(dfd)
            except BaseException:
                try:
                    f.close()
                finally:
                    tmp.unlink(missing_ok=True)
                raise


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
    """Create ``truth.h5`` (overwrites)."""
    f = h5py.File(path, "w", libver=("v110", "latest"))
    try:
        f.attrs["format"] = "vfcli-phantom-truth"
        f.attrs["generated_by"] = f"vfcli {__version__}"
        yield TruthWriter(f)
    finally:
        f.close()


def read_truth(path: str | Path, keys: list[str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """(datasets, root attributes) of a phantom's ``truth.h5`` (tests and benchmarks only)."""
    with h5py.File(path, "r") as f:
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
        wanted = keys if keys is not None else [k for k in layout.TRUTH if k in f]
        return {k: f[k][()] for k in wanted}, attrs
