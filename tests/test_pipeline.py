"""Ingest and sync a phantom as a user would (real CLI, real files), scored against truth.h5,
and every kind of bad input: one clear line, a distinct exit code, the store untouched."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from conftest import run_vfcli
from vfcli.io.ldv.read import read_ldv
from vfcli.io.ldv.write import write_ldv_uff
from vfcli.io.pressure import write_pressure_csv
from vfcli.store import Store, read_truth
from vfcli.store.parts import copy_store
from vfcli.synth.scoring import sync_offset_error

PHANTOM = [
    "synth.duration_s=0.03", "synth.ldv_epoch_s=0.06", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]


def _sets(items):
    return sum((["--set", s] for s in items), [])


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    out = tmp_path_factory.mktemp("pipe") / "raw"
    res = run_vfcli("synth", out, "--seed", "11", *_sets(PHANTOM))
    assert res.returncode == 0, res.stderr
    return out


@pytest.fixture(scope="module")
def synced(raw, tmp_path_factory):
    store = tmp_path_factory.mktemp("store") / "rec.h5"
    for args in (
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config", raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store],
    ):
        res = run_vfcli(*args)
        assert res.returncode == 0, res.stderr
    return store


def test_ingested_video_is_the_raw_video_unchanged(raw, synced):
    import pyMRAW

    frames, _ = pyMRAW.load_video(str(raw / "video.cihx"))
    with Store(synced).read() as r:
        stored = r.read("hsc", "frames")
        attrs = r.attrs("hsc")
        ds = r.dataset("hsc", "frames")
        assert ds.chunks == (1, *stored.shape[1:]) and ds.dtype == np.uint16
    np.testing.assert_array_equal(stored, np.asarray(frames))
    assert attrs["fps_hz"] == 10000 and attrs["bit_depth"] == 12 and attrs["px_per_mm"] == 9


def test_tiff_and_csv_ingest_the_same_recording(raw, synced, tmp_path):
    other = tmp_path / "tif.h5"
    res = run_vfcli("ingest-hsc", other, raw / "video.tif", "--pressure", raw / "video_pressure.csv",
                    "--config", raw / "recording.toml", "--set", "camera.fps_hz=10000")
    assert res.returncode == 0, res.stderr
    assert run_vfcli("ingest-ldv", other, raw / "scan.csv").returncode == 0
    with Store(other).read() as a, Store(synced).read() as b:
        np.testing.assert_array_equal(a.read("hsc", "frames"), b.read("hsc", "frames"))
        np.testing.assert_allclose(a.read("hsc", "pressure"), b.read("hsc", "pressure"), rtol=1e-9)
        np.testing.assert_allclose(a.read("ldv", "velocity"), b.read("ldv", "velocity"), rtol=1e-5, atol=1e-4)


def test_sync_timing_error_is_under_half_an_ldv_sample(raw, synced):
    truth, _ = read_truth(raw / "truth.h5", ["ldv/sync_offset_s", "ldv/f0_hz"])
    with Store(synced).read() as r:
        off, ok = r.read("sync", "offset_s"), r.read("sync", "ok")
    err = sync_offset_error(off, truth["ldv/sync_offset_s"], truth["ldv/f0_hz"])
    rms_us = 1e6 * np.sqrt(np.mean(err[ok] ** 2))
    print(f"sync: RMS timing error {rms_us:.2f} us over {ok.sum()} of {ok.size} points")
    assert ok.sum() >= 0.9 * ok.size
    assert rms_us < 10.0, f"RMS timing error {rms_us:.2f} us"


def test_aligned_velocity_matches_the_true_surface_velocity(raw, synced):
    truth, _ = read_truth(raw / "truth.h5", ["ldv/points_model_mm", "ldv/dropout_kind", "frames/phase"])
    with Store(synced).read() as r:
        w, ok = r.read("sync", "aligned_w"), r.read("sync", "ok")
    # truth: the vertical velocity at each point at each frame's phase, from the truth's own cycle table
    from vfcli.synth.motion import PeriodicMotion
    from vfcli.camera.raster import raycast_points
    from vfcli.synth.phantom import view_surface
    from vfcli.model.mesh import FoldMesh

    t, attrs = read_truth(raw / "truth.h5")
    mesh = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    motion = PeriodicMotion(t["motion/coeffs_real"] + 1j * t["motion/coeffs_imag"])
    tris, _, _ = view_surface(mesh)
    pts = t["ldv/points_model_mm"]
    frames = np.arange(0, w.shape[1], 7)
    true_w = np.full((len(pts), len(frames)), np.nan)
    for j, f in enumerate(frames):
        phi = np.array([t["frames/phase"][f]])
        ras = raycast_points(pts, mesh.nodes + motion.displacement(phi)[0], tris)
        vz = motion.velocity(phi, attrs["f0_hz"])[0][:, 2]
        true_w[:, j] = ras.scatter(ras.interpolate_visible(vz), np.nan)
    good = ok & (t["ldv/dropout_kind"] == 0) & np.all(np.isfinite(true_w), axis=1)
    err = w[good][:, frames] - true_w[good]
    rel = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(true_w[good] ** 2))
    print(f"sync: aligned vertical velocity {100 * rel:.1f}% RMS from the truth on {good.sum()} points")
    assert rel < 0.1


def test_unchanged_inputs_do_nothing_and_rewritten_upstream_marks_sync_stale(raw, synced, tmp_path):
    store = tmp_path / "copy.h5"
    copy_store(synced, store)
    res = run_vfcli("ingest-ldv", store, raw / "scan.uff")
    assert res.returncode == 0 and "up to date" in res.stdout
    res = run_vfcli("sync", store)
    assert "up to date" in res.stdout
    res = run_vfcli("ingest-ldv", store, raw / "scan.csv")  # another input: rewritten
    assert "written" in res.stdout
    info = json.loads(run_vfcli("info", store, "--json").stdout)
    sync = [s for s in info["stages"] if s["path"] == "/sync"][0]
    assert sync["stale"] and "/ldv was rewritten" in sync["stale_because"][0]
    res = run_vfcli("sync", store)
    assert "written" in res.stdout


def test_the_same_scan_ingested_again_by_another_spelling_of_its_path_leaves_sync_current(raw, synced, tmp_path):
    """`vfcli ingest-ldv STORE ./raw/scan.uff --force` after `raw/scan.uff`: every dataset the same, but the stored
    dropout warning quotes the path as typed, and through the integrity manifest's hash of the attributes it changed
    /ldv's digest: /sync, /fields and the fit were called stale and rerun."""
    store = tmp_path / "copy.h5"
    copy_store(synced, store)
    with Store(store).read() as r:
        before, warned = r.digest("ldv"), r.summary("ldv")["warnings"]
    res = run_vfcli("ingest-ldv", store.resolve(), "scan.uff", "--force", cwd=raw)
    assert res.returncode == 0 and "written" in res.stdout, res.stderr
    with Store(store).read() as r:
        assert r.summary("ldv")["warnings"] != warned            # the premise: the same warning, another path
        assert r.digest("ldv") == before
    info = json.loads(run_vfcli("info", store, "--json").stdout)
    assert not {s["path"]: s["stale"] for s in info["stages"]}["/sync"], info


# ------------------------------------------------------------------ bad input


@pytest.fixture
def store_with_hsc(raw, tmp_path):
    store = tmp_path / "rec.h5"
    assert run_vfcli("ingest-ldv", store, raw / "scan.uff").returncode == 0
    return store


def _bad_mraw_truncated(raw, d):
    shutil.copy(raw / "video.cihx", d / "video.cihx")
    data = (raw / "video.mraw").read_bytes()
    (d / "video.mraw").write_bytes(data[: len(data) // 2 + 7])
    return ["ingest-hsc", d / "video.cihx"], "video.mraw"


def _bad_cihx_disagrees(raw, d):
    shutil.copy(raw / "video.mraw", d / "video.mraw")
    text = (raw / "video.cihx").read_bytes().replace(b"<totalFrame>300</totalFrame>", b"<totalFrame>400</totalFrame>")
    (d / "video.cihx").write_bytes(text)
    return ["ingest-hsc", d / "video.cihx"], "video"


def _bad_empty(raw, d):
    (d / "video.tif").write_bytes(b"")
    return ["ingest-hsc", d / "video.tif"], "video.tif"


def _bad_wrong_type(raw, d):
    (d / "scan.uff").write_text("this is a lab notebook, not a scan\n")
    return ["ingest-ldv", d / "scan.uff"], "scan.uff"


def _bad_nan_pressure(raw, d):
    p = np.full(2000, 800.0)
    p[100] = np.nan
    (d / "p.csv").write_text("time_s,p_sub\n" + "\n".join(f"{i / 50000:.6f},{v}" for i, v in enumerate(p)))
    return ["ingest-hsc", raw / "video.cihx", "--pressure", d / "p.csv"], "p.csv"


def _bad_shared_cell(raw, d):
    # a scan with a point left out is read since session 69 (tests/test_hostile_inputs.py); one point more, in a cell
    # another point holds, is not a scan grid
    scan = read_ldv(raw / "scan.uff")
    from dataclasses import replace

    add = lambda a, row: np.concatenate([a, row[None]])  # noqa: E731
    more = replace(scan, node_ids=add(scan.node_ids, scan.node_ids.max() + 1),
                   coords_mm=add(scan.coords_mm, scan.coords_mm[5] + 0.01), velocity_mm_s=add(scan.velocity_mm_s,
                   scan.velocity_mm_s[5]), reference=add(scan.reference, scan.reference[5]), t0=add(scan.t0, scan.t0[5]))
    write_ldv_uff(d / "scan.uff", more)
    return ["ingest-ldv", d / "scan.uff"], "the 375 scan points fill only 374 cells of their 17 x 22 grid"


BAD = {
    "truncated MRAW": (_bad_mraw_truncated, 3),
    "CIHX disagrees with MRAW size": (_bad_cihx_disagrees, 3),
    "empty file": (_bad_empty, 3),
    "wrong file type": (_bad_wrong_type, 3),
    "NaN pressure samples": (_bad_nan_pressure, 3),
    "UFF with two points in one cell": (_bad_shared_cell, 3),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_with_its_exit_code_and_the_store_untouched(case, raw, store_with_hsc, tmp_path):
    make, code = BAD[case]
    bad_dir = tmp_path / "bad"
    bad_dir.mkdir()
    args, needle = make(raw, bad_dir)
    before = store_with_hsc.read_bytes()
    res = run_vfcli(args[0], store_with_hsc, *args[1:])
    assert res.returncode == code, (case, res.stderr)
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
    assert needle in res.stderr, res.stderr
    assert store_with_hsc.read_bytes() == before


def test_pressure_without_periodicity_fails_sync_clearly(raw, tmp_path):
    store = tmp_path / "rec.h5"
    noise = np.random.default_rng(0).normal(800, 50, 50000)
    write_pressure_csv(tmp_path / "noise.csv", noise, 50000.0)
    assert run_vfcli("ingest-hsc", store, raw / "video.cihx", "--pressure", tmp_path / "noise.csv").returncode == 0
    assert run_vfcli("ingest-ldv", store, raw / "scan.uff").returncode == 0
    before = store.read_bytes()
    res = run_vfcli("sync", store)
    assert res.returncode == 3 and res.stderr.count("\n") == 1, res.stderr
    assert "period" in res.stderr.lower()
    assert store.read_bytes() == before


def test_mismatched_sampling_rates_in_a_scan_are_one_clear_line(tmp_path):
    from vfcli.io.ldv.read import LdvScan

    n = 4
    rng = np.random.default_rng(0)
    scan = LdvScan(node_ids=np.arange(1, n + 1), coords_mm=rng.random((n, 3)), velocity_mm_s=rng.random((n, 100)),
                   fs=50000.0, reference=rng.random((n, 100)), reference_unit="Pa", t0=np.zeros(n))
    path = tmp_path / "scan.uff"
    write_ldv_uff(path, scan, binary=False)
    text = path.read_text()
    last = text.rfind("2.00000e-05")
    path.write_text(text[:last] + "2.10000e-05" + text[last + len("2.10000e-05"):])
    res = run_vfcli("ingest-ldv", tmp_path / "rec.h5", path, "--set", "ingest_ldv.grid_rows=2", "--set", "ingest_ldv.grid_cols=2")
    assert res.returncode == 3 and res.stderr.count("\n") == 1, res.stderr
    assert "sample interval" in res.stderr and "scan.uff" in res.stderr
    assert not (tmp_path / "rec.h5").exists()
