"""Progress bars for long work: on for terminals, off with ``--quiet`` or when piped."""
from __future__ import annotations

import sys
from typing import Any, Iterable, Protocol


class Progress(Protocol):
    """What a stage needs of a progress bar."""

    def __call__(self, iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it") -> Any: ...


def make_progress(enabled: bool | None = None) -> Progress:
    """A tqdm factory; ``enabled=None`` means on when stderr is a terminal."""
    from tqdm import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty()

    def progress(iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it") -> Any:
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=not enabled, leave=False, file=sys.stderr)

    return progress


def no_progress(iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it") -> Any:
    """A progress factory that shows nothing (library default)."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, disable=True)
