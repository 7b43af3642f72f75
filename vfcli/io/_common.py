"""Small helpers shared by the raw-file readers and writers of :mod:`vfcli.io`."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vfcli.errors import InputDataError


def require_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a Path if it is an existing, non-empty regular file.

    Raises
    ------
    InputDataError
        If the file is missing, not a regular file (a directory, a FIFO: never opened, so
        never waited on), empty (0 bytes) or not readable (permissions).
    """
    p = Path(path)
    if not p.exists():
        raise InputDataError(f"{what} not found", p)
    if not p.is_file():
        raise InputDataError(f"{what} is not a regular file", p)
    if p.stat().st_size == 0:
        raise InputDataError(f"{what} is empty (0 bytes)", p)
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:  # PermissionError and the like: the reader would fail later
        raise InputDataError(f"{what} cannot be read: {exc.strerror or exc}", p) from None
    return p


def natural_key(name: str) -> list:
    """Sort key that orders embedded numbers numerically (``f2`` before ``f10``)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def check_finite(values: np.ndarray, path: str | Path, what: str) -> None:
    """Raise InputDataError naming the first non-finite sample of ``values``."""
    bad = ~np.isfinite(values)
    if bad.any():
        idx = np.unravel_index(int(np.argmax(bad)), values.shape)
        raise InputDataError(
            f"{what} has {int(bad.sum())} NaN/Inf sample(s); first at index "
            f"{tuple(int(i) for i in idx)}",
            path,
        )
