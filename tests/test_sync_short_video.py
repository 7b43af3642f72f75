"""Sync on short videos and scans it cannot align (issue 15: no stage exits 0 with an empty product;
advice that helps).

* A video whose pressure record holds 1.4 cycles (12 ms at 120 Hz) gave no reliable f0 of its own:
  its estimate was the third harmonic (359 Hz), and sync blamed the scan's sampling rate ("the data
  imply 150 kHz"). It must now say the video is too short, at the f0 the scan agrees on.
* A sync that aligns no point used to exit 0 with an empty /sync; it now fails (exit 3, store unchanged).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from _small_phantom import SMALL, shared_phantom_with_hsc
from conftest import run_vfcli
from vfcli.errors import InputDataError
from vfcli.io.ldv.read import read_ldv
from vfcli.io.ldv.write import write_ldv_uff
from vfcli.store import Store, copy_store
from vfcli.sync.align import sync_scan
from vfcli.sync.rate import check_ldv_rate, harmonic_r2, scan_explains_video
from vfcli.synth.instruments import PressureWaveform, subglottal_pressure, video_pressure

FS = 50_000.0
F0 = 120.0


def _recording(duration_s: float, seed: int, scan_fs: float = FS):
    """The synth's pressure waveform: a video pressure record of ``duration_s`` and 24 epochs of 0.1 s
    (references at f0 within 0.3 %), velocities a sine of the epoch's f0."""
    rng = np.random.default_rng(seed)
    wf = PressureWaveform(mean_pa=1000.0, amplitude_rel=0.6,
                          phases_rad=tuple(np.round(rng.uniform(-np.pi, np.pi, 4), 3)))
    rec = video_pressure(duration_s, FS, F0, wf, float(rng.uniform()), 4.0, rng)
    frame_times = np.arange(int(duration_s * 1e4)) / 1e4
    t = np.arange(5000) / FS
    f = F0 * (1 + 0.003 * rng.standard_normal(24))
    ref = np.array([subglottal_pressure(t, fi, wf, rng.uniform()) + 4.0 * rng.standard_normal(t.size) for fi in f])
    vel = np.array([np.sin(2 * np.pi * fi * t) for fi in f])
    return rec.measured_pa, frame_times, ref, vel


def test_a_video_of_1_4_cycles_is_too_short_at_the_scans_f0_not_a_wrong_scan_rate():
    p, frames, ref, vel = _recording(0.012, seed=1)
    with pytest.raises(InputDataError) as exc:
        sync_scan(p, FS, 0.0, frames, ref, vel, FS)
    msg = str(exc.value)
    assert "too short" in msg and "sampling rate" not in msg, msg
    f_scan = float(msg.split("agrees on (")[1].split(" Hz")[0])
    assert f_scan == pytest.approx(F0, rel=0.01)
    assert "16.7 ms" in msg            # 2 cycles at 120 Hz: the record it needs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_videos_of_2_4_and_3_cycles_still_align_every_point(seed):
    for duration in (0.02, 0.025):
        p, frames, ref, vel = _recording(duration, seed)
        res = sync_scan(p, FS, 0.0, frames, ref, vel, FS)
        assert res.ok.all() and res.f0_video_hz == pytest.approx(F0, rel=2e-3)


def test_the_harmonics_of_the_true_f0_explain_the_short_record_and_a_harmonic_does_not():
    p, _, _, _ = _recording(0.012, seed=1)
    assert harmonic_r2(p, FS, F0, 10) > 0.99
    assert harmonic_r2(p, FS, 3 * F0, 10) < 0.9
    assert scan_explains_video(p, FS, 3 * F0, F0, 10)
    # a scan whose stated rate is half the true one: its apparent f0 is a sub-harmonic, which explains
    # a long enough video no better than the video's own right f0, so the rate check still applies
    p, _, ref, _ = _recording(0.025, seed=1)
    assert not scan_explains_video(p, FS, F0, F0 / 2, 10)
    with pytest.raises(InputDataError, match="the data imply"):
        check_ldv_rate(F0, ref, FS / 2, f_range=(50.0, 500.0), max_drift=0.05, source="scan.uff")


# --------------------------------------------------------------------------- the stage, real subprocesses

@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A small phantom and a store with its /hsc."""
    return shared_phantom_with_hsc(tmp_path_factory, 4, SMALL)     # tests/test_plausibility.py's too


def test_a_sync_that_aligns_no_point_fails_with_the_reasons_and_leaves_the_store(video, tmp_path):
    """A scan whose reference channel recorded noise only (a disconnected pressure sensor): no point
    has a periodic reference. sync used to exit 0 with 0 of 374 points aligned."""
    raw, hsc = video
    store = copy_store(hsc, tmp_path / "rec.h5")
    scan = read_ldv(raw / "scan.uff")
    rng = np.random.default_rng(0)
    noise = replace(scan, reference=rng.standard_normal(scan.reference.shape))
    write_ldv_uff(tmp_path / "scan.uff", noise)
    assert run_vfcli("ingest-ldv", "-q", store, tmp_path / "scan.uff").returncode == 0
    before = store.read_bytes()
    res = run_vfcli("sync", store)
    assert res.returncode == 3, res.stderr
    line = res.stderr.strip().splitlines()[-1]
    assert "only 0 of 374 LDV points could be aligned" in line and "no periodicity" in line, line
    assert "same recording" in line and "ingest_ldv.reference_id1" in line, line
    assert "Traceback" not in res.stderr
    assert store.read_bytes() == before
    with Store(store).read() as r:
        assert not r.has_stage("sync")
