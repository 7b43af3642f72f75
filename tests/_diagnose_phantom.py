"""A short phantom recording taken through the pipeline up to a fitted run, for the diagnose tests.

:func:`fitted_phantom` runs `vfcli synth` (the small settings of :data:`PHANTOM`, the given seed and
synth options), ingest, sync, flow, mesh and optimize (the given options) as a user does.
"""
from __future__ import annotations

from pathlib import Path

from conftest import run_vfcli

#: a short, small phantom (0.03 s, 160 x 160 px)
PHANTOM = [
    "synth.duration_s=0.03", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]


def fitted_phantom(d: Path, seed: int, fit: list[str], synth: tuple[str, ...] = ()) -> Path:
    """The store d / "rec.h5" of the phantom ``seed`` (raw files in d / "raw"), fitted by
    `vfcli optimize` with the options ``fit``; ``synth``: extra `vfcli synth` options (--effect ...)."""
    raw, store = d / "raw", d / "rec.h5"
    steps = [
        ["synth", raw, "--seed", str(seed), *synth, *sum((["--set", s] for s in PHANTOM), [])],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config", raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
        ["flow", store],
        ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, *fit],
    ]
    for args in steps:
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    return store
