"""A small optimised phantom store shared by the export and report tests (built once per session)."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from conftest import run_vfcli

PHANTOM = [
    "synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]
WINDOW = ["--set", "optimize.n_frames=6", "--set", "optimize.first_frame=20"]


def sets(values: list[str]) -> list[str]:
    return sum((["--set", s] for s in values), [])


def optimised_store(tmp_path_factory) -> Path:
    """Path of a store with /hsc ... /mesh and two runs: 'pressure' (default loads) and 'free' (paper's field).

    Built once per test session under pytest's base temp folder; tests copy it before writing.
    """
    # VFCLI_TEST_STORE_DIR keeps the store between sessions while developing (never set in CI)
    d = Path(os.environ.get("VFCLI_TEST_STORE_DIR") or tmp_path_factory.getbasetemp()) / "export_store"
    store = d / "rec.h5"
    if (d / "done").exists():
        return store
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    raw = d / "raw"
    steps = [
        ["synth", raw, "--seed", "5", *sets(PHANTOM)],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config", raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
        ["flow", store],
        ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, "--run", "pressure", *WINDOW, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, "--run", "free", "--setup", "3x3x10-one-sided", *WINDOW, "--set", "mesh.target_edge_mm=2.5",
         "--set", "optimize.max_iterations=4"],
    ]
    for args in steps:
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr[-2000:])
    (d / "done").touch()
    return store
