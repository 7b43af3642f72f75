"""Calibration values a lab measures for its own rig: which ones a recording's config leaves at their
default, and the warning that says so (every length and velocity from the video scales with them)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from vfcli.config import RecordingConfig


#: Settings a lab measures for its own setup; left at the default they silently scale results.
CALIBRATION: dict[str, tuple[str, str]] = {
    "camera.px_per_mm": ("px/mm", "measure it on a calibration target in the folds' plane"),
}
#: the full scale of a WAV pressure (a WAV states no unit): `ingest-hsc` warns while it is left at its default
WAV_FULL_SCALE = "ingest_hsc.wav_full_scale_pa"
#: every setting a lab measures for its own rig, warned about while a config leaves it at its default: the
#: example config (vfcli/example_config.py) leaves them unset
MEASURED_SETTINGS = (*CALIBRATION, WAV_FULL_SCALE)


def default_calibration(stored: RecordingConfig, effective: RecordingConfig,
                        keys: Iterable[str] = tuple(CALIBRATION)) -> list[str]:
    """The ``keys`` (``section.field``; default :data:`CALIBRATION`'s) that no config file or ``--set`` gave a
    value: they are at their default (a value equal to the default counts as given when the stored config or this run's
    ``--set`` sets it)."""
    out = []
    for key in keys:
        section, name = key.split(".")
        model = getattr(effective, section)
        default = type(model).model_fields[name].default
        given = name in getattr(stored, section).model_fields_set or name in model.model_fields_set
        if getattr(model, name) == default and not given:
            out.append(key)
    return out


def calibration_warnings(stored: RecordingConfig, effective: RecordingConfig, store: str | Path) -> list[str]:
    """One line per :func:`default_calibration` key: its default value and how to set it."""
    lines = []
    for key in default_calibration(stored, effective):
        section, name = key.split(".")
        value = getattr(getattr(effective, section), name)
        unit, how = CALIBRATION[key]
        lines.append(f"{key} is not set: the default {value:g} {unit} is used, and every length and velocity from "
                     f"the video scales with it; {how} and set it with `vfcli config {store} --set {key}=VALUE` "
                     f"(or in recording.toml), then rerun")
    return lines
