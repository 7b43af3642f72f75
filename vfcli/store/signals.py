"""Signals during a store write: SIGTERM aborts it like Ctrl-C, neither interrupts the commit's rename,
and both end a long call into C code at once.

Only the main thread installs handlers (Python runs signal handlers there); elsewhere these
are no-ops.
"""
from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager
from typing import Any, Iterator


class _Terminated(SystemExit):
    """SIGTERM inside a write: unwinds like Ctrl-C (the write is aborted and cleaned up), then
    the process exits 143 (128 + SIGTERM)."""


@contextmanager
def abort_on_sigterm() -> Iterator[None]:
    """SIGTERM raises :class:`_Terminated` while a write is open (SIGINT already raises
    KeyboardInterrupt), so that the write's cleanup runs; only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def terminate(signum: int, _frame: Any) -> None:
        print("vfcli: terminated (SIGTERM); the write was aborted, the store is unchanged", file=sys.stderr)
        raise _Terminated(128 + signum)

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def deferred() -> Iterator[None]:
    """SIGINT and SIGTERM held back while the commit's rename and its bookkeeping run: a signal
    that arrives meanwhile is delivered when the block ends (the write is then committed)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, _frame: pending.append(signum)) for s in sigs}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for s in dict.fromkeys(pending):
            signal.raise_signal(s)


@contextmanager
def killable() -> Iterator[None]:
    """SIGINT and SIGTERM kill the process at once (their default action) during a long call into C
    code that never returns to Python, where a Python handler would wait for it to end (tetgen ran
    12 min past a SIGTERM).  The store is then left as by ``kill -9``: unchanged, the temporary copy
    removed by the next writer.  Only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, signal.SIG_DFL) for s in sigs}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
