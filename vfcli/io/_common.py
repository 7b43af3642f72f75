"""Small helpers shared by the raw-file readers and writers of :mod:`vfcli.io`."""
from __future__ import annotations

import contextlib
import logging
import re
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
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


# --------------------------------------------------------------------------- what a library says

logger = logging.getLogger("vfcli.io")
_LIBRARY_LOGGERS = threading.RLock()   # one capture at a time changes the loggers (see library_output)


class LibraryOutput:
    """What a library said while it read a file: its Python warnings and its log records.

    ``entries`` holds ``(source, level, message)``: the source is the logger's name (``nptdms.reader``)
    or the warning's category (``UserWarning``), the level a :mod:`logging` level (WARNING for a Python
    warning).
    """

    def __init__(self) -> None:
        self.entries: list[tuple[str, int, str]] = []

    @property
    def messages(self) -> list[str]:
        """Every message, in the order said."""
        return [m for _, _, m in self.entries]

    def errors(self, prefix: str = "") -> list[str]:
        """The messages logged at ERROR or above that start with ``prefix``."""
        return [m for _, lvl, m in self.entries if lvl >= logging.ERROR and m.startswith(prefix)]


class _Collect(logging.Handler):
    def __init__(self, said: LibraryOutput) -> None:
        super().__init__(logging.WARNING)
        self.said = said

    def emit(self, record: logging.LogRecord) -> None:
        self.said.entries.append((record.name, record.levelno, record.getMessage()))


@contextlib.contextmanager
def library_output(path: str | Path, *loggers: str) -> Iterator[LibraryOutput]:
    """Collect, instead of printing, what a library says while it reads ``path``.

    Inside the block the Python warnings and the log records (WARNING and up) of the named loggers
    and their children (``"tifffile"``, ``"nptdms"``) are collected in the :class:`LibraryOutput`
    yielded; the loggers' own handlers (npTDMS prints with its own) and the root's see nothing. A
    reader that refuses the file raises its InputDataError inside the block, with the useful part of
    what was said folded into its one line; the rest is dropped. When the block ends without an
    exception, each distinct message is logged once as a vfcli warning naming the file (shown
    unless ``-q``). The library must be imported before the block (npTDMS adds its handlers then).
    """
    said = LibraryOutput()
    collect = _Collect(said)
    with _LIBRARY_LOGGERS, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")   # every time, also what was said before (-q ignores them)
        for dev in (DeprecationWarning, PendingDeprecationWarning):   # the developer's business
            warnings.simplefilter("ignore", dev)
        saved = []
        try:
            for name in loggers:
                top = logging.getLogger(name)
                family = [top] + [lg for key, lg in list(logging.root.manager.loggerDict.items())
                                  if key.startswith(name + ".") and isinstance(lg, logging.Logger)]
                for lg in family:
                    saved.append((lg, lg.handlers, lg.propagate, lg.level))
                    lg.handlers, lg.propagate = [], True
                top.handlers, top.propagate = [collect], False
                if not logging.NOTSET < top.level <= logging.WARNING:
                    top.setLevel(logging.WARNING)
            yield said
        finally:
            for lg, handlers, propagate, level in reversed(saved):
                lg.handlers, lg.propagate = handlers, propagate
                lg.setLevel(level)
            said.entries += [(w.category.__name__, logging.WARNING, str(w.message)) for w in caught]
    for source, message in dict.fromkeys((s, m) for s, _, m in said.entries):
        logger.warning("%s: %s: %s", Path(path).name, source, message)


# --------------------------------------------------------------------------- text tables

def shorten(text: str, n: int = 40) -> str:
    """``text`` cut to its first and last ``n // 2`` characters (joined by ``...``) when longer than ``n``."""
    return text if len(text) <= n else f"{text[: n // 2]}...{text[-(n // 2):]}"


def check_last_row_complete(text: str, path: str | Path) -> None:
    """Refuse a text table whose last line holds data but ends without a line break.

    A copy or download cut off inside a row leaves exactly that, and the cut row still reads as
    numbers: ``0.01976,14`` where the file had ``0.01976,1404.22`` (a wrong last value, stored
    silently). The writers of these files (numpy.savetxt, Python's csv module, spreadsheet exports)
    end every row with a line break; a complete file without one needs it added. A last line that
    is blank or a ``#`` comment is no data row and passes.
    """
    if not text or text.endswith(("\n", "\r")):
        return
    last = text[max(text.rfind("\n"), text.rfind("\r")) + 1:].strip()
    if last and not last.startswith("#"):
        raise InputDataError(f"the last row {shorten(last)!r} does not end with a line break: it may be cut off "
                             "(an interrupted copy or write); if the file is complete, add a line break at its end",
                             path)


def numeric_rows(rows: Sequence[tuple[int, str]], delimiter: str, path: str | Path,
                 names: Sequence[str] | None = None,
                 converters: dict[int, Callable[[str], float]] | None = None) -> np.ndarray:
    """The (rows, columns) float64 table of a text table's data rows, read with ``numpy.loadtxt``.

    ``rows`` are ``(line number in the file, 1-based, line)`` of the data rows (comments, blank
    lines and the header left out); ``names`` are the columns' names for messages; ``converters``
    map a column to a function of its text (raising ValueError with its own message).

    Raises
    ------
    InputDataError
        No rows; a row with another number of values than the first (naming its line and both
        counts); a value that is not a number (naming its line, column and value).
    """
    if not rows:
        raise InputDataError("CSV has no data rows", path)
    counts = [line.split("#", 1)[0].count(delimiter) + 1 for _, line in rows]
    bad = next((k for k, c in enumerate(counts) if c != counts[0]), None)
    if bad is not None:
        n = counts[bad]
        raise InputDataError(f"line {rows[bad][0]} has {n} value{'s' * (n != 1)}, the rows before it "
                             f"{counts[0]}", path)
    try:
        with library_output(path):
            return np.loadtxt((line for _, line in rows), delimiter=delimiter, converters=converters,
                              ndmin=2, dtype=np.float64)
    except ValueError as exc:
        numpy_says = str(exc).split("; use `usecols`")[0]
    for number, line in rows:
        for j, value in enumerate(line.split("#", 1)[0].split(delimiter)):
            try:
                (converters or {}).get(j, float)(value)
            except ValueError as exc:
                said = str(exc) if j in (converters or {}) else f"{shorten(value.strip())!r} is not a number"
                if re.fullmatch(r"\s*[-+]?\d+,\d*\s*", value):
                    said += " (a decimal comma: vfcli reads decimal points; export the file with '.' as the decimal " \
                            "separator)"
                column = f"column {j + 1}" + (f" ({names[j]!r})" if names and j < len(names) else "")
                raise InputDataError(f"line {number}, {column}: {said}", path) from None
    raise InputDataError(f"CSV data rows are not all numbers: {numpy_says}", path)
