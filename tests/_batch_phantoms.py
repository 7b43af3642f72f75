"""Tiny phantom recordings for the batch tests (test_batch.py, test_examples_batch.py, test_injected_map.py)."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from conftest import ROOT, shared_product

#: A phantom small enough for a batch test: 100 frames of 128 x 128 px holding 2.5 glottal cycles at 250 Hz
#: (sync needs 2). `vfcli synth` 4.9 s, `vfcli run` with :data:`SMALL_OPTIMIZE` 9.6 s (flow 5.3 s); at the
#: synth's 120 Hz it needed 200 frames: 9.0 s and 15.2 s (flow 7.6 s) (session 33, the suite's time).
TINY = ["synth.f0_hz=250", "synth.duration_s=0.01", "synth.ldv_epoch_s=0.04", "synth.target_edge_mm=2.0",
        "synth.n_phase=64", "synth.width_px=128", "synth.height_px=128", "synth.px_per_mm=8", "synth.supersample=1"]
#: recording.toml's [optimize] for a small fit that holds in a tiny phantom (20 frames, 3 iterations).
SMALL_OPTIMIZE = '\n[optimize]\nn_frames = 20\nmax_iterations = 3\nsetup = "3x3x10-one-sided"\nloads = "free"\nuncertainty = false\n'
#: the fitted mesh's edge for that fit, mm: the synth writes the default 1.5 mm into recording.toml, where
#: optimize's fixed cost (the elastic model and the basis solves, whatever the frames or iterations) was
#: 3.7 s of CPU; 2.5 mm (the diagnose and export tests' fitted mesh) takes 0.8 s
SMALL_EDGE_MM = 2.5


def synth(out: Path, seed: int) -> subprocess.Popen:
    """Start `vfcli synth` of a tiny phantom into ``out`` (wait on the returned process)."""
    args = [sys.executable, "-m", "vfcli.cli.main", "synth", str(out), "--seed", str(seed), "-q"]
    for s in TINY:
        args += ["--set", s]
    return subprocess.Popen(args, env={**os.environ, "PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE, text=True)


def tiny_raw(tmp_path_factory, seed: int) -> Path:
    """The raw folder ``rec<seed>`` of the tiny phantom ``seed`` (:data:`TINY`), made by `vfcli synth`
    once per test run and shared by the batch tests (read-only: copy it before changing a file)."""
    def build(d: Path) -> None:
        proc = synth(d / f"rec{seed}", seed)
        assert proc.wait() == 0, proc.stderr.read()

    return shared_product(tmp_path_factory, f"tiny-{seed}", build) / f"rec{seed}"


def small_fit_raw(tmp_path_factory, seed: int, dest: Path) -> Path:
    """A copy at ``dest`` of the tiny phantom ``seed``'s raw folder (:func:`tiny_raw`), its recording.toml
    set for a small fit: :data:`SMALL_OPTIMIZE` appended and the mesh's edge :data:`SMALL_EDGE_MM`."""
    shutil.copytree(tiny_raw(tmp_path_factory, seed), dest)
    config = dest / "recording.toml"
    text, n = re.subn(r"(?m)^target_edge_mm = .*$", f"target_edge_mm = {SMALL_EDGE_MM}", config.read_text())
    assert n == 1, "the synth's recording.toml has no [mesh] target_edge_mm"
    config.write_text(text + SMALL_OPTIMIZE)
    return dest
