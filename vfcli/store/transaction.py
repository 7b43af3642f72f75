"""Write transactions on a store: the lock and the atomic commit (each stage group is written
by a :class:`vfcli.store.stage_writer.StageWriter`).

Crash safety
------------
A write never modifies a file a reader may have open. The writer takes an exclusive lock
(``flock`` on the sidecar ``.<name>.lock`` beside the real file, released by the kernel if
the process dies), writes each stage but /mesh into a new part file (:mod:`vfcli.store.parts`:
``<name>.parts/<stage>-<16 hex>.h5``, complete, flushed and fsynced), copies the store file
(the index: root attributes, /mesh and one external link per other stage; small) to
``.<name>.vfcli-<pid>-<8 hex>.tmp``, writes the small stages and links there, writes a fresh
compact copy of it (so the index does not grow from write to write), fsyncs that and
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
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import h5py

from vfcli import __version__
from vfcli.errors import ConfigError, StoreAccessError, StoreDamagedError, StoreLockedError, VfcliError
from vfcli.store import integrity, layout, locking, migrate, parts, signals
from vfcli.store.provenance import content_digest
from vfcli.store.reader import StoreReader, check_format, open_h5
from vfcli.store.stage_writer import StageWriter

#: HDF5 format versions of what vfcli writes: v2 object headers, B-trees and heaps, all checksummed
#: (libhdf5 refuses a flipped byte in them instead of reading it).
_LIBVER = ("v110", "latest")


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

    def set_recording_config(self, config_json: str, file_sha256: str | None = None) -> None:
        """Store the recording config; ``file_sha256``: the SHA-256 of the config file it was read from
        (None: not from a file now, the last file's hash is kept)."""
        self._f.attrs[layout.ROOT_CONFIG_ATTR] = config_json
        if file_sha256 is not None:
            self._f.attrs[layout.ROOT_CONFIG_FILE_ATTR] = file_sha256

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
            g.attrs[layout.METHOD_ATTR] = st.method
            g.attrs["complete"] = True
            if part is not None:
                part.flush()
                part.close()
                parts.fsync_path(part_path)
                if self._f.get(path, getlink=True) is not None:
                    del self._f[path]
                self._f[path] = h5py.ExternalLink(target, path)
        finally:
            if part is not None:  # abandoned (a failed block, a full disk): removed by the abort
                parts.close_discarding(part)
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
                parts.refuse_missing(f, real, self.path)
                with parts.foreign_reader_locks(f, real):
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
                linked = parts.referenced_parts(f)
            finally:
                f.close()
            found += parts.unreferenced_parts(real, linked)  # a hand copy's parts are not leftovers
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
            free_before = shutil.disk_usage(real.parent).free if real.parent.is_dir() else None
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
                    parts.adopt_foreign_parts(f, real, moved)  # a hand copy (cp rec.h5 rec2.h5): its own parts
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
                # a fresh compact index every time: HDF5 does not reuse all the space a rewritten
                # attribute or link frees, so an index edited in place grows ~4 kB per write
                f.flush()  # a full disk fails here, while the stages' datasets are still open
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
                    parts.remove_if_empty(parts.parts_dir(real))  # made for this write's parts only
                    if parts.is_no_room(exc):
                        raise parts.no_room_error(self.path, written, free_before) from None
                _raise_damage(exc, self.path)


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
    parts.close_discarding(f)  # copied: what it still holds is not needed (nor written on a full disk)
    tmp.unlink()
    return compact


def _abort(f: h5py.File | None, tmp: Path, new_parts: list[Path]) -> int:
    """Remove what an aborted write made (its index copy and new part files); returns their
    size in bytes (what the write needed at least)."""
    if f is not None:
        parts.close_discarding(f)  # a damaged or unwritable copy may not close cleanly; it is deleted
    written = 0
    for p in (tmp, *new_parts):
        try:
            written += p.stat().st_size
        except OSError:
            pass
        p.unlink(missing_ok=True)
    return written
