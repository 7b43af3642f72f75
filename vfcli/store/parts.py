"""Part files: the stages of a store that grow with the recording, each in its own HDF5 file beside the store.

A store is its file ``<dir>/<name>`` plus the folder ``<dir>/<name>.parts/``. The store
file (the *index*) holds the root attributes (format, recording config), /mesh (small) and
one HDF5 external link per other stage (:data:`PART_STAGES`: /hsc, /ldv, /sync, /flow,
/fields and each run of /optimize and /diagnose) to the group of the same
path in its part file ``<name>.parts/<stage>-<16 hex>.h5``. h5py, h5netcdf/xarray, HDFView
and MATLAB follow the links transparently while the folder is beside the file.

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
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import h5py
from h5py import h5f, h5p

from vfcli.errors import StoreSpaceError
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


def new_part_name(store: Path, group_path: str) -> str:
    """Link target (relative to the store's folder) of a new part file for stage group
    ``group_path`` ("/hsc", "/optimize/run1"): ``<name>.parts/<stage>[-<run>]-<16 hex>.h5``."""
    stem = "-".join(_SAFE.sub("_", p) for p in group_path.strip("/").split("/"))
    return f"{parts_dir(store).name}/{stem}-{secrets.token_hex(8)}.h5"


def is_part_stage(name: str) -> bool:
    return name in PART_STAGES


def referenced_parts(f: h5py.File) -> set[str]:
    """Link targets (file names relative to the store's folder) of the external links in the
    index ``f``: the stages' and, in a group of runs (/optimize, /diagnose), the runs'."""
    out: set[str] = set()
    for key in f:
        link = f.get(key, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            out.add(link.filename)
        elif key in PART_STAGES and isinstance(link, h5py.HardLink):
            runs = f[key]
            for run in runs:
                sub = runs.get(run, getlink=True)
                if isinstance(sub, h5py.ExternalLink):
                    out.add(sub.filename)
    return out


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


def collect_garbage(store: Path, keep: set[str]) -> list[Path]:
    """Delete the part files of ``store`` that ``keep`` (link targets, as
    :func:`referenced_parts` gives them) does not name, unless a reader holds the store open
    (then nothing is deleted: the next writer tries again). Call under the write lock.
    Returns the deleted files."""
    parts = own_parts(store)
    if not parts:
        return []
    fd = os.open(_lock_file(store), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return []
            raise
        keep_names = {Path(k).name for k in keep if Path(k).parent.name == parts_dir(store).name}
        gone = [p for p in parts if p.name not in keep_names]
        for p in gone:
            p.unlink(missing_ok=True)
        return gone
    finally:
        os.close(fd)


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


def no_room_error(store: Path, needed_bytes: int) -> StoreSpaceError:
    """The one-line error of a write that ran out of space: about how much it needs, how much
    is free."""
    free = shutil.disk_usage(store.parent).free
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    room = (f"{_mb(free)} free in {store.parent}" if limit == resource.RLIM_INFINITY else
            f"the process's file-size limit (ulimit -f) is {_mb(limit)}")
    return StoreSpaceError(
        f"not enough disk space for this write: it needs at least {_mb(needed_bytes)}, {room}; "
        "free some space and run the command again (the store is unchanged and the temporary data are removed)",
        store)


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
        groups = [f] + [f[k] for k in f if k in PART_STAGES and isinstance(f.get(k, getlink=True), h5py.HardLink)]
        for g in groups:
            for key in list(g):
                link = g.get(key, getlink=True)
                if isinstance(link, h5py.ExternalLink) and link.filename.startswith(old_folder + "/"):
                    del g[key]
                    g[key] = h5py.ExternalLink(new_folder + link.filename[len(old_folder):], link.path)


def holder(store: str | Path, group_path: str) -> Path:
    """The file that holds stage group ``group_path`` ("/hsc", "/optimize/run1"): its part file,
    or the store file for a small stage. netCDF readers (xarray's h5netcdf engine) resolve a
    dataset's dimension scales in the file they opened, so they open a stage here:
    ``xr.open_dataset(holder(store, "/hsc"), group="hsc", engine="h5netcdf")``."""
    real = Path(os.path.realpath(store))
    with h5py.File(real, "r") as f:
        link = f.get(group_path, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            return real.parent / link.filename
    return real


def missing_parts(f: h5py.File, store: Path) -> list[str]:
    """Link targets of the index ``f`` (of the store file at real path ``store``) whose part
    file is not there (a store file copied or renamed without its parts folder)."""
    return sorted(t for t in referenced_parts(f) if not (store.parent / t).is_file())
