"""The pressure record every reader returns, the units vfcli understands, and the checks shared by the readers.

:func:`finish` is the one place where a reader's samples become a :class:`PressureRecord`:
it converts them to Pa and refuses what cannot be a subglottal pressure recording (no samples,
NaN/Inf, a sampling rate or a pressure outside vfcli/io/limits.py).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vfcli.errors import InputDataError
from vfcli.io._common import check_finite
from vfcli.io.limits import MAX_ABS_PRESSURE_PA, PRESSURE_FS_RANGE, check_abs_max, check_range

#: Pascals per unit of each understood pressure unit (keys lower case, no spaces).
PA_PER_UNIT = {
    "pa": 1.0, "hpa": 100.0, "kpa": 1000.0, "mbar": 100.0, "bar": 1e5, "psi": 6894.757293168,
    "cmh2o": 98.0665, "mmh2o": 9.80665, "inh2o": 249.08891, "mmhg": 133.322387415,
}

#: Volts per unit of the voltage units a transducer's output may be recorded in (a DAQ's raw channel).
VOLTS_PER_UNIT = {"v": 1.0, "mv": 1e-3}

#: Channel or column names that look like the subglottal pressure.
PRESSURE_NAME = re.compile(r"p_?sub|subglottal|pressure|^p$", re.IGNORECASE)


class PressureRecord(NamedTuple):
    """A pressure signal: ``samples (N,) float64 Pa``, ``fs`` Hz, ``t0`` s, ``unit`` (the samples' unit in the
    file), ``source`` (one line), ``unit_source``: where ``unit`` came from, ``"file"`` (stated there),
    ``"config"`` (the caller's, the file states none) or ``"assumed"`` (Pa: neither states one)."""

    samples: np.ndarray
    fs: float
    t0: float
    unit: str
    source: str
    unit_source: str = "file"


class Transducer(NamedTuple):
    """A pressure transducer's calibration, for a record of its output voltage: ``Pa = (V - zero_volts) *
    pa_per_volt`` (``ingest_hsc.pressure_pa_per_volt``, ``ingest_hsc.pressure_zero_volts``)."""

    pa_per_volt: float
    zero_volts: float = 0.0


def _unit_key(unit: str) -> str:
    return re.sub(r"[\s_]", "", unit).lower()


def is_voltage_unit(unit: str) -> bool:
    """True for a unit string of :data:`VOLTS_PER_UNIT` (``'V'``, ``'mV'``)."""
    return _unit_key(unit) in VOLTS_PER_UNIT


def _known_units() -> str:
    return ", ".join(PA_PER_UNIT) + "; a transducer's output in " + ", ".join(VOLTS_PER_UNIT)


def _per_unit(unit: str, path: Path | None) -> tuple[str, float]:
    """("pa", Pa per unit) for a pressure unit, ("v", V per unit) for a voltage unit; InputDataError otherwise."""
    key = _unit_key(unit)
    if key in PA_PER_UNIT:
        return "pa", PA_PER_UNIT[key]
    if key in VOLTS_PER_UNIT:
        return "v", VOLTS_PER_UNIT[key]
    raise InputDataError(f"pressure unit {unit!r} is not a unit vfcli knows ({_known_units()})", path)


def is_pressure_unit(unit: str) -> bool:
    """True for a unit string of :data:`PA_PER_UNIT` (spaces, underscores and case aside: ``'cm H2O'``, ``'KPA'``)."""
    return _unit_key(unit) in PA_PER_UNIT


def pa_per_unit(unit: str, path: str | Path | None = None) -> float:
    """Conversion factor to Pa for a unit string such as ``'kPa'`` or ``'cm H2O'``."""
    kind, factor = _per_unit(unit, path)
    if kind != "pa":
        raise InputDataError(f"{unit!r} is a transducer's output, not a pressure unit: its Pa need the transducer's "
                             "calibration (Transducer)", path)
    return factor


def resolve_unit(file_unit: str | None, unit: str | None, path: Path) -> tuple[str, str]:
    """(unit, where it came from) to apply: the file's, checked against the configured one (``"file"``); the
    configured one where the file states none (``"config"``); Pa where neither does (``"assumed"``)."""
    if file_unit and unit and _per_unit(file_unit, path) != _per_unit(unit, path):
        raise InputDataError(f"unit mismatch: the file says {file_unit!r}, the config (ingest_hsc.pressure_unit) "
                             f"says {unit!r}", path)
    if file_unit:
        return file_unit, "file"
    return (unit, "config") if unit else ("Pa", "assumed")


def uniform_rate(t: np.ndarray, p: Path) -> tuple[float, float]:
    """(fs Hz, t0 s) of a time column or channel (N,) s; InputDataError unless uniform within 0.1 period."""
    if t.size < 2:
        raise InputDataError("time column needs at least 2 samples", p)
    dt = (t[-1] - t[0]) / (t.size - 1)
    if not dt > 0:
        raise InputDataError("time column does not increase", p)
    dev = np.abs(t - (t[0] + dt * np.arange(t.size))) / dt
    k = int(np.argmax(dev))
    if dev[k] > 0.1 or np.any(np.diff(t) <= 0):
        raise InputDataError(
            f"non-uniform time column: row {k} (t = {t[k]:g} s) is {dev[k]:.2f} sample periods "
            "off a uniform grid (gaps or jitter)", p)
    return 1.0 / dt, float(t[0])


def finish(samples: np.ndarray, fs: float, t0: float, unit: str, source: str,
           path: Path, unit_source: str = "file", transducer: Transducer | None = None) -> PressureRecord:
    """Check a reader's samples and make the record.

    Parameters
    ----------
    samples : (N,) array in ``unit``
    fs : float, Hz
    t0 : float, s
    unit : str
        A unit of :data:`PA_PER_UNIT`, or of :data:`VOLTS_PER_UNIT` with ``transducer``.
    unit_source : ``"file"``, ``"config"`` or ``"assumed"`` (:func:`resolve_unit`).
    transducer : the calibration that turns a voltage record into Pa (None: a voltage record is refused).

    Raises
    ------
    InputDataError
        No samples, NaN/Inf (before or after the unit), a sampling rate outside
        ``PRESSURE_FS_RANGE``, a pressure beyond ``MAX_ABS_PRESSURE_PA``, or a voltage without ``transducer``.
    """
    samples = np.asarray(samples, dtype=np.float64).reshape(-1)
    if samples.size == 0:
        raise InputDataError("pressure signal has no samples", path)
    check_finite(samples, path, "pressure signal")
    if not (np.isfinite(fs) and fs > 0):
        raise InputDataError(f"sampling rate {fs} Hz is not positive", path)
    if not np.isfinite(t0):
        raise InputDataError(f"start time {t0} s is not finite", path)
    kind, scale = _per_unit(unit, path)
    if kind == "v" and transducer is None:
        raise InputDataError(
            f"the pressure is recorded in {unit} (a transducer's output, not a pressure): set its calibration, "
            "ingest_hsc.pressure_pa_per_volt (Pa per V, from the transducer's calibration sheet or a manometer) and "
            "ingest_hsc.pressure_zero_volts (its output at zero pressure, e.g. before the flow starts)", path)
    fs = float(f"{fs:.12g}")  # 1 / wf_increment: drop the last-digit noise of the inverse
    check_range(fs, *PRESSURE_FS_RANGE, "pressure sampling rate", "Hz", path)
    with np.errstate(over="ignore"):
        pa = samples * scale if kind == "pa" else (samples * scale - transducer.zero_volts) * transducer.pa_per_volt
    check_finite(pa, path, "pressure signal (in Pa)")
    check_abs_max(pa, MAX_ABS_PRESSURE_PA, "pressure", "Pa", path)
    return PressureRecord(pa, fs, float(t0), unit, source, unit_source)
