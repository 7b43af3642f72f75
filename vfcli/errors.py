"""Errors a user can cause, each with its documented exit code.

The CLI turns every :class:`VfcliError` into one line on stderr and exits with
``exit_code``; anything else is a bug and keeps its traceback.

Exit codes
----------
0  done (or nothing to do: inputs unchanged)
1  internal error (a bug: please report it with the traceback)
2  usage or config error (bad option, invalid config value)
3  bad input data (unreadable, truncated, inconsistent or non-physical raw files)
4  store locked by another writer (or held open by another program), not writable
   (permissions, a lock path that is a directory), not a vfcli store / incompatible version,
   or damaged (a stage whose structure or checksums differ from what vfcli wrote), or
   not enough disk space for a write (the store is unchanged, the temporary data removed)
5  a stage this command needs is missing or incomplete (run the upstream command first)
6  not implemented yet
130  interrupted (Ctrl-C, SIGINT); a stage is committed whole or not at all, so no half-written stage is left
"""
from __future__ import annotations

from pathlib import Path

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_BAD_INPUT = 3
EXIT_STORE = 4
EXIT_MISSING_STAGE = 5
EXIT_NOT_IMPLEMENTED = 6
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report a command killed by Ctrl-C


def interruption(exc: BaseException) -> BaseException | None:
    """The Ctrl-C (KeyboardInterrupt) or SIGTERM exit (SystemExit) that ``exc`` stands for: ``exc`` itself or one in
    its chain of causes and contexts; None for any other exception.

    A signal whose Python handler runs while compiled code is calling back into Python can come out wrapped: Ctrl-C
    during h5py's iteration over a group's attributes surfaced as ``SystemError: <cyfunction FastRLock.__exit__>
    returned a result with an exception set``, its cause the KeyboardInterrupt, and `vfcli run` then exited 1 with a
    traceback instead of 130 (tests/test_run.py::test_ctrl_c_during_a_run_lists_the_steps_it_committed, one run in
    many)."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, SystemExit)):
            return e
        seen.add(id(e))
        e = e.__cause__ if e.__cause__ is not None else e.__context__
    return None


class VfcliError(Exception):
    """Base class: a problem the user can fix; printed as one line."""

    exit_code = EXIT_INTERNAL

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else str(path)
        super().__init__(one_line(f"{self.path}: {message}" if self.path else message))


def one_line(text: str) -> str:
    """``text`` with line breaks and other control characters escaped as ``\\n``, ``\\x1b`` ...

    A message quotes what the user gave (a file name, a ``--set`` key), which may hold a newline;
    the CLI prints every error as one line.
    """
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class ConfigError(VfcliError):
    """An invalid option or config value (exit 2)."""

    exit_code = EXIT_USAGE


class InputDataError(VfcliError):
    """A raw input file that cannot be used as it is (exit 3)."""

    exit_code = EXIT_BAD_INPUT


class StoreLockedError(VfcliError):
    """Another process is writing the store (exit 4)."""

    exit_code = EXIT_STORE


class StoreAccessError(VfcliError):
    """The store (its folder or lock file) cannot be written: permissions, a directory in the way (exit 4)."""

    exit_code = EXIT_STORE


class StoreSpaceError(StoreAccessError):
    """Not enough disk space (or a file-size limit) for a write: the message says how much it
    needs; the store is unchanged and the temporary data removed (exit 4)."""


class StoreFormatError(VfcliError):
    """Not a vfcli store, or written by an incompatible version (exit 4)."""

    exit_code = EXIT_STORE


class StoreDamagedError(StoreFormatError):
    """A stage whose structure or checksums differ from what vfcli wrote: a damaged or
    hand-edited store (exit 4); the message names the stage and the dataset."""


class MissingStageError(VfcliError):
    """A stage the command reads is absent or incomplete (exit 5)."""

    exit_code = EXIT_MISSING_STAGE


class NotImplementedYet(VfcliError):
    """A subcommand that is not built yet (exit 6)."""

    exit_code = EXIT_NOT_IMPLEMENTED
