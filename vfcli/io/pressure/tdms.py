"""TDMS pressure recordings (npTDMS): the reader, with the truncation check npTDMS lacks, and the writer.

A waveform channel with ``wf_increment`` (s) and optionally ``wf_start_offset`` (s),
``wf_start_time`` and its unit in ``unit_string`` (or DAQmx's ``NI_UnitDescription``); or a channel
without waveform properties beside a uniform time channel of its group (named ``time``/``t``, in s
unless its own unit says otherwise). Channel choice: ``group``/``channel`` names if given;
otherwise the only channel in the file (a time channel aside), or the only one whose name looks like
``p_sub``/``psub``/``pressure``/``subglottal``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import LibraryOutput, library_output
from vfcli.io.pressure.record import PRESSURE_NAME, PressureRecord, Transducer, finish, resolve_unit, uniform_rate
from vfcli.io.units import seconds_per, time_units_text

#: Names of a time channel beside a pressure channel without waveform properties.
_TIME_CHANNEL = ("time", "t", "time_s", "zeit")


def _unit_of(props) -> str | None:
    """The unit a TDMS channel states: ``unit_string``, else DAQmx's ``NI_UnitDescription``; None when neither."""
    for key in ("unit_string", "NI_UnitDescription"):
        text = str(props.get(key, "")).strip()
        if text:
            return text
    return None


def read_tdms(p: Path, group: str | None, channel: str | int | None,
              unit: str | None, transducer: Transducer | None = None) -> PressureRecord:
    from nptdms import TdmsFile

    with open(p, "rb") as fh:
        if fh.read(4) != b"TDSm":
            raise InputDataError("not a TDMS file (no 'TDSm' lead-in)", p)
    with library_output(p, "nptdms") as said:
        try:
            tdms = TdmsFile.open(p)  # metadata only; the chosen channel's data is read below
        except Exception as exc:  # npTDMS raises ValueError/struct.error/... on corrupt files
            raise InputDataError(f"unreadable TDMS: {type(exc).__name__}: {exc}", p) from None
        try:
            return _read_tdms_channel(p, tdms, group, channel, unit, said, transducer)
        finally:
            tdms.close()


def _read_tdms_channel(p: Path, tdms, group: str | None, channel: str | int | None,
                       unit: str | None, said: LibraryOutput, transducer: Transducer | None = None) -> PressureRecord:
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
            raise InputDataError(f"no TDMS channel {channel!r} (ingest_hsc.pressure_channel); channels: {names}", p)
    elif len(chans) > 1:
        chans = [gc for gc in chans if PRESSURE_NAME.search(gc[1].name)] or \
            [gc for gc in chans if gc[1].name.strip().lower() not in _TIME_CHANNEL]
    if len(chans) != 1:
        raise InputDataError(f"cannot choose the pressure channel among {names}: set ingest_hsc.pressure_group and "
                             "ingest_hsc.pressure_channel (`vfcli config STORE --set ingest_hsc.pressure_channel=NAME` "
                             "or in recording.toml)", p)
    gname, ch = chans[0]
    props = ch.properties
    try:
        data = ch[:]
        if "wf_increment" in props:
            dt = float(props["wf_increment"])
            t0 = float(props.get("wf_start_offset", 0.0))
        else:
            fs, t0 = _time_channel_rate(p, tdms, gname, ch)
            dt = 1.0 / fs
    except InputDataError:
        raise
    except Exception as exc:
        raise InputDataError(f"unreadable TDMS channel {gname}/{ch.name}: {exc}", p) from None
    if not (np.isfinite(dt) and dt > 0):
        raise InputDataError(f"wf_increment {dt} s is not positive", p)
    if not np.issubdtype(np.asarray(data).dtype, np.number):
        raise InputDataError(f"channel {gname}/{ch.name} is not numeric", p)
    _check_tdms_complete(p, tdms, gname, ch, len(data), said.messages)
    unit_used, unit_source = resolve_unit(_unit_of(props), unit, p)
    start = props.get("wf_start_time")
    src = f"TDMS {p.name} {gname}/{ch.name}" + (f", wf_start_time {start}" if start else "")
    return finish(data, 1.0 / dt, t0, unit_used, src, p, unit_source, transducer)


def _time_channel_rate(p: Path, tdms, gname: str, ch) -> tuple[float, float]:
    """(fs Hz, t0 s) of a channel without waveform properties from the time channel of its group
    (:data:`_TIME_CHANNEL`, uniform, in s unless its unit says otherwise); refused when there is none."""
    times = [c for c in tdms[gname].channels() if c.name.strip().lower() in _TIME_CHANNEL and c.name != ch.name]
    if len(times) != 1:
        raise InputDataError(f"channel {gname}/{ch.name} has no wf_increment (sample interval) and its group no "
                             f"time channel (named {', '.join(_TIME_CHANNEL)}): not a waveform", p)
    tc = times[0]
    unit = _unit_of(tc.properties)
    scale = 1.0 if unit is None else seconds_per(unit)
    if scale is None:
        raise InputDataError(f"time channel {gname}/{tc.name}: unit {unit!r} is not a time unit vfcli knows "
                             f"({time_units_text()})", p)
    t = np.asarray(tc[:], dtype=float) * scale
    if t.shape != (len(ch),):
        raise InputDataError(f"time channel {gname}/{tc.name} holds {t.size} samples, {gname}/{ch.name} {len(ch)}", p)
    return uniform_rate(t, p)


def _check_tdms_complete(p: Path, tdms, gname: str, ch, n: int, warned: list[str]) -> None:
    """Refuse a channel with fewer samples than the file promises (a truncated TDMS).

    npTDMS reads a truncated last segment with only a logged warning ("less data than
    expected"), which vfcli turns into a refusal; a channel shorter than another channel of
    its group at the same sample interval (a DAQ samples them together) is refused too.
    """
    name = f"{gname}/{ch.name}"
    trunc = [w for w in warned if "less data than expected" in w or "not a multiple of the chunk" in w]
    if trunc:
        said = trunc[0].split(", will attempt")[0].split(". Will attempt")[0]
        raise InputDataError(f"channel {name} is truncated ({n} samples read; npTDMS: {said[:120]})", p)
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


