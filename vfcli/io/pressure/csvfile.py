"""CSV pressure recordings: the reader and vfcli's own CSV writer.

Optional comment lines starting with ``#``, which may set ``# fs = 50000`` (Hz, or with a unit:
``50 kHz``; also ``sampling_rate``/``sample_rate``), ``# t0 = 0.0`` (s, or with a unit: ``-1 ms``) and
``# unit = Pa``. Delimiter ``,``, ``;`` or tab; a UTF-8 byte-order mark (Excel's "CSV UTF-8") is skipped.
Then either

* a header row and columns: a time column (``t``/``time``, in s unless its name states a unit:
  ``time [ms]``, ``Time (msec)``, ``t_us``, ``time [min]``; a unit that is not a time is refused) and a
  pressure column (``column=``, else the one named like ``p_sub``/``pressure``, else the only other one);
  a unit in the header name (``p_sub [kPa]``, ``pressure (Pa)`` or ``p_sub_kPa``) is used;
* or a single column of samples (header optional) with ``# fs = ...``.

Every row holds the same number of values and ends with a line break (a last row without one may be
cut off: refused).

The time column must be uniform: every sample within 0.1 sample period of ``t0 + k / fs``; ``# fs`` and ``# t0``
comments, where given beside it, must agree with it.
"""
from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import check_finite, check_last_row_complete, numeric_rows
from vfcli.io.pressure.record import (PRESSURE_NAME, PressureRecord, Transducer, finish, is_pressure_unit,
                                     is_voltage_unit, resolve_unit, uniform_rate)
from vfcli.io.units import hz_per, seconds_per, time_units_text

_TIME_NAME = re.compile(r"^\s*(t|time)(?=$|[\s_\[(])", re.IGNORECASE)
_UNIT_IN_NAME = re.compile(r"[\[(]\s*([^\])]+?)\s*[\])]")
_COMMENT_KEY = re.compile(r"^#\s*([A-Za-z_ 0-9]+?)\s*[=:]\s*(.+?)\s*$")


def read_csv(p: Path, column: str | int | None, unit: str | None, transducer: Transducer | None = None) -> PressureRecord:
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputDataError("not a text CSV file (undecodable bytes)", p) from None
    check_last_row_complete(text, p)
    meta: dict[str, str] = {}
    lines: list[tuple[int, str]] = []   # (line number in the file, row)
    for number, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _COMMENT_KEY.match(s)
            if m:
                meta[m.group(1).strip().lower().replace(" ", "_")] = m.group(2)
            continue
        lines.append((number, s))
    if not lines:
        raise InputDataError("CSV has no data rows", p)
    delim = ";" if ";" in lines[0][1] else ("\t" if "\t" in lines[0][1] else ",")
    first = next(csv.reader([lines[0][1]], delimiter=delim))
    has_header = not all(_is_number(c) for c in first)
    header = [c.strip() for c in first] if has_header else None
    table = numeric_rows(lines[1:] if has_header else lines, delim, p, header)
    ncol = table.shape[1]
    if header is not None and len(header) != ncol:
        raise InputDataError(f"header has {len(header)} names, the rows {ncol} values", p)
    names = header or [f"column {i}" for i in range(ncol)]
    t_col = next((i for i, n in enumerate(names) if header and _TIME_NAME.match(n)), None)
    if t_col is None and ncol == 2 and header is None:
        t_col = 0
    # pressure column
    if column is not None:
        if isinstance(column, int) or str(column).isdigit():
            p_col = int(column)
        elif header and str(column) in header:
            p_col = header.index(str(column))
        else:
            raise InputDataError(f"no CSV column {column!r}; columns: {names}", p)
        if not 0 <= p_col < ncol:
            raise InputDataError(f"column {p_col} outside the {ncol} columns", p)
    else:
        rest = [i for i in range(ncol) if i != t_col]
        named = [i for i in rest if header and PRESSURE_NAME.search(names[i])]
        pick = named if len(named) == 1 else rest
        if len(pick) != 1:
            raise InputDataError(f"cannot choose the pressure column among {names}: set "
                                 "the column", p)
        p_col = pick[0]
    file_unit = meta.get("unit")
    if header:
        file_unit = _pressure_unit_in_name(names[p_col]) or file_unit
    samples = table[:, p_col]
    fs_key = next((k for k in ("fs", "sampling_rate", "sample_rate", "fs_hz", "sampling_rate_hz") if k in meta), None)
    fs_meta = None if fs_key is None else _comment_value(meta[fs_key], fs_key, hz_per, "a frequency (Hz, kHz, MHz)", p)
    t0_meta = None if "t0" not in meta else _comment_value(meta["t0"], "t0", seconds_per, f"a time ({time_units_text()})", p)
    t0 = 0.0 if t0_meta is None else t0_meta
    if t_col is not None:
        t = table[:, t_col] * _time_scale(names[t_col], p) if header else table[:, t_col]
        check_finite(t, p, "time column")
        fs, t0 = uniform_rate(t, p)
        if fs_meta is not None:
            if abs(fs - fs_meta) > 1e-3 * fs_meta:
                raise InputDataError(f"'# fs = {fs_meta:g}' disagrees with the time column "
                                     f"({fs:g} Hz)", p)
            fs = fs_meta
        if t0_meta is not None and not abs(t0 - t0_meta) <= 0.1 / fs:                # NaN included
            raise InputDataError(f"'# t0 = {t0_meta:g}' disagrees with the time column (first time {t0:g} s)", p)
    elif fs_meta is not None:
        fs = fs_meta
    else:
        raise InputDataError("CSV has neither a time column nor a '# fs = <Hz>' comment", p)
    unit_used, source = resolve_unit(file_unit, unit, p)
    return finish(samples, fs, t0, unit_used, f"CSV {p.name} column {names[p_col]!r}", p, source, transducer)


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _time_scale(name: str, p: Path) -> float:
    """Seconds per value of the time column ``name``: the unit its name states (``time [ms]``, ``Time (msec)``,
    ``t_us``), 1 when it states none; a unit in brackets that is not a time is refused."""
    m = _UNIT_IN_NAME.search(name)
    if not m:   # a unit after an underscore (t_ms, time_us) when it is one; else none stated
        suffix = name.strip().split("_", 1)[1] if "_" in name else ""
        return seconds_per(suffix) or 1.0
    unit = m.group(1)
    scale = seconds_per(unit)
    if scale is None:
        raise InputDataError(f"time column {name!r}: unit {unit!r} is not a time unit vfcli knows "
                             f"({time_units_text()})", p)
    return scale


def _pressure_unit_in_name(name: str) -> str | None:
    """The unit a pressure column's name states: in brackets (``p_sub [kPa]``, ``pressure (Pa)``) or as its last
    ``_`` part when that is a pressure unit (``p_sub_kPa``); None when it states none."""
    m = _UNIT_IN_NAME.search(name)
    if m:
        return m.group(1)
    last = name.strip().rsplit("_", 1)[-1] if "_" in name else ""
    return last if last and (is_pressure_unit(last) or is_voltage_unit(last)) else None


def _comment_value(text: str, key: str, per_unit, what: str, p: Path) -> float:
    """The number of a ``# key = value [unit]`` comment in s or Hz (``per_unit(unit)``: that unit's size in them,
    None for a unit of another kind); a value that is not a number, or a unit that is not ``what``, is refused
    naming the comment."""
    number, _, unit = text.strip().partition(" ")
    try:
        value = float(number)
    except ValueError:
        raise InputDataError(f"'# {key} = {text}': {number!r} is not a number", p) from None
    if not unit.strip():
        return value
    scale = per_unit(unit.strip())
    if scale is None:
        raise InputDataError(f"'# {key} = {text}': {unit.strip()!r} is not {what}", p)
    return value * scale


def write_pressure_csv(path: str | Path, samples_pa: np.ndarray, fs: float, t0: float = 0.0,
                       with_time: bool = True) -> Path:
    """Write a pressure signal (Pa) in vfcli's CSV layout.

    ``# fs = ...``, ``# t0 = ...`` and ``# unit = Pa`` comments, then a header
    ``time [s],p_sub [Pa]`` (or ``p_sub [Pa]`` alone with ``with_time=False``)
    and one row per sample, values with 17 significant digits (exact round trip).
    """
    samples = np.asarray(samples_pa, dtype=np.float64).reshape(-1)
    if samples.size == 0 or not np.isfinite(samples).all():
        raise ConfigError("pressure samples must be non-empty and finite")
    if not fs > 0:
        raise ConfigError(f"fs must be > 0, got {fs}")
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    head = f"# fs = {float(fs)!r}\n# t0 = {float(t0)!r}\n# unit = Pa\n"
    if with_time:
        data = np.column_stack([t0 + np.arange(samples.size) / fs, samples])
        head += "time [s],p_sub [Pa]"
    else:
        data = samples[:, None]
        head += "p_sub [Pa]"
    np.savetxt(p, data, delimiter=",", fmt="%.17g", header=head, comments="")
    return p


