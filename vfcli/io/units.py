"""Time and frequency units as instrument files spell them, and their conversion to s and Hz.

A file that states a unit vfcli does not know is refused by the reader naming the unit (never read as
seconds or hertz by default); a file that states none is read in s or Hz as its format's documentation says.
"""
from __future__ import annotations

import re

#: Seconds per unit of each understood time unit (keys lower case, no spaces or dots).
SECONDS_PER_UNIT = {
    "s": 1.0, "sec": 1.0, "secs": 1.0, "second": 1.0, "seconds": 1.0,
    "ms": 1e-3, "msec": 1e-3, "millisecond": 1e-3, "milliseconds": 1e-3,
    "us": 1e-6, "µs": 1e-6, "μs": 1e-6, "usec": 1e-6, "microsecond": 1e-6, "microseconds": 1e-6,
    "ns": 1e-9, "nanosecond": 1e-9, "nanoseconds": 1e-9,
    "min": 60.0, "mins": 60.0, "minute": 60.0, "minutes": 60.0,
}

#: Hertz per unit of each understood frequency unit (keys lower case).
HZ_PER_UNIT = {"hz": 1.0, "khz": 1e3, "mhz": 1e6, "1/s": 1.0, "s^-1": 1.0, "fps": 1.0}


def _key(unit: str) -> str:
    return re.sub(r"[\s.]", "", unit).lower()


def seconds_per(unit: str) -> float | None:
    """Seconds per ``unit`` (e.g. ``'ms'`` -> 1e-3, ``'µs'`` -> 1e-6), or None for a unit that is not a time."""
    return SECONDS_PER_UNIT.get(_key(unit))


def hz_per(unit: str) -> float | None:
    """Hertz per ``unit`` (e.g. ``'kHz'`` -> 1e3), or None for a unit that is not a frequency."""
    return HZ_PER_UNIT.get(_key(unit))


def time_units_text() -> str:
    """The time units understood, for messages: ``s, ms, us, ns, min``."""
    return "s, ms, us (µs), ns, min"
