"""Write transactions on a store: the lock, the atomic commit, and :class:`StageWriter`.

Crash safety
------------
A write never modifies a file a reader may have open. The writer takes an exclusive lock
(``flock`` on the sidecar ``.<name>.lock`` beside the real file, released by the kernel if
the process dies), writes each stage but /mesh into a new part file (:mod:`vfcli.store.parts`:
``<name>.parts/<stage>-<16 hex>.h5``, complete, flushed and fsynced), copies the store file
(the index: root attributes, /mesh and one external link per other stage; small) to
``.<name>.vfcli-<pid>-<8 hex>.tmp``, writes the small stages and links there, fsyncs it and
atomically renames it over the store. A process killed at any moment therefore leaves the
old index or the new one, never a half-written stage; a leftover temporary index or an
unlinked part file is the only trace and is removed by the next writer (``vfcli info``
reports it as an interrupted write). Ctrl-C, SIGTERM and a full disk abort the write the
same way, removing its temporary data at once. Readers open the store read-only and keep
the version they opened (:func:`vfcli.store.parts.reader_lock`). A write costs what it
writes plus one copy of the index, whatever the size of the store.

Video frames are written by :meth:`StageWriter.write_frames` (chunks encoded in threads,
:mod:`vfcli.store.frames`); provenance is recorded when a stage block ends
(:mod:`vfcli.store.provenance`, checked by :meth:`vfcli.store.reader.StoreReader.is_current`).
"""
from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import json
import os
import re
import secrets
import shutil
import stat
from collections import deque
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping

import h5py
import numpy as np

from vfcli import __version__
from vfcli.errors import ConfigError, StoreAccessError, StoreDamagedError, StoreLockedError, VfcliError
from vfcli.store import integrity, layout, locking, migrate, parts, signals
from vfcli.store.chunks import encode_frames
from vfcli.store.frames import CHUNK_CODECS, COMPRESSIONS, nbit_dataset
from vfcli.store.provenance import content_digest
from vfcli.store.reader import StoreReader, check_format, open_h5

if TYPE_CHECKING:
    from vfcli.io.video.base import FrameBatch

#: HDF5 format versions of what vfcli writes: v2 object headers, B-trees and heaps, all checksummed
#: (libhdf5 refuses a flipped byte in them instead of reading it).
_LIBVER = ("v110", "latest")
_COMPRESSION = COMPRESSIONS["gzip"]


def _jsonable(value: Any) -> Any:
    """``value`` (not a JSON type) as JSON can hold it: numpy scalars and arrays as numbers and lists."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    return str(value)


def _lock_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.lock")


def _leftover_tmp_files(path: Path) -> list[Path]:
    """The temporary index copies of writers of ``path`` that died: ``.<name>.vfcli-<pid>-<8 hex>.tmp``
    (and ``<name>.tmp-<pid>`` of earlier vfcli versions), matched exactly: a user's files are left alone."""
    pattern = re.compile(rf"^(?:\.{re.escape(path.name)}\.vfcli-\d+-[0-9a-f]{{8}}\.tmp|{re.escape(path.name)}\.tmp-\d+)$")
    try:
        return sorted(p for p in path.parent.iterdir() if pattern.match(p.name))
    except OSError:
        return []


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _raise_damage(exc: BaseException, path: Path) -> None:
    """Re-raise ``exc``, as :class:`StoreDamagedError` when libhdf5 raised it on a damaged file
    (exit 4, one line, instead of a traceback)."""
    why = integrity.h5py_damage(exc)
    if why is None:
        raise exc
    raise StoreDamagedError(f"damaged store: libhdf5 cannot read it ({why}); restore it from a copy", path) from None


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
            scale.attrs["units"] = "1" if ax.labels else "index"
            scale.attrs["description"] = ax.description
        scale = self._g[dim]
        if not isinstance(scale, h5py.Dataset) or scale.ndim != 1 or scale.shape[0] != n:
            return None
        if not scale.is_scale:
            scale.make_scale(dim)
        return scale


class StoreWriter:
    """A write transaction on a copy of the store's index (and new part files for the large
    stages, :mod:`vfcli.store.parts`); committed by an atomic rename of the index."""

    def __init__(self, f: h5py.File, path: Path, command: str, real: Path | None = None,
                 mode: int | None = None) -> None:
        self._f = f
        self.path = path
        self.command = command
        self.reader = StoreReader(f, path)
        self._real = real or path
        self._mode = mode  # the store file's permission bits, given to its new part files
        self._new_parts: list[Path] = []  # written by this transaction: removed if it aborts

    @property
    def new_parts(self) -> list[Path]:
        """The part files this transaction wrote (removed if it aborts)."""
        return list(self._new_parts)

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
        self.reader.refuse_damaged(keep=path)  # never carry a damaged stage forward
        part: h5py.File | None = None
        if parts.is_part_stage(st.name):  # a new part file, linked when complete
            target = parts.new_part_name(self._real, path)
            part_path = self._real.parent / target
            part_path.parent.mkdir(exist_ok=True)
            self._new_parts.append(part_path)
            part = h5py.File(part_path, "w", libver=_LIBVER)
            if self._mode is not None:
                os.chmod(part_path, self._mode)
            g = part.require_group(path)
        else:
            if self._f.get(path, getlink=True) is not None:
                del self._f[path]
            g = self._f.require_group(path)
        try:
            g.attrs["complete"] = False
            writer = StageWriter(g, st)
            yield writer
            writer.attach_scales()
            manifest = integrity.manifest(g)
            g.attrs[layout.MANIFEST_ATTR] = manifest
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
            hashed = {k: v["sha256"] for k, v in json.loads(manifest)["datasets"].items()}
            record["digest"] = content_digest(g, hashed)   # the chunks hashed once, for the manifest
            for k, v in record.items():
                g.attrs[k] = v
            g.attrs["complete"] = True
            if part is not None:
                part.flush()
                part.close()
                parts.fsync_path(part_path)
                if self._f.get(path, getlink=True) is not None:
                    del self._f[path]
                self._f[path] = h5py.ExternalLink(target, path)
        finally:
            if part is not None and part.id.valid:
                part.close()
        self.reader.forget(path)


class Store:
    """A recording's store: its file (the index) and its parts folder (:mod:`vfcli.store.parts`).

    A symlinked store stays a symlink: vfcli writes, locks and keeps the parts beside the
    link's target (``real_path``), so the link and its target share one lock.

    >>> store = Store("rec.h5")                                   # doctest: +SKIP
    >>> with store.write("vfcli mesh rec.h5") as w:               # doctest: +SKIP
    ...     with w.stage("mesh", config_json=cfg.model_dump_json()) as s:
    ...         s.put("nodes", nodes)
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @property
    def real_path(self) -> Path:
        """The store file a symlink points to (the path itself otherwise)."""
        return Path(os.path.realpath(self.path))

    def exists(self) -> bool:
        return self.path.exists()

    @contextmanager
    def read(self) -> Iterator[StoreReader]:
        """Open read-only; :class:`StoreFormatError` if it is not a vfcli store. The version
        opened stays readable until the block ends (no writer deletes its part files)."""
        if not self.path.exists():
            raise ConfigError("no such store file; the first writing command creates it", self.path)
        real = self.real_path
        with parts.reader_lock(real):
            f = open_h5(real, "r")
            try:
                check_format(f, self.path)
                _refuse_missing_parts(f, real, self.path)
                yield StoreReader(f, self.path)
            except integrity.H5_ERRORS as exc:
                _raise_damage(exc, self.path)
            finally:
                f.close()

    def interrupted_writes(self) -> list[Path]:
        """Leftovers of writers that died (cleaned up by the next writer): temporary index
        copies, and part files the index does not link to."""
        real = self.real_path
        found = _leftover_tmp_files(real)
        own = parts.own_parts(real)
        if own:
            try:
                f = open_h5(real, "r")
            except VfcliError:
                return found
            try:
                linked = {Path(t).name for t in parts.referenced_parts(f)}
            finally:
                f.close()
            found += [p for p in own if p.name not in linked]
        return found

    def writer_active(self) -> bool:
        """Whether a live process holds the write lock now (its temporary file is work in
        progress, not the leftover of an interrupted write). Probes with a shared lock,
        released at once."""
        try:
            fd = os.open(_lock_path(self.real_path), os.O_RDONLY)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            fcntl.flock(fd, fcntl.LOCK_UN)
            return False
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return True
            if locking.lock_unsupported(exc):
                return False  # no locks on this file system: no writer can be seen (the write says so)
            raise
        finally:
            os.close(fd)

    @contextmanager
    def _lock(self) -> Iterator[None]:
        path = self.real_path  # a symlink and its target take the same lock
        try:  # a read-only folder, an unwritable lock file, a lock path that is a directory
            path.parent.mkdir(parents=True, exist_ok=True)
            if not os.access(path.parent, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, "folder not writable", str(path.parent))
            fd = os.open(_lock_path(path), os.O_RDWR | os.O_CREAT, 0o644)
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
                if locking.lock_unsupported(exc):  # NFS/Lustre without locks (errno 37, 524)
                    raise locking.flock_unsupported_error(exc.errno, self.path) from None
                raise
            yield
        finally:
            os.close(fd)

    def _writable_mode(self, real: Path) -> int:
        """The store file's permission bits; :class:`StoreAccessError` when it is read-only
        (vfcli does not replace a file its owner protected)."""
        mode = stat.S_IMODE(os.stat(real).st_mode)
        if not mode & stat.S_IWUSR or not os.access(real, os.W_OK):
            raise StoreAccessError(f"the store file is read-only (mode {mode:04o}); vfcli does not replace it: "
                                   "make it writable (chmod u+w) to write to it", self.path)
        return mode

    @contextmanager
    def write(self, command: str) -> Iterator[StoreWriter]:
        """An exclusive write transaction: all of it reaches the store, or none of it.

        Costs what it writes: the stages (but /mesh) go to new part files, and only the store's
        index (small) is copied, then renamed over the store (the commit). On an abort (an
        exception, Ctrl-C, SIGTERM, a full disk) the temporary copy and the new part files
        are removed and the store is unchanged; a full disk is :class:`StoreSpaceError`."""
        real = self.real_path
        with self._lock(), signals.abort_on_sigterm():
            for leftover in _leftover_tmp_files(real):
                leftover.unlink(missing_ok=True)
            tmp = real.with_name(f".{real.name}.vfcli-{os.getpid()}-{secrets.token_hex(4)}.tmp")
            f: h5py.File | None = None
            w: StoreWriter | None = None
            moved: list[Path] = []  # stages of an earlier vfcli's store moved to part files
            committed = False
            try:
                if real.exists():
                    with self.read():  # refuses files that are not vfcli stores
                        pass
                    mode: int | None = self._writable_mode(real)
                    parts.check_room(real, real.stat().st_size + _ROOM_MARGIN)
                    shutil.copyfile(real, tmp)
                    os.chmod(tmp, mode)
                    f = open_h5(tmp, "r+", libver=_LIBVER)  # new objects get checksummed (v2) object headers
                    parts.collect_garbage(real, parts.referenced_parts(f))  # parts of killed writers
                    migrate.move_inline_stages(f, real, mode, moved)  # a store of an earlier vfcli
                else:
                    mode = None
                    f = h5py.File(tmp, "w", fs_strategy="fsm", fs_persist=True, libver=_LIBVER)
                    f.attrs["format"] = layout.FORMAT_NAME
                    f.attrs["format_version"] = layout.FORMAT_VERSION
                    f.attrs["created_utc"] = _now()
                    f.attrs["generated_by"] = f"vfcli {__version__}"
                w = StoreWriter(f, self.path, command, real, mode)
                w._new_parts += moved
                yield w
                linked = parts.referenced_parts(f)
                if migrate.needs_compaction(f):  # HDF5 does not shrink a file: write it anew
                    tmp = _compacted(f, tmp, mode)
                f.close()
                parts.fsync_path(tmp)
                if w.new_parts:
                    parts.fsync_path(parts.parts_dir(real))
                with signals.deferred():
                    os.replace(tmp, real)
                    committed = True
                parts.fsync_path(real.parent)
                parts.collect_garbage(real, linked)  # the parts of the stages this write replaced
            except BaseException as exc:
                if not committed:
                    written = _abort(f, tmp, w.new_parts if w else moved)
                    if parts.is_no_room(exc):
                        raise parts.no_room_error(self.path, written) from None
                _raise_damage(exc, self.path)


def _refuse_missing_parts(f: h5py.File, real: Path, path: Path) -> None:
    """:class:`StoreDamagedError` naming the first part file the index links to that is not there."""
    missing = parts.missing_parts(f, real)
    if missing:
        raise StoreDamagedError(
            f"damaged store: its part file {missing[0]} is missing ({len(missing)} in all); a store is its file "
            f"plus its folder {parts.parts_dir(real).name}: copy or move both and keep their names "
            "(`vfcli share` makes one self-contained file)", path)


#: Free space asked beyond the index's size before copying it (its growth by a small stage).
_ROOM_MARGIN = 4 << 20


def _compacted(f: h5py.File, tmp: Path, mode: int | None) -> Path:
    """A compact copy of the temporary store file ``f`` (at ``tmp``, then removed); its path."""
    compact = tmp.with_name(f"{tmp.name.rsplit('-', 1)[0]}-{secrets.token_hex(4)}.tmp")
    try:
        migrate.compact_copy(f, compact)
        if mode is not None:
            os.chmod(compact, mode)
    except BaseException:
        compact.unlink(missing_ok=True)
        raise
    f.close()
    tmp.unlink()
    return compact


def _abort(f: h5py.File | None, tmp: Path, new_parts: list[Path]) -> int:
    """Remove what an aborted write made (its index copy and new part files); returns their
    size in bytes (what the write needed at least)."""
    if f is not None:
        try:
            f.close()
        except integrity.H5_ERRORS:
            pass  # a damaged copy may not close cleanly; it is deleted
    written = 0
    for p in (tmp, *new_parts):
        try:
            written += p.stat().st_size
        except OSError:
            pass
        p.unlink(missing_ok=True)
    return written
