"""A vibrometer sampling rate that contradicts the recording (issue 20): refused, not passed silently.

A wrong but plausible rate (25 kHz stated for 50 kHz) passes every range check of
vfcli/io/limits.py. The pressure recorded beside each vibrometer point fixes the true rate: its f0
on the vibrometer's stated time base must match the f0 of the pressure recorded with the video
(vfcli/sync/rate.py). Before, such a scan ingested and synced with exit 0 and 0 of 374 points aligned.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from _small_phantom import SMALL_160, shared_raw
from tests.conftest import run_vfcli
from vfcli.errors import InputDataError
from vfcli.sync.rate import check_ldv_rate

FS = 50_000.0
F0 = 120.0
F_RANGE = (50.0, 500.0)


def _reference(n_points=20, n_s=1500, f0=F0, seed=0) -> np.ndarray:
    """(P, S) pressure-like references at ``f0`` sampled at the true FS, with harmonics and noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_s) / FS + rng.uniform(0, 1, (n_points, 1))
    ph = 2 * np.pi * f0 * t
    return 800 + 300 * np.sin(ph) + 80 * np.sin(2 * ph + 0.4) + 30 * np.sin(3 * ph + 1.1) + rng.normal(0, 5, t.shape)


@pytest.mark.parametrize("stated", [25_000.0, 40_000.0, 100_000.0, 12_500.0])
def test_a_rate_off_by_a_factor_is_refused_with_the_rate_the_data_imply(stated):
    with pytest.raises(InputDataError) as e:
        check_ldv_rate(F0, _reference(), stated, f_range=F_RANGE, max_drift=0.05, source="scan.uff")
    msg = str(e.value)
    assert msg.startswith("scan.uff: ") and f"stated vibrometer sampling rate {stated:g} Hz" in msg
    implied = float(msg.split("the data imply ")[1].split(" Hz")[0])
    assert abs(implied / FS - 1) < 0.003, implied          # measured: within 0.05 % (short, noisy epochs)
    # the other cause it names, and no advice to widen sync.max_drift (which would join two oscillations)
    assert "phonated at different f0" in msg and "different recordings" in msg and "max_drift" not in msg


@pytest.mark.parametrize("stated, f0_video", [(FS, F0), (FS, F0 * 1.03), (FS * 0.97, F0)])
def test_the_true_rate_and_a_drift_within_max_drift_pass(stated, f0_video):
    # a rate within sync.max_drift of the truth is indistinguishable from an f0 change between the
    # recordings; sync aligns such a scan by phase, so its velocities are unaffected
    check_ldv_rate(f0_video, _reference(), stated, f_range=F_RANGE, max_drift=0.05, source="scan.uff")


def test_epochs_too_short_or_without_a_common_f0_are_left_to_sync():
    short = _reference(n_s=500)                                   # 1.2 cycles: no reliable f0
    check_ldv_rate(F0, short, 25_000.0, f_range=F_RANGE, max_drift=0.05, source="scan.uff")
    rng = np.random.default_rng(3)
    mixed = np.vstack([_reference(n_points=1, f0=f) for f in rng.uniform(60, 400, 20)])   # no common f0
    check_ldv_rate(F0, mixed, FS, f_range=F_RANGE, max_drift=0.05, source="scan.uff")
    # 12 of 20 epochs at another f0, 8 at the video's: the rate explains those 8; sync rejects the rest
    part = np.vstack([_reference(n_points=12, f0=F0 * 0.7), _reference(n_points=8, seed=1)])
    check_ldv_rate(F0, part, FS, f_range=F_RANGE, max_drift=0.05, source="scan.uff")
    with pytest.raises(InputDataError):       # the same 12 alone: refused, so the 8 are what saves it
        check_ldv_rate(F0, part[:12], FS, f_range=F_RANGE, max_drift=0.05, source="scan.uff")


# --------------------------------------------------------------------------- a phantom, real subprocesses

#: tests/test_store_integrity.py's phantom (and tests/test_diagnose_refit_phantom.py's null): its raw folder is
#: made once per run and shared
SEED = 34


@pytest.fixture(scope="module")
def phantom(tmp_path_factory) -> Path:
    """The raw folder of the phantom (read-only)."""
    return shared_raw(tmp_path_factory, SEED, SMALL_160)


def _rewrite_rate(raw: Path, fs: float, out: Path) -> Path:
    """The phantom's scan.uff written again with pyuff's dataset writers, its sampling rate stated as ``fs``."""
    from vfcli.io.ldv.read import read_ldv
    from vfcli.io.ldv.write import write_ldv_uff

    scan = read_ldv(raw / "scan.uff", expected_grid=None)
    assert scan.fs == FS
    return write_ldv_uff(out, dataclasses.replace(scan, fs=fs))


def _ingest_video(raw: Path, store: Path) -> bytes:
    """ingest-hsc of the phantom's video and pressure into ``store``; the store's bytes after it."""
    r = run_vfcli("ingest-hsc", "-q", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                  "--config", raw / "recording.toml")
    assert r.returncode == 0, r.stderr
    return store.read_bytes()


def _assert_rate_refused(r, name: str, stated: int) -> None:
    """Exit 3, one line naming the file, the stated rate and an implied rate within 1 % of the truth."""
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert name in line and f"stated vibrometer sampling rate {stated} Hz" in line, line
    implied = float(line.split("the data imply ")[1].split(" Hz")[0])
    assert 49_500 < implied < 50_500, line


def test_phantom_uff_claiming_25_khz_is_refused_at_ingest_ldv(phantom, tmp_path):
    store = tmp_path / "rec.h5"
    before = _ingest_video(phantom, store)
    bad = _rewrite_rate(phantom, 25_000.0, tmp_path / "scan25k.uff")
    r = run_vfcli("ingest-ldv", "-q", store, bad)
    _assert_rate_refused(r, "scan25k.uff", 25_000)
    assert store.read_bytes() == before
    # the phantom's own file (50 kHz) passes, and sync aligns its points: the check does not misfire
    r = run_vfcli("ingest-ldv", "-q", store, phantom / "scan.uff")
    assert r.returncode == 0, r.stderr
    r = run_vfcli("sync", "--json", store)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["aligned"] >= 0.95 * out["points"], out                  # the full-size phantom: 374 of 374


def test_phantom_uff_ingested_before_the_video_is_refused_by_sync(phantom, tmp_path):
    store = tmp_path / "rec.h5"
    bad = _rewrite_rate(phantom, 100_000.0, tmp_path / "scan100k.uff")
    assert run_vfcli("ingest-ldv", "-q", store, bad).returncode == 0        # no video yet: nothing to check against
    before = _ingest_video(phantom, store)
    r = run_vfcli("sync", "-q", store)
    _assert_rate_refused(r, "scan100k.uff", 100_000)
    assert store.read_bytes() == before
