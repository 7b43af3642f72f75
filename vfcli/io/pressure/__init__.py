"""Subglottal pressure recordings: one reader per format, the shared record and checks, and writers.

* :mod:`~vfcli.io.pressure.record` -- :class:`PressureRecord`, the units understood and the
  checks every reader's samples pass (:func:`~vfcli.io.pressure.record.finish`);
* :mod:`~vfcli.io.pressure.tdms` -- TDMS (npTDMS), reader and writer;
* :mod:`~vfcli.io.pressure.csvfile` -- CSV, reader and writer;
* :mod:`~vfcli.io.pressure.wav` -- WAV (scipy.io.wavfile), reader.

Every reader returns a :class:`PressureRecord` ``(samples, fs, t0, unit, source)``:
samples in Pa (float64), sampling rate in Hz, time of the first sample in s
(relative to the DAQ's own start: TDMS ``wf_start_offset``, CSV first time value),
the unit the file stated, and a one-line description of the source. Each format module's
docstring says which layouts it accepts.

Units understood: Pa, hPa, kPa, mbar, bar, psi, cmH2O, mmH2O, inH2O, mmHg; and V, mV, a transducer's output, with
its calibration (:class:`~vfcli.io.pressure.record.Transducer`).
"""
from __future__ import annotations

from pathlib import Path

from vfcli.errors import InputDataError
from vfcli.io._common import require_file
from vfcli.io.pressure.csvfile import read_csv, write_pressure_csv
from vfcli.io.pressure.record import PA_PER_UNIT, PressureRecord, Transducer, pa_per_unit
from vfcli.io.pressure.tdms import read_tdms, write_pressure_tdms
from vfcli.io.pressure.wav import WAV_PA_PER_FULL_SCALE, read_wav

__all__ = ["PA_PER_UNIT", "PressureRecord", "Transducer", "WAV_PA_PER_FULL_SCALE", "pa_per_unit", "read_pressure",
           "write_pressure_csv", "write_pressure_tdms"]


def read_pressure(
    path: str | Path,
    group: str | None = None,
    channel: str | int | None = None,
    unit: str | None = None,
    wav_pa_per_full_scale: float = WAV_PA_PER_FULL_SCALE,
    kind: str | None = None,
    transducer: Transducer | None = None,
) -> PressureRecord:
    """Read a subglottal pressure recording (TDMS, CSV or WAV, by extension).

    Parameters
    ----------
    path : str or Path
    group, channel : str or None
        TDMS group/channel names (``channel`` is the column name for CSV and
        the channel index for WAV). Defaults: see the format modules.
    unit : str or None
        Unit of the values when the file does not say (CSV, TDMS without
        ``unit_string``); when the file does say, it must agree.
    wav_pa_per_full_scale : float
        WAV calibration, Pa at digital full scale.
    kind : {'tdms', 'csv', 'wav'} or None
        Force the format; default from the extension.
    transducer : Transducer or None
        The calibration of a record in V or mV (a transducer's output); None: such a record is refused.

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
        return read_tdms(p, group, channel, unit, transducer)
    if kind in ("csv", "txt"):
        return read_csv(p, channel, unit, transducer)
    if kind == "wav":
        return read_wav(p, channel, wav_pa_per_full_scale)
    raise InputDataError(f"unsupported pressure file type {p.suffix!r} (tdms, csv, wav)", p)
