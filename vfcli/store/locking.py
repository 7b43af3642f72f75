"""File locks that a file system does not provide: detect them and say what to do.

vfcli keeps writers of a store apart with ``flock`` on the sidecar ``.<name>.lock``
(:mod:`vfcli.store.transaction`), and libhdf5 locks the HDF5 file itself when it opens it.
Many NFS mounts (no lock daemon, ``nolock``) and Lustre mounts (without ``-o flock``) refuse
both: the call fails at once with errno 37 (``ENOLCK``, "No locks available") or 524 (the
kernel's ``ENOTSUPP``), sometimes 95 (``EOPNOTSUPP``) or 38 (``ENOSYS``). vfcli never waits
on a lock (non-blocking calls only), so it cannot hang there; these functions turn the
failure into one line (:class:`LockUnsupportedError`, exit 4) instead of a traceback or a
misleading "store locked", before anything is written: the store stays as it was.

What to do is in the message: for libhdf5's own lock, ``HDF5_USE_FILE_LOCKING=FALSE``
(vfcli's lock file still keeps vfcli writers apart when ``flock`` works there); when
``flock`` itself fails, write the store on a node-local disk (``$TMPDIR``) and move the
finished store to the shared file system, or have the file system mounted with locks.
"""
from __future__ import annotations

import errno
import re
from pathlib import Path

from vfcli.errors import StoreAccessError

#: errno values meaning "this file system does not do locks" (not "someone holds the lock").
#: 524 is Linux's internal ENOTSUPP, which NFS and Lustre let reach user space.
UNSUPPORTED_ERRNOS = frozenset({errno.ENOLCK, 524, errno.EOPNOTSUPP, errno.ENOSYS})
_HDF5_ERRNO = re.compile(r"lock file, errno = (\d+)", re.IGNORECASE)


class LockUnsupportedError(StoreAccessError):
    """The file system of a store does not provide file locks (exit 4)."""


def lock_unsupported(exc: BaseException) -> int | None:
    """The errno when ``exc`` says the file system has no working locks (from ``flock``, or
    libhdf5's "unable to lock file, errno = 37" as h5py reports it), else None."""
    if isinstance(exc, OSError) and exc.errno in UNSUPPORTED_ERRNOS:
        return exc.errno
    m = _HDF5_ERRNO.search(str(exc))
    if m and int(m.group(1)) in UNSUPPORTED_ERRNOS:
        return int(m.group(1))
    return None


def _name(code: int) -> str:
    return {524: "ENOTSUPP"}.get(code) or errno.errorcode.get(code, str(code))


def flock_unsupported_error(code: int, path: Path) -> LockUnsupportedError:
    """The error for vfcli's own lock (``flock`` on the lock file) failing with ``code``."""
    return LockUnsupportedError(
        f"this file system gives no file locks (flock on {path.parent / ('.' + path.name + '.lock')} failed: "
        f"errno {code} {_name(code)}, as on NFS without a lock daemon or Lustre without -o flock), so vfcli cannot "
        "keep two writers apart; write the store on a node-local disk (e.g. $TMPDIR) and move the finished store "
        "here, or have the file system mounted with locks", path)


def hdf5_lock_unsupported_error(code: int, path: Path) -> LockUnsupportedError:
    """The error for libhdf5's own file lock failing with ``code`` when it opens ``path``."""
    return LockUnsupportedError(
        f"libhdf5 cannot lock the file on this file system (errno {code} {_name(code)}, as on NFS or Lustre); "
        "set HDF5_USE_FILE_LOCKING=FALSE in the environment (vfcli's own lock file then keeps vfcli writers "
        "apart, where flock works), or write the store on a node-local disk and move the finished store here", path)
