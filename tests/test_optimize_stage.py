"""`vfcli optimize` on a phantom as a user runs it: history in the store, the camera pose
found from the gap, and --resume after SIGKILL ending where an uninterrupted run ends."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import ROOT, run_vfcli
from vfcli.stages.optimize import checkpoint_path
from vfcli.store import Store, read_truth

PHANTOM = [
    "synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]
FIT = ["--setup", "3x3x10-one-sided", "--set", "optimize.n_frames=12", "--set", "optimize.first_frame=20",
       "--set", "mesh.target_edge_mm=2.5"]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("opt")
    raw, store = d / "raw", d / "rec.h5"
    steps = [
        ["synth", raw, "--seed", "5", *sum((["--set", s] for s in PHANTOM), [])],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config", raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
        ["flow", store],
        ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
    ]
    for args in steps:
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    return store, raw


def test_optimize_stores_a_decreasing_history_and_the_motion(store, tmp_path):
    path, raw = store
    plot = tmp_path / "conv.png"
    res = run_vfcli("optimize", path, *FIT, "--set", "optimize.max_iterations=4", "--run", "short", "--plot", plot)
    assert res.returncode == 0, res.stderr
    with Store(path).read() as r:
        total = r.read("optimize", "history_total", "short")
        disp = r.read("optimize", "displacements", "short")
        names = r.read("optimize", "parameter_names", "short")
        attrs = r.attrs("optimize", "short")
        n_nodes = r.read("mesh", "nodes").shape[0]
    assert len(total) == 5 and np.all(np.diff(total) <= 0) and total[-1] < 0.8 * total[0]
    assert disp.shape == (13, n_nodes, 3) and np.abs(disp).max() > 0.01
    assert len(names) == 780 and names[0].startswith("fold0/inferior/x")
    assert plot.stat().st_size > 1000
    truth = read_truth(raw / "truth.h5", [])[1]
    assert abs(attrs["camera_rotation_deg"] - truth["camera_rotation_deg"]) < 0.5
    assert np.abs(attrs["camera_offset_px"] - truth["camera_offset_px"]).max() < 4.0
    again = run_vfcli("optimize", path, *FIT, "--set", "optimize.max_iterations=4", "--run", "short")
    assert "up to date" in again.stdout


def test_resume_after_sigkill_ends_where_an_uninterrupted_run_ends(store):
    path, _ = store
    opts = [*FIT, "--set", "optimize.max_iterations=7"]
    assert run_vfcli("optimize", path, *opts, "--run", "whole").returncode == 0
    ckpt = checkpoint_path(path, "killed")
    proc = subprocess.Popen([sys.executable, "-m", "vfcli.cli.main", "optimize", str(path), *map(str, opts), "--run", "killed"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if ckpt.exists():
            with np.load(ckpt) as z:
                if int(z["iteration"]) >= 3:
                    break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with Store(path).read() as r:
        assert not r.has_stage("optimize", "killed")  # nothing half-written in the store
    res = run_vfcli("optimize", path, *opts, "--run", "killed", "--resume")
    assert res.returncode == 0, res.stderr
    assert not ckpt.exists()
    with Store(path).read() as r:
        a = r.read("optimize", "controls", "whole")
        b = r.read("optimize", "controls", "killed")
        ha = r.read("optimize", "history_total", "whole")
        hb = r.read("optimize", "history_total", "killed")
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hb, ha, rtol=1e-12)
