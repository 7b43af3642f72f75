"""WAV pressure recordings (scipy.io.wavfile), with the chunk-size check scipy only warns about.

Sampling rate from the header; integer samples are divided by full scale (int16: 32768,
int32: 2**31, uint8: centred on 128; float: 1.0) and multiplied by ``wav_pa_per_full_scale``
(default :data:`WAV_PA_PER_FULL_SCALE` = 10 kPa, a typical transducer range: set it to your
amplifier's calibration). ``channel`` picks a column of a multi-channel WAV by index; a WAV of more
than one channel without it is refused (as TDMS and CSV refuse a channel they cannot choose).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io.pressure.record import PressureRecord, finish

#: Default WAV calibration: pascals at digital full scale.
WAV_PA_PER_FULL_SCALE = 10_000.0


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


def read_wav(p: Path, channel: str | int | None, pa_per_fs: float) -> PressureRecord:
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
    if data.ndim == 2 and data.shape[1] == 1:
        data = data[:, 0]
    if data.ndim == 2:
        if channel is None:
            raise InputDataError(f"cannot choose the pressure channel among the {data.shape[1]} WAV channels: set "
                                 "ingest_hsc.pressure_channel to its index (0, 1, ...)", p)
        idx = int(channel)
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
    return finish(x * pa_per_fs, float(fs), 0.0, "Pa",
                   f"WAV {p.name} ({data.dtype}, {pa_per_fs:g} Pa full scale)", p, "config")
