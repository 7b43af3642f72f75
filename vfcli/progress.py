"""Progress bars for long work: on for terminals, off with ``--quiet`` or when piped."""
from __future__ import annotations

import sys
from typing import Any, Iterable, Protocol


class Progress(Protocol):
    """What a stage needs of a progress bar."""

    def __call__(self, iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
                 bar_format: str | None = None) -> Any: ...


def make_progress(enabled: bool | None = None) -> Progress:
    """A tqdm factory; ``enabled=None`` means on when stderr is a terminal."""
    from tqdm import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty()

    def progress(iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
                 bar_format: str | None = None) -> Any:
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=not enabled, leave=False, file=sys.stderr,
                    bar_format=bar_format)

    return progress


def no_progress(iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
                bar_format: str | None = None) -> Any:
    """A progress factory that shows nothing (library default)."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, disable=True)


class Phases:
    """The named phases of one stage's work, shown as one bar (the current phase in its description, the
    elapsed time beside it) and timed.

    ``phases("calibrate")`` ends the phase running (if any) and starts ``calibrate``; :meth:`close` ends the last
    and returns every phase's wall time, s, in the order run (a phase started twice adds up).  ``total`` is the
    number of phases expected (the bar's length; :meth:`expect` adds phases found on the way).  Each phase's
    time is logged at INFO level by ``log`` when it ends, so ``-v`` says where the time went.  ``clock`` : seconds
    now (default :func:`time.perf_counter`).
    """

    def __init__(self, progress: Progress, desc: str, total: int, log: Any = None, clock: Any = None) -> None:
        import time

        self._clock = clock or time.perf_counter
        self._desc = desc
        # the phases take unlike times: no rate or remaining time, which would be guesses
        # (tqdm's set_description adds ': ' to a description; the one given at the start has it written out)
        self._bar = progress(total=total, desc=f"{desc}: ", unit="step", bar_format="{desc}{n_fmt} of {total_fmt} steps done, "
                                                                              "{elapsed}")
        self._log = log
        self._name: str | None = None
        self._t0 = 0.0
        self.seconds: dict[str, float] = {}

    def __call__(self, name: str) -> None:
        self._end()
        self._name, self._t0 = name, self._clock()
        self._bar.set_description(f"{self._desc}: {name}")

    def expect(self, more: int) -> None:
        """``more`` phases beyond the ones counted at the start."""
        if self._bar.total is not None:
            self._bar.total += more
            self._bar.refresh()

    def _end(self) -> None:
        if self._name is None:
            return
        dt = self._clock() - self._t0
        self.seconds[self._name] = self.seconds.get(self._name, 0.0) + dt
        if self._log is not None:
            self._log.info("%s: %s took %.1f s", self._desc, self._name, dt)
        self._bar.update(1)
        self._name = None

    def close(self) -> dict[str, float]:
        """End the last phase and the bar; every phase's seconds."""
        self._end()
        self._bar.close()
        return dict(self.seconds)


def no_phase(name: str) -> None:
    """A phase marker that does nothing (library default of a ``phase`` argument)."""
