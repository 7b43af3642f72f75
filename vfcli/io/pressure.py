"""Subglottal pressure recordings: TDMS, CSV and WAV readers; TDMS and CSV writers.

Every reader returns a :class:`PressureRecord` ``(samples, fs, t0, unit, source)``:
samples in Pa (float64), sampling rate in Hz, time of the first sample in s
(relative to the DAQ's own start: TDMS ``wf_start_offset``, CSV first time value),
the unit the file stated, and a one-line description of the source.

Accepted layouts
----------------
TDMS (npTDMS)
    A waveform channel with ``wf_increment`` (s) and optionally
    ``wf_start_offset`` (s), ``wf_start_time`` and ``unit_string``. Channel
    choice: ``group``/``channel`` names if given; otherwise the only channel in
    the file, or the only one whose name looks like ``p_sub``/``psub``/
    ``pressure``/``subglottal``.
CSV
    Optional comment lines starting with ``#``, which may set
    ``# fs = 50000`` (Hz; also ``sampling_rate``/``sample_rate``), ``# t0 = 0.0``
    (s) and ``# unit = Pa``. Delimiter ``,``, ``;`` or tab. Then either

    * a header row and columns: a time column (``t``/``time``, in s, or in
      ms with ``[ms]``/``(ms)`` in its name) and a pressure column (``column=``,
      else the one named like ``p_sub``/``pressure``, else the only other one);
      a unit in the header name (``p_sub [kPa]`` or ``pressure (Pa)``) is used;
    * or a single column of samples (header optional) with ``# fs = ...``.

    The time column must be uniform: every sample within 0.1 sample period of
    ``t0 + k / fs``.
WAV (scipy.io.wavfile)
    Sampling rate from the header; integer samples are divided by full scale
    (int16: 32768, int32: 2**31, uint8: centred on 128; float: 1.0) and
    multiplied by ``wav_pa_per_full_scale`` (default
    :data:`WAV_PA_PER_FULL_SCALE` = 10 kPa, a typical transducer range: set
    it to your amplifier's calibration). ``channel`` picks a column of a
    multi-channel WAV (default 0).

Units understood: Pa, hPa, kPa, mbar, bar, psi, cmH2O, mmH2O, inH2O, mmHg.
"""
from __future__ import annotations

import csv
import io
import logging
import re
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import check_finite, require_file
from vfcli.io.limits import MAX_ABS_PRESSURE_PA, PRESSURE_FS_RANGE, check_abs_max, check_range

logger = logging.getLogger(__name__)

#: Default WAV calibration: pascals at digital full scale.
WAV_PA_PER_FULL_SCALE = 10_000.0

#: Pascals per unit of each understood pressure unit (keys lower case, no spaces).
PA_PER_UNIT = {
    "pa": 1.0, "hpa": 100.0, "kpa": 1000.0, "mbar": 100.0, "bar": 1e5, "psi": 6894.757293168,
    "cmh2o": 98.0665, "mmh2o": 9.80665, "inh2o": 249.08891, "mmhg": 133.322387415,
}

_PRESSURE_NAME = re.compile(r"p_?sub|subglottal|pressure|^p$", re.IGNORECASE)
_TIME_NAME = re.compile(r"^\s*(t|time)\b", re.IGNORECASE)


class PressureRecord(NamedTuple):
    """A pressure signal: ``samples (N,) float64 Pa``, ``fs`` Hz, ``t0`` s, ``unit``, ``source``."""

    samples: np.ndarray
    fs: float
    t0: float
    unit: str
    source: str


def pa_per_unit(unit: str, path: str | Path | None = None) -> float:
    """Conversion factor to Pa for a unit string such as ``'kPa'`` or ``'cm H2O'``."""
    key = re.sub(r"[\s_]", "", unit).lower()
    if key not in PA_PER_UNIT:
        raise InputDataError(
            f"pressure unit {unit!r} is not a pressure unit vfcli knows "
            f"({', '.join(PA_PER_UNIT)})", path)
    return PA_PER_UNIT[key]


def _resolve_unit(file_unit: str | None, unit: str | None, path: Path) -> str:
    """The unit to apply: the file's, checked against the configured one."""
    if file_unit and unit and pa_per_unit(file_unit, path) != pa_per_unit(unit, path):
        raise InputDataError(f"unit mismatch: the file says {file_unit!r}, the config says "
                             f"{unit!r}", path)
    return file_unit or unit or "Pa"


def _finish(samples: np.ndarray, fs: float, t0: float, unit: str, source: str,
            path: Path) -> PressureRecord:
    samples = np.asarray(samples, dtype=np.float64).reshape(-1)
    if samples.size == 0:
        raise InputDataError("pressure signal has no samples", path)
    check_finite(samples, path, "pressure signal")
    if not (np.isfinite(fs) and fs > 0):
        raise InputDataError(f"sampling rate {fs} Hz is not positive", path)
    if not np.isfinite(t0):
        raise InputDataError(f"start time {t0} s is not finite", path)
    scale = pa_per_unit(unit, path)
    fs = float(f"{fs:.12g}")  # 1 / wf_increment: drop the last-digit noise of the inverse
    check_range(fs, *PRESSURE_FS_RANGE, "pressure sampling rate", "Hz", path)
    with np.errstate(over="ignore"):
        pa = samples * scale
    check_finite(pa, path, "pressure signal (in Pa)")
    check_abs_max(pa, MAX_ABS_PRESSURE_PA, "pressure", "Pa", path)
    return PressureRecord(pa, fs, float(t0), unit, source)


def read_pressure(
    path: str | Path,
    group: str | None = None,
    channel: str | int | None = None,
    unit: str | None = None,
    wav_pa_per_full_scale: float = WAV_PA_PER_FULL_SCALE,
    kind: str | None = None,
) -> PressureRecord:
    """Read a subglottal pressure recording (TDMS, CSV or WAV, by extension).

    Parameters
    ----------
    path : str or Path
    group, channel : str or None
        TDMS group/channel names (``channel`` is the column name for CSV and
        the channel index for WAV). Defaults: see the module docstring.
    unit : str or None
        Unit of the values when the file does not say (CSV, TDMS without
        ``unit_string``); when the file does say, it must agree.
    wav_pa_per_full_scale : float
        WAV calibration, Pa at digital full scale.
    kind : {'tdms', 'csv', 'wav'} or None
        Force the format; default from the extension.

    Returns
    -------
    PressureRecord
        ``samples (N,) float64 Pa``, ``fs`` Hz, ``t0`` s, ``unit`` (as in the
        file), ``source``.

    Raises
    ------
    InputDataError
        Missing/empty/unreadable file, no or ambiguous channel, NaN/Inf samples,
        non-uniform time column, unknown unit or unit mismatch.
    """
    p = require_file(path, "pressure file")
    kind = kind or p.suffix.lower().lstrip(".")
    if kind == "tdms":
        return _read_tdms(p, group, channel, unit)
    if kind in ("csv", "txt"):
        return _read_csv(p, channel, unit)
    if kind == "wav":
        return _read_wav(p, channel, wav_pa_per_full_scale)
    raise InputDataError(f"unsupported pressure file type {p.suffix!r} (tdms, csv, wav)", p)


# --------------------------------------------------------------------------- TDMS

def _read_tdms(p: Path, group: str | None, channel: str | int | None,
               unit: str | None) -> PressureRecord:
    from nptdms import TdmsFile

    with open(p, "rb") as fh:
        if fh.read(4) != b"TDSm":
            raise InputDataError("not a TDMS file (no 'TDSm' lead-in)", p)
    nptdms_log = logging.getLogger("nptdms")
    said = _Said()
    nptdms_log.addHandler(said)
    try:
        try:
            tdms = TdmsFile.open(p)  # metadata only; the chosen channel's data is read below
        except Exception as exc:  # npTDMS raises ValueError/struct.error/... on corrupt files
            raise InputDataError(f"unreadable TDMS: {type(exc).__name__}: {exc}", p) from None
        try:
            return _read_tdms_channel(p, tdms, group, channel, unit, said.messages)
        finally:
            tdms.close()
    finally:
        nptdms_log.removeHandler(said)


class _Said(logging.Handler):
    """Collects npTDMS's warnings (it reads a truncated file with a logged warning only)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _read_tdms_channel(p: Path, tdms, group: str | None, channel: str | int | None,
                       unit: str | None, warned: list[str]) -> PressureRecord:
    try:
        chans = [(g.name, c) for g in tdms.groups() for c in g.channels()]
    except Exception as exc:
        raise InputDataError(f"unreadable TDMS: {type(exc).__name__}: {exc}", p) from None
    if group is not None:
        chans = [gc for gc in chans if gc[0] == group]
        if not chans:
            raise InputDataError(f"no TDMS group {group!r}", p)
    names = [f"{g}/{c.name}" for g, c in chans]
    if channel is not None:
        chans = [gc for gc in chans if gc[1].name == str(channel)]
        if not chans:
            raise InputDataError(f"no TDMS channel {channel!r}; channels: {names}", p)
    elif len(chans) > 1:
        chans = [gc for gc in chans if _PRESSURE_NAME.search(gc[1].name)]
    if len(chans) != 1:
        raise InputDataError(
            f"cannot choose the pressure channel among {names}: set group/channel", p)
    gname, ch = chans[0]
    props = ch.properties
    try:
        data = ch[:]
        dt = float(props["wf_increment"])
        t0 = float(props.get("wf_start_offset", 0.0))
    except KeyError:
        raise InputDataError(f"channel {gname}/{ch.name} has no wf_increment (sample "
                             "interval): not a waveform", p) from None
    except Exception as exc:
        raise InputDataError(f"unreadable TDMS channel {gname}/{ch.name}: {exc}", p) from None
    if not (np.isfinite(dt) and dt > 0):
        raise InputDataError(f"wf_increment {dt} s is not positive", p)
    if not np.issubdtype(np.asarray(data).dtype, np.number):
        raise InputDataError(f"channel {gname}/{ch.name} is not numeric", p)
    _check_tdms_complete(p, tdms, gname, ch, len(data), warned)
    file_unit = str(props.get("unit_string", "")).strip() or None
    unit_used = _resolve_unit(file_unit, unit, p)
    start = props.get("wf_start_time")
    src = f"TDMS {p.name} {gname}/{ch.name}" + (f", wf_start_time {start}" if start else "")
    return _finish(data, 1.0 / dt, t0, unit_used, src, p)


def _check_tdms_complete(p: Path, tdms, gname: str, ch, n: int, warned: list[str]) -> None:
    """Refuse a channel with fewer samples than the file promises (a truncated TDMS).

    npTDMS reads a truncated last segment with only a logged warning ("less data than
    expected"), which vfcli turns into a refusal; a channel shorter than another channel of
    its group at the same sample interval (a DAQ samples them together) is refused too.
    """
    name = f"{gname}/{ch.name}"
    trunc = [w for w in warned if "less data than expected" in w or "not a multiple of the chunk" in w]
    if trunc:
        raise InputDataError(f"channel {name} is truncated ({n} samples read; npTDMS: {trunc[0][:120]})", p)
    try:
        dt = ch.properties.get("wf_increment")
        promised = [len(c) for c in tdms[gname].channels()
                    if c.name != ch.name and c.properties.get("wf_increment") == dt]
    except Exception:  # noqa: BLE001 - lengths are a plausibility check only
        promised = []
    longest = max(promised, default=n)
    if longest > n:
        raise InputDataError(f"channel {name} holds {n} samples, another channel of the group at the same "
                             f"rate {longest}: truncated file?", p)


def write_pressure_tdms(path: str | Path, samples_pa: np.ndarray, fs: float, t0: float = 0.0,
                        group: str = "pressure", channel: str = "p_sub",
                        start_time: np.datetime64 | None = None) -> Path:
    """Write a pressure waveform (Pa) as a TDMS channel with waveform properties.

    Parameters
    ----------
    samples_pa : (N,) float array, Pa
    fs : float, Hz
    t0 : float, s
        Stored as ``wf_start_offset``.
    start_time : numpy.datetime64 or None
        ``wf_start_time`` (default: now, UTC).
    """
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    samples = np.asarray(samples_pa, dtype=np.float64).reshape(-1)
    if samples.size == 0 or not np.isfinite(samples).all():
        raise ConfigError("pressure samples must be non-empty and finite")
    if not fs > 0:
        raise ConfigError(f"fs must be > 0, got {fs}")
    start = np.datetime64("now", "us") if start_time is None else np.datetime64(start_time, "us")
    props = {"wf_increment": 1.0 / fs, "wf_start_offset": float(t0), "wf_start_time": start,
             "wf_samples": int(samples.size), "unit_string": "Pa"}
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with TdmsWriter(p) as w:
        w.write_segment([RootObject(), GroupObject(group),
                         ChannelObject(group, channel, samples, properties=props)])
    return p


# --------------------------------------------------------------------------- CSV

_UNIT_IN_NAME = re.compile(r"[\[(]\s*([^\])]+?)\s*[\])]")
_COMMENT_KEY = re.compile(r"^#\s*([A-Za-z_ 0-9]+?)\s*[=:]\s*(.+?)\s*$")


def _read_csv(p: Path, column: str | int | None, unit: str | None) -> PressureRecord:
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputDataError("not a text CSV file (undecodable bytes)", p) from None
    meta: dict[str, str] = {}
    lines = []
    for line in text.splitlines():
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _COMMENT_KEY.match(s)
            if m:
                meta[m.group(1).strip().lower().replace(" ", "_")] = m.group(2)
            continue
        lines.append(s)
    if not lines:
        raise InputDataError("CSV has no data rows", p)
    delim = ";" if ";" in lines[0] else ("\t" if "\t" in lines[0] else ",")
    first = next(csv.reader([lines[0]], delimiter=delim))
    has_header = not all(_is_number(c) for c in first)
    header = [c.strip() for c in first] if has_header else None
    body = "\n".join(lines[1:] if has_header else lines)
    if not body.strip():
        raise InputDataError("CSV has no data rows", p)
    try:
        table = np.loadtxt(io.StringIO(body), delimiter=delim, ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise InputDataError(f"CSV data rows are not all numbers: {exc}", p) from None
    if table.size == 0:
        raise InputDataError("CSV has no data rows", p)
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
        named = [i for i in rest if header and _PRESSURE_NAME.search(names[i])]
        pick = named if len(named) == 1 else rest
        if len(pick) != 1:
            raise InputDataError(f"cannot choose the pressure column among {names}: set "
                                 "the column", p)
        p_col = pick[0]
    file_unit = meta.get("unit")
    m = _UNIT_IN_NAME.search(names[p_col]) if header else None
    if m:
        file_unit = m.group(1)
    samples = table[:, p_col]
    fs_meta = next((meta[k] for k in ("fs", "sampling_rate", "sample_rate", "fs_hz",
                                      "sampling_rate_hz") if k in meta), None)
    try:
        fs_meta = None if fs_meta is None else float(fs_meta.split()[0])
        t0 = float(meta.get("t0", "0").split()[0])
    except ValueError:
        raise InputDataError("'# fs' or '# t0' comment is not a number", p) from None
    if t_col is not None:
        t = table[:, t_col]
        tm = _UNIT_IN_NAME.search(names[t_col]) if header else None
        if tm and tm.group(1).lower() == "ms":
            t = t * 1e-3
        check_finite(t, p, "time column")
        fs, t0 = _uniform_rate(t, p)
        if fs_meta is not None:
            if abs(fs - fs_meta) > 1e-3 * fs_meta:
                raise InputDataError(f"'# fs = {fs_meta:g}' disagrees with the time column "
                                     f"({fs:g} Hz)", p)
            fs = fs_meta
    elif fs_meta is not None:
        fs = fs_meta
    else:
        raise InputDataError("CSV has neither a time column nor a '# fs = <Hz>' comment", p)
    unit_used = _resolve_unit(file_unit, unit, p)
    return _finish(samples, fs, t0, unit_used, f"CSV {p.name} column {names[p_col]!r}", p)


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _uniform_rate(t: np.ndarray, p: Path) -> tuple[float, float]:
    """(fs, t0) of a time column; InputDataError unless uniform within 0.1 period."""
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


# --------------------------------------------------------------------------- WAV

def _check_wav_chunks(p: Path, riff: bytes) -> None:
    """Refuse a WAV whose ``data`` chunk claims more bytes than the file holds.

    scipy reads such a file with a warning and returns what is there; a header that
    lies about the length is a truncated or corrupt recording. RF64 (sizes in the ds64
    chunk) is left to scipy.
    """
    import struct

    if riff == b"RF64":
        return
    fmt = ">I" if riff == b"RIFX" else "<I"
    size = p.stat().st_size
    with open(p, "rb") as fh:
        pos = 12
        while pos + 8 <= size:
            fh.seek(pos)
            tag, n = fh.read(4), struct.unpack(fmt, fh.read(4))[0]
            if tag == b"data":
                if pos + 8 + n > size:
                    raise InputDataError(f"truncated WAV: the data chunk claims {n} bytes, the file holds "
                                         f"{size - pos - 8} after its header", p)
                return
            pos += 8 + n + (n & 1)


def _read_wav(p: Path, channel: str | int | None, pa_per_fs: float) -> PressureRecord:
    from scipy.io import wavfile

    if not (np.isfinite(pa_per_fs) and pa_per_fs > 0):
        raise ConfigError(f"wav_pa_per_full_scale must be > 0, got {pa_per_fs}")
    with open(p, "rb") as fh:
        head = fh.read(12)
    if head[:4] not in (b"RIFF", b"RIFX", b"RF64") or head[8:12] != b"WAVE":
        raise InputDataError("not a WAV file (no RIFF/WAVE header)", p)
    _check_wav_chunks(p, head[:4])
    if channel is not None and not (isinstance(channel, int) or str(channel).strip().isdigit()):
        raise ConfigError(f"{p}: the channel of a WAV is its index (0, 1, ...), not {channel!r}: "
                          "set ingest_hsc.pressure_channel")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fs, data = wavfile.read(p, mmap=False)
    except Exception as exc:  # scipy raises ValueError/EOFError/... on corrupt files
        raise InputDataError(f"unreadable WAV: {type(exc).__name__}: {exc}", p) from None
    if data.ndim == 2:
        idx = 0 if channel is None else int(channel)
        if not 0 <= idx < data.shape[1]:
            raise InputDataError(f"channel {idx} outside the {data.shape[1]} WAV channels", p)
        data = data[:, idx]
    kind = data.dtype.kind
    if kind == "u":
        half = 2.0 ** (8 * data.dtype.itemsize - 1)
        x = (data.astype(np.float64) - half) / half
    elif kind == "i":
        x = data.astype(np.float64) / 2.0 ** (8 * data.dtype.itemsize - 1)
    elif kind == "f":
        x = data.astype(np.float64)
    else:
        raise InputDataError(f"unsupported WAV sample type {data.dtype}", p)
    return _finish(x * pa_per_fs, float(fs), 0.0, "Pa",
                   f"WAV {p.name} ({data.dtype}, {pa_per_fs:g} Pa full scale)", p)
