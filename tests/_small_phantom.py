"""A small `vfcli synth` phantom and a store holding its /hsc, for tests of the later stages."""
from __future__ import annotations

import hashlib
from pathlib import Path

from conftest import run_vfcli, shared_product

#: A short, small phantom (200 frames of 112 x 112 px at 6 px/mm; 0.03 s vibrometer epochs).
SMALL = ["synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
         "synth.width_px=112", "synth.height_px=112", "synth.px_per_mm=6", "synth.supersample=1"]
#: A small phantom of 200 frames of 160 x 160 px at 9 px/mm on SMALL's coarse mesh and phase sampling
#: (5 s to make; 14 s at the synth's default ones): tests/test_store_integrity.py's and
#: tests/test_hostile_rate.py's and tests/test_diagnose_refit_phantom.py's null (seed 34, shared_raw).
SMALL_160 = ["synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
             "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1"]


def phantom_with_hsc(folder: Path, seed: int, sets: list[str]) -> tuple[Path, Path]:
    """`vfcli synth` into FOLDER/raw with ``--set`` SETS, then `vfcli ingest-hsc` of its video and
    pressure into FOLDER/hsc.h5; (raw folder, store)."""
    raw, store = folder / "raw", folder / "hsc.h5"
    res = run_vfcli("synth", "-q", raw, "--seed", str(seed), *sum((["--set", s] for s in sets), []))
    assert res.returncode == 0, res.stderr
    res = run_vfcli("ingest-hsc", "-q", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                    "--config", raw / "recording.toml")
    assert res.returncode == 0, res.stderr
    return raw, store


def shared_phantom_with_hsc(tmp_path_factory, seed: int, sets: list[str]) -> tuple[Path, Path]:
    """:func:`phantom_with_hsc` built once per test run for each (seed, sets) and shared by the
    test files that ask for the same one (read-only: tests copy the store before writing)."""
    key = hashlib.sha256(repr(sorted(sets)).encode()).hexdigest()[:12]
    d = shared_product(tmp_path_factory, f"hsc-seed{seed}-{key}", lambda f: phantom_with_hsc(f, seed, sets))
    return d / "raw", d / "hsc.h5"


def shared_raw(tmp_path_factory, seed: int, sets: list[str]) -> Path:
    """The raw folder `vfcli synth --seed SEED` with ``--set`` SETS writes, made once per test run
    for each (seed, sets) and shared by the test files that ask for the same one (read-only)."""
    def build(d: Path) -> None:
        res = run_vfcli("synth", "-q", d / "raw", "--seed", str(seed), *sum((["--set", s] for s in sets), []))
        assert res.returncode == 0, res.stderr

    key = hashlib.sha256(repr(sorted(sets)).encode()).hexdigest()[:12]
    return shared_product(tmp_path_factory, f"raw-seed{seed}-{key}", build) / "raw"
