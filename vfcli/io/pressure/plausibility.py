"""What a subglottal pressure record must be for vfcli to use it: a rate that resolves the fundamental,
and a level that reads as a phonation pressure in the unit the record was read in.

Two judgements, each stated where it is used (docs/input-checks.md lists them):

* the fundamental search (vfcli.sync.f0) looks up to 0.45 of the sampling rate, so a record sampled below
  ``sync.f0_max_hz / 0.45`` cannot show the highest fundamental the config admits: refused (a 100 Hz record
  crashed ingest-ldv's rate check; the rig samples at 50 kHz);
* synthetic folds oscillate at mean subglottal pressures of 300-3000 Pa with swings of tens to hundreds of Pa
  (the physical set-up note), so a record whose mean and swing both stay below :data:`MIN_PHONATION_PA` reads
  as a file in kPa or bar taken as Pa: a warning, never a refusal (a bench test at a tiny pressure is real).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.errors import InputDataError
from vfcli.io.pressure.record import PressureRecord

#: A record whose |mean| and swing (5th to 95th percentile) are both below this, Pa, is no phonation pressure
#: in Pa (the folds need hundreds of Pa to oscillate): 20 Pa is 15 times below the lowest mean pressure of the
#: physical set-up note and catches a kPa file read as Pa (a 0.3-3 kPa mean reads 0.3-3 "Pa").
MIN_PHONATION_PA = 20.0


def check_pressure_rate(fs_hz: float, f0_max_hz: float, path: str | Path) -> None:
    """Refuse a record sampled at ``fs_hz`` Hz too slowly to show a fundamental up to ``f0_max_hz`` Hz (the f0
    search's reach, :data:`vfcli.sync.f0.F0_SEARCH_FRACTION` of the rate)."""
    from vfcli.sync.f0 import F0_SEARCH_FRACTION   # scipy: imported when a pressure is read

    if F0_SEARCH_FRACTION * fs_hz < f0_max_hz:
        raise InputDataError(
            f"the pressure is sampled at {fs_hz:g} Hz: its fundamental can be found up to {F0_SEARCH_FRACTION * fs_hz:g} Hz "
            f"only, below sync.f0_max_hz = {f0_max_hz:g} Hz; check the file's sampling rate or time unit (the rig "
            f"records at tens of kHz), or lower sync.f0_max_hz if the folds oscillate that slowly", path)


def pressure_unit_warnings(rec: PressureRecord) -> list[str]:
    """Warnings (one line each) about the unit a record was read in: stated nowhere, or a level no phonation
    pressure has in Pa."""
    out = []
    if rec.unit_source == "assumed":
        out.append("the file states no pressure unit: read as Pa; if it is another, set ingest_hsc.pressure_unit "
                   "(e.g. `--set ingest_hsc.pressure_unit=kPa`) and rerun")
    lo, hi = np.percentile(rec.samples, [5.0, 95.0])
    mean = float(np.mean(rec.samples))
    if abs(mean) < MIN_PHONATION_PA and hi - lo < MIN_PHONATION_PA:
        out.append(f"the pressure's mean ({mean:.3g} Pa) and swing ({hi - lo:.3g} Pa, 5th to 95th percentile) are both "
                   f"below {MIN_PHONATION_PA:g} Pa, read in {rec.unit}: no phonation pressure is that small; is the "
                   "file in kPa or bar (ingest_hsc.pressure_unit), or a transducer's output in V (pressure_unit = "
                   "'V' with ingest_hsc.pressure_pa_per_volt and pressure_zero_volts)?")
    return out
