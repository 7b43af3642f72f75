"""A small optimised phantom store shared by the export and report tests, and the meshed store it
grows from (shared by tests/test_optimize_stage.py): each built once per test run."""
from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

from _small_phantom import SMALL_160
from conftest import run_vfcli, shared_product
from vfcli.store.parts import copy_store

#: the small phantom's synth settings (tests/_small_phantom.py's SMALL_160, as tests/_diagnose_phantom.py's)
PHANTOM = SMALL_160
WINDOW = ["--set", "optimize.n_frames=6", "--set", "optimize.first_frame=20"]


def sets(values: list[str]) -> list[str]:
    return sum((["--set", s] for s in values), [])


def _run_steps(steps: list[list]) -> None:
    for args in steps:
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr[-2000:])


def _build_meshed(d: Path) -> None:
    raw, store = d / "raw", d / "rec.h5"
    _run_steps([
        ["synth", raw, "--seed", "5", *sets(PHANTOM)],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config", raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
        ["flow", store],
        ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
    ])


def meshed_store(tmp_path_factory) -> tuple[Path, Path]:
    """(store, raw folder) of the phantom seed 5 (:data:`PHANTOM`) through /hsc, /ldv, /sync, /flow,
    /fields and /mesh (target edge 2.5 mm), as the real commands write them. Built once per test
    run and shared: read-only (copy the store with :func:`vfcli.store.parts.copy_store` to write)."""
    d = shared_product(tmp_path_factory, "meshed_seed5", _build_meshed)
    return d / "rec.h5", d / "raw"


def _add_runs(d: Path, meshed: Path) -> None:
    store = d / "rec.h5"
    copy_store(meshed, store)
    (d / "raw").symlink_to(meshed.parent / "raw", target_is_directory=True)  # its raw files, beside it
    _run_steps([
        ["optimize", store, "--run", "pressure", *WINDOW, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, "--run", "free", "--setup", "3x3x10-one-sided", *WINDOW, "--set", "mesh.target_edge_mm=2.5",
         "--set", "optimize.max_iterations=4"],
    ])


def optimised_store(tmp_path_factory) -> Path:
    """Path of a store with /hsc ... /mesh and two runs: 'pressure' (default loads) and 'free' (paper's field);
    its raw folder is the store's sibling ``raw``.

    Built once per test run (:func:`meshed_store` and two `vfcli optimize`); tests copy it before writing.
    """
    # VFCLI_TEST_STORE_DIR keeps the store between sessions while developing (never set in CI)
    keep = os.environ.get("VFCLI_TEST_STORE_DIR")
    if not keep:
        meshed, _ = meshed_store(tmp_path_factory)
        return shared_product(tmp_path_factory, "export_store", lambda d: _add_runs(d, meshed)) / "rec.h5"
    d = Path(keep) / "export_store"
    if not (d / "done").exists():
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        _build_meshed(d / "meshed")
        _add_runs(d, d / "meshed" / "rec.h5")
        (d / "done").touch()
    return d / "rec.h5"


def _write_report(d: Path, store: Path) -> None:
    """`vfcli report` of a copy of ``store`` at d / "rec.h5" into d / "report.html"; the copy's bytes and
    time stamp must be what they were (the report writes nothing into the store)."""
    copy = d / "rec.h5"
    copy_store(store, copy)
    before = hashlib.sha256(copy.read_bytes()).hexdigest(), copy.stat().st_mtime_ns
    res = run_vfcli("report", copy, "--out", d / "report.html")
    assert res.returncode == 0, res.stderr
    assert (hashlib.sha256(copy.read_bytes()).hexdigest(), copy.stat().st_mtime_ns) == before


def optimised_report(tmp_path_factory) -> Path:
    """The page `vfcli report` writes of (a copy of) :func:`optimised_store`, report.html beside that copy
    (rec.h5), checked to leave the store as it was. Built once per test run for tests/test_report.py and
    tests/test_report_browser.py (the same command on the same store: a report takes seconds of figures);
    read-only: tests copy the store or the page before changing either."""
    store = optimised_store(tmp_path_factory)
    return shared_product(tmp_path_factory, "export_report", lambda d: _write_report(d, store)) / "report.html"
