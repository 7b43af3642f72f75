"""Shared settings and checks of the fuzzers (tests/test_hostile_fuzz*.py, tests/test_io_*.py).

Hypothesis profiles
-------------------
``vfcli-ci`` (the default)
    ``derandomize=True``: the examples are drawn from a fixed seed, so every run of the suite
    tries the same cases and a failure reproduces; no example database.
``vfcli-explore``
    Fresh random examples on every run, failures saved in hypothesis's database.

Choose with ``VFCLI_FUZZ_PROFILE=vfcli-explore``; ``VFCLI_FUZZ_SCALE=10`` multiplies every
fuzzer's case count (a nightly or a hunt; the counts in docs/input-checks.md are at scale 1).

Hypothesis's own ``deadline`` is off: it measures wall time after the fact, which a shared
machine under load exceeds by chance, and it cannot stop a hang. Instead every case runs
under :func:`per_case_deadline`, a SIGALRM that interrupts a reader stuck for
:data:`CASE_DEADLINE_S` seconds (a few milliseconds is typical) and fails the test. A hang inside
a library's C code, which a Python signal handler cannot interrupt, is stopped by the fuzz
modules' :data:`BACKSTOP` (pytest-timeout's thread method: stacks dumped, the run ended).
"""
from __future__ import annotations

import os
import signal
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable

import pytest
from hypothesis import HealthCheck, settings

from vfcli.errors import VfcliError

_COMMON: dict[str, Any] = dict(deadline=None, print_blob=True,
                               suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                                      HealthCheck.data_too_large, HealthCheck.filter_too_much])
settings.register_profile("vfcli-ci", derandomize=True, database=None, **_COMMON)
settings.register_profile("vfcli-explore", derandomize=False, **_COMMON)

PROFILE = os.environ.get("VFCLI_FUZZ_PROFILE", "vfcli-ci")
SCALE = float(os.environ.get("VFCLI_FUZZ_SCALE", "1"))
#: Longest a single case may take, s (typical: 1-5 ms; generous for a loaded machine).
CASE_DEADLINE_S = 20.0


#: Module mark of the fuzz files: a whole fuzz test past this many seconds is a hang in C code.
BACKSTOP = pytest.mark.timeout(900, method="thread")


def fuzz(n: int) -> settings:
    """Hypothesis settings of the chosen profile with ``n`` cases (times ``VFCLI_FUZZ_SCALE``)."""
    return settings(settings.get_profile(PROFILE), max_examples=max(1, int(round(n * SCALE))))


class CaseHang(BaseException):
    """A fuzz case ran past :data:`CASE_DEADLINE_S` (a hang or a runaway computation).

    A BaseException, like KeyboardInterrupt, so that a reader's ``except Exception`` (which turns a
    library's error into a user error) cannot swallow it."""


@contextmanager
def per_case_deadline(seconds: float = CASE_DEADLINE_S):
    """Interrupt the body with :class:`CaseHang` after ``seconds`` of wall time (main thread only)."""
    def _alarm(_sig, _frame):
        raise CaseHang(f"a fuzz case took longer than {seconds:g} s (hang?)")

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def fresh(path: Path) -> Path:
    """``path`` with no file at it, so that a case writes its file anew instead of over the last case's.

    Truncating a file that holds data to write it again (``write_bytes``, ``open(..., "wb")``) starts the
    file's writeback on ext4 (``auto_da_alloc``): 2.2-2.6 ms per write on the suite's machine against
    0.06 ms for a new file (session 37, scratch hT/iot), and the fuzzers write about 27,000 case files.
    What the reader is given is the same bytes."""
    path.unlink(missing_ok=True)
    return path


def user_error_or(fn: Callable[[], Any], check: Callable[[Any], Any] | None = None) -> None:
    """Call ``fn`` under the per-case deadline: a vfcli user error is fine, a result must pass
    ``check``; any other exception (a bug) and a hang fail the test.

    A user error must also be one line (what the CLI prints).
    """
    try:
        with per_case_deadline():
            out = fn()
    except VfcliError as exc:
        assert "\n" not in str(exc), repr(str(exc))
        return
    except CaseHang as exc:
        raise AssertionError(str(exc)) from None
    if check is not None:
        check(out)


def mutate(data: bytes, cut: int, flips: list[tuple[int, int]]) -> bytes:
    """``data`` truncated by ``cut`` bytes (a negative cut appends that many zero bytes) with bits flipped
    at ``(position mod length, bit)``."""
    b = bytearray(data[: max(0, len(data) - cut)] if cut >= 0 else data + bytes(-cut))
    for pos, bit in flips:
        if b:
            b[pos % len(b)] ^= 1 << bit
    return bytes(b)
