"""A short phantom recording taken through the pipeline up to a fitted run, for the diagnose tests.

:func:`fitted_phantom` runs `vfcli synth` (the small settings of :data:`PHANTOM`, the given seed and
synth options), ingest, sync, flow, mesh and optimize (the given options) as a user does;
:func:`shared_diagnosed_phantom` builds one, and its diagnosis, once per test run for every test
file that asks for it.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

from _small_phantom import SMALL_160
from conftest import run_vfcli, shared_product

#: a short, small phantom (0.02 s, 160 x 160 px): tests/_small_phantom.py's SMALL_160, so that a raw
#: folder :func:`_small_phantom.shared_raw` makes of it serves here too
PHANTOM = SMALL_160

#: the paper's free force field, short (60 frames, 3 iterations) on a coarse mesh, stored as the run "fit"
#: (tests/test_diagnose_stage.py and tests/test_contact_phantom.py share the fitted seed 41 with contact)
ONE_SIDED_FIT = ["--setup", "3x3x10-one-sided", "--set", "optimize.n_frames=60", "--set", "optimize.first_frame=120",
                 "--set", "mesh.target_edge_mm=2.5", "--set", "optimize.max_iterations=3", "--run", "fit"]
#: the contact phantom both files diagnose: seed 41 (outside the reserved panels), `--effect contact`
CONTACT_PHANTOM = (41, ("--effect", "contact"))


def fitted_phantom(d: Path, seed: int, fit: list[str], synth: tuple[str, ...] = (), raw: Path | None = None) -> Path:
    """The store d / "rec.h5" of the phantom ``seed`` (raw files in d / "raw"), fitted by
    `vfcli optimize` with the options ``fit``; ``synth``: extra `vfcli synth` options (--effect ...).
    ``raw``: the phantom's raw folder made already (:func:`_small_phantom.shared_raw` of ``seed`` with
    :data:`PHANTOM`, read-only), read from there instead of synthesised into d / "raw"."""
    store = d / "rec.h5"
    steps = [] if raw is not None else [
        ["synth", d / "raw", "--seed", str(seed), *synth, *sum((["--set", s] for s in PHANTOM), [])]]
    raw = raw if raw is not None else d / "raw"
    steps += [
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


def shared_diagnosed_phantom(tmp_path_factory, seed: int, fit: list[str], synth: tuple[str, ...] = ()) -> Path:
    """The folder of the store :func:`fitted_phantom` makes of ``seed`` with ``fit`` (which stores the
    run "fit", as :data:`ONE_SIDED_FIT` does) and ``synth``, then `vfcli diagnose --run fit --map
    maps/map.png` of it: rec.h5 (fitted and diagnosed), maps/map.png, the raw files, and the diagnosis' standard
    output in stdout.txt. Built once per test run (:func:`conftest.shared_product`) for every test file
    that asks for the same one; read-only (a test that writes copies the store with
    :func:`vfcli.store.parts.copy_store`)."""
    def build(d: Path) -> None:
        store = fitted_phantom(d, seed, fit, synth)
        # the map in a folder not there yet: --map's folder is made (it was a traceback after the whole diagnosis)
        res = run_vfcli("diagnose", store, "--run", "fit", "--map", d / "maps" / "map.png", timeout=3000)
        assert res.returncode == 0, res.stderr
        (d / "stdout.txt").write_text(res.stdout)

    key = hashlib.sha256(repr((seed, list(fit), list(synth))).encode()).hexdigest()[:12]
    return shared_product(tmp_path_factory, f"diagnosed-seed{seed}-{key}", build)
