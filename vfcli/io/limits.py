"""Plausible ranges of what the instruments' files may state, and the checks against them.

A value outside its range cannot come from the rig of the reference notes "The physical
set-up: numbers to build with" (or from any rig vfcli is built for): the readers refuse it
with one line and exit 3 instead of storing it. The ranges are deliberately wide (orders of magnitude around the rig's values)
so that only impossible or mis-scaled values are refused; docs/input-checks.md lists them.

Sources of each range (those notes, and "The instruments' file formats", unless said otherwise):

* video frame rate: the SA-X2 records 10,000 frames/s; high-speed cameras reach about 1e6
  frames/s at small frames, ``camera.fps_hz`` allows up to 1e7. Below 1 frame/s a video
  cannot show a 50-500 Hz phonation.
* Photron start frame (frames from the trigger): a camera counter, bounded like
  ``ingest_hsc.first_frame`` (1e9 frames: more than a day at 10 kHz).
* vibrometer sampling rate: 50 kHz in the paper. `sync` fits ``sync.n_harmonics`` (10) harmonics
  of f0 up to ``sync.f0_max_hz`` (500 Hz), so anything below 10 kHz cannot be this kind of
  recording (a rate written 1 kHz instead of 50 kHz is refused). Upper bound 25.6 MHz: an
  estimate far above any vibrometer acquisition rate (est.).
* vibrometer point extent: 374 points on the superior surface of two folds 15-17 mm long and
  5-10 mm deep each; a scan spans a few mm to about 35 mm. Allowed: 0.2-100 mm, so a file in
  metres read as mm (x 1e-3) or mm read as metres (x 1e3), or coordinates scaled by 1e6,
  is refused.
* vibrometer velocity: superior-surface velocities 0.1-0.5 m/s, closing velocities up to
  1.6 m/s. Allowed: |v| <= 100 m/s, far above any vocal-fold velocity (est.).
* pressure: subglottal pressure 300-3000 Pa. Allowed: |p| <= 1e6 Pa (10 bar, est.: no
  phonation rig holds it); the sampling rate 1 Hz-10 MHz (the paper: 50 kHz).
  A vibrometer reference channel in a pressure unit has the same bound; in volts (or a unit
  vfcli does not know) |x| <= 1e6 (a transducer amplifier gives +-10 V).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.errors import InputDataError

#: Video frame rate, frames/s (inclusive range).
FPS_RANGE = (1.0, 1e7)
#: |Photron start frame|, frames.
MAX_ABS_START_FRAME = 10**9
#: Vibrometer sampling rate, Hz.
LDV_FS_RANGE = (1e4, 2.56e7)
#: Extent (largest of the x and y spans) of the vibrometer's scan points, mm.
LDV_EXTENT_MM = (0.2, 100.0)
#: Largest |velocity| of a vibrometer sample, mm/s.
LDV_MAX_ABS_VELOCITY_MM_S = 1e5
#: Largest |pressure| of a sample, Pa.
MAX_ABS_PRESSURE_PA = 1e6
#: Largest |sample| of an LDV reference channel not in a pressure unit (volts: a transducer
#: amplifier gives +-10 V), in the channel's own unit.
MAX_ABS_REFERENCE = 1e6
#: Pressure sampling rate, Hz.
PRESSURE_FS_RANGE = (1.0, 1e7)


def check_range(value: float, lo: float, hi: float, what: str, unit: str,
                 path: str | Path | None) -> float:
    """Return ``value`` as a float if it is finite and within ``[lo, hi]``, else raise.

    Raises
    ------
    InputDataError
        Naming ``what``, the value, its unit and the range.
    """
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InputDataError(f"{what} {value!r} is not a number", path) from None
    if not (np.isfinite(v) and lo <= v <= hi):
        raise InputDataError(f"{what} {v:g} {unit} is impossible for this kind of recording "
                             f"(plausible: {lo:g}..{hi:g} {unit}; vfcli/io/limits.py)", path)
    return v


def check_abs_max(values: np.ndarray, limit: float, what: str, unit: str,
                  path: str | Path | None) -> None:
    """Raise InputDataError when a finite sample of ``values`` exceeds ``limit`` in magnitude."""
    values = np.asarray(values)
    if values.size == 0:
        return
    peak = float(np.max(np.abs(values)))
    if peak > limit:
        i = np.unravel_index(int(np.argmax(np.abs(values))), values.shape)
        raise InputDataError(
            f"{what} reaches {peak:g} {unit} (index {tuple(int(k) for k in i)}), beyond the "
            f"plausible {limit:g} {unit} (mis-scaled or corrupt samples? vfcli/io/limits.py)", path)


def check_ldv_extent(coords_mm: np.ndarray, path: str | Path | None, hint: str = "") -> None:
    """Raise InputDataError unless the scan points span a plausible extent for the folds.

    Parameters
    ----------
    coords_mm : (P, 3) float
        Scan point coordinates, mm.
    hint : str
        Appended to the message (e.g. which config field sets the unit).
    """
    if coords_mm.shape[0] < 2:
        return
    span = float(np.max(np.ptp(coords_mm[:, :2], axis=0)))
    lo, hi = LDV_EXTENT_MM
    if not lo <= span <= hi:
        raise InputDataError(
            f"the scan points span {span:.4g} mm, implausible for vocal folds (plausible: "
            f"{lo:g}..{hi:g} mm): wrong length unit or scaled coordinates?{hint}", path)
