"""The collision candidate's evidence on phantoms run through the whole pipeline, as a user runs it.

`vfcli synth --effect contact` (the folds pressed together and kept from interpenetrating by an
exact contact solution) and a null phantom whose glottis closes without the folds being pressed
past the midplane (closed_fraction = 0), each through ingest, sync, flow, mesh, a short optimize
(the paper's free force field, 3x3x10 one-sided) and `vfcli diagnose`: the contact line reports the
no-contact fit's folds crossing the midplane during the closed phase on the contact phantom (0.31 mm
on seed 41, 0.5 mm on seed 31), and no lead on the null, whose short fit crosses too (0.23 mm on
seed 42, 0.17 mm on seed 33: the fit's overshoot where the glottis closes; the crossing alone does not
separate the two).  Seeds 41 and 42 (outside the reserved panels).
"""
from __future__ import annotations

import re

import pytest

from conftest import run_vfcli

PHANTOM = [
    "synth.duration_s=0.03", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]
FIT = ["--setup", "3x3x10-one-sided", "--set", "optimize.n_frames=60", "--set", "optimize.first_frame=120",
       "--set", "mesh.target_edge_mm=2.5", "--set", "optimize.max_iterations=3", "--run", "fit"]
CROSSING = re.compile(r"cross the midplane (?:by up to ([0-9.e-]+) mm|not at all) during the closed phase")


def _diagnose(d, effect: str, seed: int, *extra: str) -> str:
    raw, store = d / "raw", d / "rec.h5"
    steps = [
        ["synth", raw, "--effect", effect, "--seed", str(seed), *sum((["--set", s] for s in [*PHANTOM, *extra]), [])],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config",
         raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
        ["flow", store],
        ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, *FIT],
        ["diagnose", store, "--run", "fit"],
    ]
    for args in steps:
        res = run_vfcli(*args, timeout=3000)
        assert res.returncode == 0, (args[0], res.stderr)
    return next(line for line in res.stdout.splitlines() if line.startswith("contact: "))


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_the_no_contact_fit_of_a_contact_phantom_crosses_the_midplane_while_closed(tmp_path):
    line = _diagnose(tmp_path, "contact", 41)
    print(line)
    m = CROSSING.search(line)
    assert m and m.group(1) and float(m.group(1)) > 0.2, line        # measured 0.31 mm (seed 41), 0.5 (seed 31)
