"""A map over forked children of this process: the in-process map for pieces that share large state.

The diagnosis's larger pieces (its profile values, its shifted factorisations, the confirmation refits of its
leads) each use the run's baseline (half a GB on the demo recording) and read the open store, and spend most of
their time in small numpy calls that hold the GIL: in threads two refits ran 1.3 times faster than one after the
other, not twice (docs/diagnose.md, "Session 62"). A child forked when its piece starts sees this process's memory
as it is then, copy-on-write: nothing is pickled on the way in, and the piece runs on its own core. Only its result
travels back, pickled through a pipe, so a piece should return what the caller needs and no more; with it come the
log records the piece made, which the caller logs as its own, in the pieces' order (a stage stores its warnings).

POSIX only (``os.fork``); on Linux by default (:func:`vfcli.parallel.local_map`), where forking a process whose
only thread is the caller's is safe for numpy, scipy and h5py: the child reads the store through the inherited
file (``pread``) and ends with ``os._exit``, which closes no HDF5 file and flushes no buffer of the parent's.
"""
from __future__ import annotations

import logging
import os
import pickle
import selectors
import signal
import traceback
from typing import Any, Callable, Iterable, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

#: bytes read from a child's pipe at a time
CHUNK = 1 << 20

#: Longest wait, s, for a piece's output before the loop looks at its own signals again: a SIGINT that lands between
#: Python's last look at its signal flag and the ``select`` call sets the flag and wakes nothing, and an unbounded
#: ``select`` then waited for the pieces to end (minutes) before Ctrl-C took effect.
WAKE_S = 0.5


class RemoteTraceback(Exception):
    """The traceback of a piece's error in its child, as text: the cause of the error the caller sees (as
    :mod:`concurrent.futures.process` does)."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return self.text


class PieceDied(RuntimeError):
    """A child ended without a result: killed by a signal (the kernel's out-of-memory killer sends SIGKILL) or
    exited on its own."""


def _die_with_parent() -> None:
    """In a child: SIGINT and SIGTERM at their default action (the parent says what happened; the handlers a
    stage's write installs, which would print and unwind the write, are the parent's), and on Linux SIGKILL
    when the parent dies (``prctl(PR_SET_PDEATHSIG)``): a parent killed by ``kill -9`` or the out-of-memory killer
    leaves no piece running on."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))       # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class _Kept(logging.Handler):
    """The log records of a child, as (logger name, level, message), for its parent to log."""

    def __init__(self) -> None:
        super().__init__(logging.NOTSET)
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))


def _keep_records() -> _Kept:
    """In a child: every log record it makes (at the levels its loggers let through, the parent's) is kept instead of
    handled, so that the parent logs it: a warning then reaches the handlers the parent has, among them the capture
    that stores a stage's warnings with the stage (:func:`vfcli.stages.base.captured_warnings`), and is printed once."""
    kept = _Kept()
    loggers = [logging.getLogger()] + [lg for lg in logging.root.manager.loggerDict.values()
                                       if isinstance(lg, logging.Logger)]
    for lg in loggers:
        for h in list(lg.handlers):
            lg.removeHandler(h)
        lg.propagate = True
    logging.getLogger().addHandler(kept)
    return kept


def relog(records) -> None:
    """Log a child's records (:func:`_keep_records`) in this process, under their own loggers."""
    for name, level, message in records:
        logging.getLogger(name).log(level, "%s", message)


def _child(func: Callable[[Any], Any], item: Any, fd: int, parent: int) -> None:
    """Run one piece in the child and send ``(ok, result or error, traceback text, log records)``; never returns
    (``os._exit``: the stack it was forked from, a stage's write among it, is never unwound here)."""
    code = 0
    try:
        _die_with_parent()
        if os.getppid() != parent:                    # the parent died before the line above
            os._exit(71)
        kept = _keep_records()
        try:
            payload = pickle.dumps((True, func(item), "", kept.records), protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException as exc:  # noqa: BLE001 - the caller raises it
            text = "".join(traceback.format_exception(exc))
            try:
                payload = pickle.dumps((False, exc, text, kept.records), protocol=pickle.HIGHEST_PROTOCOL)
                pickle.loads(payload)
            except Exception:          # an error that does not travel: its words and traceback do
                payload = pickle.dumps((False, RuntimeError(f"{type(exc).__name__}: {exc}"), text, kept.records))
        view = memoryview(payload)
        while view:
            view = view[os.write(fd, view):]
    except BaseException:  # noqa: BLE001 - the parent sees no result and says so
        code = 70
    finally:
        os._exit(code)


#: a child's own memory, as a share of the caller's resident memory when it forks: measured 0.24-0.28 on the demo's
#: two refits (each child's private dirty pages 1.02 and 1.20 GB, the caller's resident set 4.2 GB at its peak;
#: docs/diagnose.md, "Session 62"), doubled for the pieces of a larger recording
CHILD_SHARE = 0.5


def _kb(path: str, key: str) -> float:
    """The value of ``key`` (kB) in a /proc file such as /proc/meminfo, or NaN where it cannot be read."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return float(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return float("nan")


def room_for_a_child(running: int = 0) -> bool:
    """Whether the machine's available memory (``MemAvailable``) holds one more child beside the ``running`` ones:
    :data:`CHILD_SHARE` of this process's resident memory (``VmRSS``) for each of them, the running ones included
    (a child just forked has not yet taken the memory it will).  True where Linux's /proc cannot be read (the limit
    is then --jobs)."""
    available, rss = _kb("/proc/meminfo", "MemAvailable"), _kb("/proc/self/status", "VmRSS")
    return not (available < CHILD_SHARE * rss * (running + 1))        # NaN: no figure, no limit


def _describe(status: int) -> str:
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        try:
            name = signal.Signals(sig).name
        except ValueError:          # a number Python names no signal for
            name = str(sig)
        hint = " (SIGKILL: the out-of-memory killer? try --jobs 1)" if sig == signal.SIGKILL else ""
        return f"killed by {name}{hint}"
    return f"exit status {os.WEXITSTATUS(status)}"


class ForkMap:
    """A :class:`vfcli.parallel.Mapper` over at most ``n`` children at once, each forked for one piece (module
    docstring); the results in the items' order, each as pickled and unpickled.  A child is forked beside the
    running ones only while ``room(n_running)`` says the memory holds it (default :func:`room_for_a_child`); the first
    always is.  The first error of a piece (in the items' order) is raised, its child's traceback its cause, once
    every piece has ended; a child that dies without a result raises :class:`PieceDied`.  When the caller is
    interrupted (Ctrl-C) or fails, the children still running are killed and reaped before the exception goes on."""

    def __init__(self, n: int, room: Callable[[int], bool] = room_for_a_child) -> None:
        self.n = int(n)
        self.room = room
        if self.n < 1:
            raise ValueError(f"ForkMap: need at least 1 process, got {n}")

    def __call__(self, func: Callable[[T], R], items: Iterable[T]) -> list[R]:
        todo = list(items)
        out: list[Any] = [None] * len(todo)
        errors: dict[int, BaseException] = {}
        running: dict[int, tuple[int, int, bytearray]] = {}        # fd -> (item, pid, bytes so far)
        sel = selectors.DefaultSelector()
        parent = os.getpid()
        nxt, held = 0, False
        logs: dict[int, list] = {}              # a piece's log records, kept until those of the pieces before it are out
        said = 0                                # the pieces whose records are logged
        try:
            while nxt < len(todo) or running:
                while nxt < len(todo) and len(running) < self.n:
                    if running and not self.room(len(running)):   # one more would not fit in memory: wait
                        if not held:
                            log.info("%d pieces at once, not %d: the memory available holds no more",
                                     len(running), self.n)
                        held = True
                        break
                    r, w = os.pipe()
                    pid = os.fork()
                    if pid == 0:                               # the child
                        try:
                            os.close(r)
                            _child(func, todo[nxt], w, parent)
                        finally:
                            os._exit(70)
                    os.close(w)
                    running[r] = (nxt, pid, bytearray())
                    sel.register(r, selectors.EVENT_READ)
                    nxt += 1
                for key, _ in sel.select(timeout=WAKE_S):     # [] after WAKE_S: the loop again
                    fd = key.fd
                    i, pid, buf = running[fd]
                    chunk = os.read(fd, CHUNK)
                    if chunk:
                        buf += chunk
                        continue
                    sel.unregister(fd)
                    os.close(fd)
                    del running[fd]
                    _, status = os.waitpid(pid, 0)
                    if not buf:
                        errors[i], logs[i] = PieceDied(f"piece {i + 1} of {len(todo)}: its process ended without a "
                                                       f"result ({_describe(status)})"), []
                    else:
                        ok, value, text, logs[i] = pickle.loads(bytes(buf))
                        if ok:
                            out[i] = value
                        else:
                            value.__cause__ = RemoteTraceback(text)
                            errors[i] = value
                    while said in logs:                 # in the items' order, as one after the other would log them
                        relog(logs.pop(said))
                        said += 1
        except BaseException:
            for fd, (_, pid, _) in running.items():
                try:
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                except OSError:
                    pass
                os.close(fd)
            raise
        finally:
            sel.close()
        if errors:
            raise errors[min(errors)]
        return out
