"""``examples/recording.toml``, the example recording config `vfcli schemas --example` writes."""
from __future__ import annotations

from vfcli.calibration import MEASURED_SETTINGS
from vfcli.config import RecordingConfig


def example_toml() -> str:
    """``examples/recording.toml``: every setting with its default (written by `vfcli schemas`), those of
    :data:`vfcli.calibration.MEASURED_SETTINGS` commented out: a value written out counts as set, and their warnings would be
    silenced in a lab that starts from the example (hF, session 37)."""
    import tomli_w

    data = RecordingConfig().model_dump(mode="json", exclude_none=True)
    section, lines = "", []
    for line in tomli_w.dumps(data).splitlines():
        if line.startswith("["):
            section = line.strip("[]")
        key = line.split(" = ")[0]
        if f"{section}.{key}" in MEASURED_SETTINGS:
            line = f"# {line}    # your rig's value: measure it and set it (left unset, vfcli warns)"
        lines.append(line)
    return ("# A recording config with every default spelled out; see schemas/recording.schema.json.\n"
            "# Values a lab measures, commented out until you set yours: camera.px_per_mm (calibration target),\n"
            "# ingest_hsc.wav_full_scale_pa (a WAV pressure's amplifier); camera.fps_hz (else from the video).\n\n"
            + "\n".join(lines) + "\n")
