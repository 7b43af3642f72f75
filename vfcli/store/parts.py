"""Part files: the stages of a store that grow with the recording, each in its own HDF5 file beside the store.

A store is its file ``<dir>/<name>`` plus the folder ``<dir>/<name>.parts/``. The store
file (the *index*) holds the root attributes (format, recording config), /mesh (small) and
one HDF5 external link per other stage (:data:`PART_STAGES`: /hsc, /ldv, /sync, /flow,
/fields and each run of /optimize and /diagnose) to the group of the same
path in its part file ``<name>.parts/<stage>-<16 hex>.h5``. h5py, HDFView, MATLAB and
netCDF-C (xarray's netcdf4 engine) follow the links transparently while the folder is beside
the file; xarray's h5netcdf engine opens a group through :func:`vfcli.store.open_dataset`.

A commit (:meth:`vfcli.store.transaction.Store.write`) writes each such stage into a NEW
part file, complete, flushed and fsynced, then copies the (small) index, points its links at
the new parts and renames it over the store: the rename is the commit, so a write costs what
it writes plus one copy of the index. Part files are never modified once written. Part files
no index references (the stages a commit replaced, or the parts of a killed writer) are
deleted by the next writer under the lock, unless a reader holds the store open
(:func:`reader_lock`): a reader keeps the version it opened.

Only this module spells the part file names.
"""
from __future__ import annotations

import errno
import fcntl
import os
import re
import resource
import secrets
import shutil
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Iterator

import h5py
from h5py import h5f, h5p

from vfcli.errors import StoreDamagedError, StoreFormatError, StoreSpaceError
from vfcli.store.layout import PART_STAGES


_PART_RE = re.compile(r"^[a-z_]+(?:-[A-Za-z0-9_.]+)?-[0-9a-f]{16}\.h5$")
_SAFE = re.compile(r"[^A-Za-z0-9_.]")


def _readonly_external_links() -> None:
    """Make h5py open every external link's target read-only, whatever the mode of the file
    the link is in. libhdf5 otherwise opens it with the parent's intent: a writer's index
    opened ``r+`` would open the committed part files for writing (refused while a reader
    holds them; on a v3 superblock it even marks them open for writing). vfcli never writes
    through a link (it writes a new part file directly), so this is vfcli-wide."""
    import h5py._hl.base as base

    lapl = h5p.create(h5p.LINK_ACCESS)
    lapl.set_elink_acc_flags(h5f.ACC_RDONLY)
    base.dlapl = lapl


_readonly_external_links()


def parts_dir(store: Path) -> Path:
    """The folder of the part files of ``store`` (its real path: a symlinked store's parts
    are beside the target)."""
    return store.with_name(store.name + ".parts")


def remove_if_empty(folder: Path) -> None:
    """Remove ``folder`` if it exists and is empty (an aborted first write's parts folder); else leave it."""
    try:
        folder.rmdir()
    except OSError:
        pass


def new_part_name(store: Path, group_path: str) -> str:
    """Link target (relative to the store's folder) of a new part file for stage group
    ``group_path`` ("/hsc", "/optimize/run1"): ``<name>.parts/<stage>[-<run>]-<16 hex>.h5``."""
    stem = "-".join(_SAFE.sub("_", p) for p in group_path.strip("/").split("/"))
    return f"{parts_dir(store).name}/{stem}-{secrets.token_hex(8)}.h5"


def is_part_stage(name: str) -> bool:
    return name in PART_STAGES


def _external_links(f: h5py.File) -> Iterator[tuple[h5py.Group, str, h5py.ExternalLink]]:
    """``(group, key, link)`` of each external link of the index ``f``: the stages' and, in a
    group of runs (/optimize, /diagnose), the runs'."""
    for key in list(f):
        link = f.get(key, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            yield f, key, link
        elif key in PART_STAGES and isinstance(link, h5py.HardLink):
            runs = f[key]
            for run in list(runs):
                sub = runs.get(run, getlink=True)
                if isinstance(sub, h5py.ExternalLink):
                    yield runs, run, sub


def referenced_parts(f: h5py.File) -> set[str]:
    """Link targets (file names relative to the store's folder) of the external links in the
    index ``f``: the stages' and, in a group of runs (/optimize, /diagnose), the runs'."""
    return {link.filename for _g, _k, link in _external_links(f)}


def own_parts(store: Path) -> list[Path]:
    """The files of the parts folder that vfcli names (others are left alone)."""
    d = parts_dir(store)
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if _PART_RE.match(p.name) and p.is_file())


def _lock_file(store: Path) -> Path:
    return store.with_name(f".{store.name}.readers")


@contextmanager
def reader_lock(store: Path) -> Iterator[None]:
    """A shared lock held while a reader has the store open, so that no writer deletes a part
    file the reader's version links to. A store whose folder is read-only, or that has no
    parts, needs none."""
    try:
        fd = os.open(_lock_file(store), os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH)
        except OSError:
            pass
        yield
    finally:
        os.close(fd)


def _sibling_references(store: Path) -> set[str]:
    """Names of the part files of ``store``'s folder that OTHER store files beside it link to
    (a hand copy ``cp rec.h5 rec2.h5`` links into ``rec.h5.parts/`` until its first write
    gives it its own parts, :func:`adopt_foreign_parts`). Files that are not readable vfcli
    indexes are skipped."""
    folder = parts_dir(store).name
    out: set[str] = set()
    try:
        siblings = [p for p in store.parent.iterdir() if p.suffix in _INDEX_SUFFIXES and p.name != store.name]
    except OSError:
        return out
    for p in siblings:
        try:
            if not p.is_file() or os.path.realpath(p) == str(store):
                continue
            with h5py.File(p, "r", locking=False) as f:
                if f.attrs.get("format") != "vfcli-store":
                    continue
                out |= {Path(t).name for t in referenced_parts(f) if Path(t).parent.name == folder}
        except (OSError, KeyError, ValueError, RuntimeError):
            continue
    return out


#: File name endings of the store files whose links :func:`collect_garbage` respects.
_INDEX_SUFFIXES = (".h5", ".hdf5", ".hdf", ".nc")


def unreferenced_parts(store: Path, keep: set[str]) -> list[Path]:
    """The part files of ``store`` that neither ``keep`` (link targets, as
    :func:`referenced_parts` gives them) nor another store file beside it links to."""
    own = own_parts(store)
    keep_names = {Path(k).name for k in keep if Path(k).parent.name == parts_dir(store).name}
    gone = [p for p in own if p.name not in keep_names]
    if gone:
        shared = _sibling_references(store)
        gone = [p for p in gone if p.name not in shared]
    return gone


@contextmanager
def foreign_reader_locks(f: h5py.File, store: Path) -> Iterator[None]:
    """:func:`reader_lock` on each other store whose parts folder (beside ``store``) the index
    ``f`` links to (a hand copy not yet written to): while it is held, that store's writers
    delete none of their part files, and the copy's first write (which gives it its own
    parts) leaves this reader's version readable."""
    folders = {Path(t).parent for t in referenced_parts(f)} - {Path(parts_dir(store).name)}
    with ExitStack() as stack:
        for folder in sorted(folders):
            if len(folder.parts) == 1 and folder.name.endswith(".parts"):
                stack.enter_context(reader_lock(store.parent / folder.name[: -len(".parts")]))
        yield


def collect_garbage(store: Path, keep: set[str]) -> list[Path]:
    """Delete the part files of ``store`` that ``keep`` (link targets, as
    :func:`referenced_parts` gives them) does not name and no other store file in the same
    folder links to (a hand copy of the store file), unless a reader holds the store open
    (then nothing is deleted: the next writer tries again). Call under the write lock.
    Returns the deleted files."""
    if not own_parts(store):
        return []
    fd = os.open(_lock_file(store), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return []
            raise
        gone = unreferenced_parts(store, keep)
        for p in gone:
            p.unlink(missing_ok=True)
        return gone
    finally:
        os.close(fd)


def adopt_foreign_parts(f: h5py.File, store: Path, written: list[Path]) -> None:
    """Give the store at real path ``store`` its own copy of every part file its (writable,
    temporary) index ``f`` links to in ANOTHER store's parts folder (the index was copied by
    hand, ``cp rec.h5 rec2.h5``), and point the links at them, so that neither store's later
    writes delete what the other uses. A hard link where the file system allows (no data
    copied; part files are never modified), else a copy. Appends each new file to
    ``written`` (removed if the write aborts). Links to missing files are left as they are."""
    own = parts_dir(store)
    for g, key, link in list(_external_links(f)):
        target = Path(link.filename)
        if target.parent.name == own.name and not target.is_absolute() and len(target.parts) == 2:
            continue
        src = store.parent / target
        if not src.is_file():
            continue
        own.mkdir(exist_ok=True)
        name = target.name if _PART_RE.match(target.name) else f"{target.stem}-{secrets.token_hex(8)}.h5"
        dst = own / name
        if dst.exists():
            dst = own / f"{target.name.rsplit('-', 1)[0]}-{secrets.token_hex(8)}.h5"
        written.append(dst)
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)
            fsync_path(dst)
        del g[key]
        g[key] = h5py.ExternalLink(f"{own.name}/{dst.name}", link.path)


def fsync_path(path: Path) -> None:
    """fsync a file or a folder (a rename or a new file in it is durable once the folder is)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# -- disk space ---------------------------------------------------------------------------------

#: errno values of a write that found no room: no space, file size limit, quota.
_NO_ROOM = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
_NO_ROOM_TEXT = ("no space left", "file too large", "disk quota exceeded",
                 *(f"errno = {e}," for e in _NO_ROOM))


def is_no_room(exc: BaseException) -> bool:
    """Whether ``exc`` is a write that failed for lack of space (an OSError with ENOSPC, EFBIG
    or EDQUOT, or libhdf5's error text carrying one of them)."""
    if isinstance(exc, OSError) and exc.errno in _NO_ROOM:
        return True
    text = str(exc).lower()
    return isinstance(exc, (OSError, RuntimeError, ValueError)) and any(t in text for t in _NO_ROOM_TEXT)


def _mb(n: float) -> str:
    return f"{n / 1e6:.1f} MB"


def no_room_error(store: Path, needed_bytes: int, free: int | None = None, what: str = "the store"
                  ) -> StoreSpaceError:
    """The one-line error of a write that ran out of space: about how much it needs, how much
    is free (``free``: measured before the write began, what is free again once the command
    has exited; the files of an aborted write may stay allocated until then, held open by
    libhdf5 through objects still alive; default: measured now).  ``what``: the thing the command
    left unchanged (e.g. synth's output folder)."""
    if free is None:
        free = shutil.disk_usage(store.parent).free
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    room = (f"{_mb(free)} free in {store.parent}" if limit == resource.RLIM_INFINITY else
            f"the process's file-size limit (ulimit -f) is {_mb(limit)}")
    return StoreSpaceError(
        f"not enough disk space for this write: it needs at least {_mb(needed_bytes)}, {room}; "
        f"free some space and run the command again ({what} is unchanged and the temporary data are removed)",
        store)


def close_discarding(f: h5py.File) -> None:
    """Close ``f``, a file being abandoned (the caller deletes it), even when libhdf5 cannot
    write what it still holds: a full disk or a file-size limit. libhdf5 keeps a file whose
    close failed open and tries to flush it again when the process exits, and crashes there
    (SIGSEGV, exit 139, after vfcli printed its error). Its file descriptor is pointed at
    /dev/null first, so the close writes nowhere and succeeds."""
    if not f.id.valid:
        return
    try:
        if f.driver != "sec2":  # only the default driver's handle is a POSIX file descriptor
            raise TypeError(f.driver)
        fd = f.id.get_vfd_handle()
        null = os.open(os.devnull, os.O_RDWR)
        try:
            os.dup2(null, fd)
        finally:
            os.close(null)
    except (OSError, TypeError, ValueError, RuntimeError):
        pass  # not a POSIX file descriptor (another driver): close as it is
    try:
        f.close()
    except (OSError, RuntimeError, ValueError):
        pass


@contextmanager
def writing(path: Path, **kwargs: object) -> Iterator[h5py.File]:
    """``h5py.File(path, "w", **kwargs)``, closed when the block ends; if the block or the close
    fails, closed with :func:`close_discarding` (the caller removes the file)."""
    f = h5py.File(path, "w", **kwargs)
    try:
        yield f
        f.close()
    finally:
        close_discarding(f)


def check_room(store: Path, needed_bytes: int) -> None:
    """:class:`StoreSpaceError` when the store's disk has less than ``needed_bytes`` free."""
    if shutil.disk_usage(store.parent).free < needed_bytes:
        raise no_room_error(store, needed_bytes)


# -- copies -------------------------------------------------------------------------------------

def copy_store(src: str | Path, dst: str | Path) -> Path:
    """Copy a store to a new path, parts folder included, its links renamed to the new
    folder (the copy keeps the layout: use :func:`vfcli.store.share.copy_for_sharing` for one
    self-contained file). ``dst`` must not exist; ``src`` is only read. Returns ``dst``.

    Raises
    ------
    FileExistsError
        ``dst`` or its parts folder exists.
    """
    src, dst = Path(os.path.realpath(src)), Path(dst)
    if dst.exists() or parts_dir(dst).exists():
        raise FileExistsError(f"{dst} exists")
    with reader_lock(src):
        if parts_dir(src).is_dir():
            shutil.copytree(parts_dir(src), parts_dir(dst), copy_function=shutil.copy2)
        shutil.copy2(src, dst)
    relink(dst, parts_dir(src).name)
    return dst


def relink(store: Path, old_folder: str) -> None:
    """Point the external links of ``store`` that name the parts folder ``old_folder`` at its
    own parts folder (after a copy or a rename of the file and its folder)."""
    new_folder = parts_dir(store).name
    if old_folder == new_folder:
        return
    with h5py.File(store, "r+") as f:
        for g, key, link in list(_external_links(f)):
            if link.filename.startswith(old_folder + "/"):
                del g[key]
                g[key] = h5py.ExternalLink(new_folder + link.filename[len(old_folder):], link.path)


def missing_parts(f: h5py.File, store: Path) -> list[str]:
    """Link targets of the index ``f`` (of the store file at real path ``store``) whose part
    file is not there (a store file copied or renamed without its parts folder)."""
    return sorted(t for t in referenced_parts(f) if not (store.parent / t).is_file())


def linked_files(store: Path) -> list[Path]:
    """The part files the store file at real path ``store`` links to (in its own parts folder,
    or, for a hand copy not yet written to, in the original's)."""
    with h5py.File(store, "r") as f:
        return sorted(store.parent / t for t in referenced_parts(f))


def refuse_missing(f: h5py.File, store: Path, shown: Path) -> None:
    """:class:`StoreFormatError` (exit 4, one line) when the index ``f`` of the store file at
    real path ``store`` (``shown`` as the user named it) links to part files that are not
    there: its whole parts folder (the file was copied or moved without it), or some of its
    files (:class:`StoreDamagedError`)."""
    missing = missing_parts(f, store)
    if not missing:
        return
    folders = sorted({Path(t).parent.as_posix() for t in missing})
    absent = [d for d in folders if not (store.parent / d).is_dir()]
    if absent:
        raise StoreFormatError(
            f"store {shown}'s stage data folder {absent[0]} is missing; copy the folder with the file, "
            "or use `vfcli share`")
    raise StoreDamagedError(
        f"damaged store: its part file {missing[0]} is missing ({len(missing)} in all); a store is its file "
        f"plus its folder {parts_dir(store).name}: copy or move both and keep their names "
        "(`vfcli share` makes one self-contained file)", shown)
