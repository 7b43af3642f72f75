"""Instrument models: pressure spectrum, LDV noise and dropouts, epoch phase truth."""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.synth.instruments import (DROPOUT_FLAT, DROPOUT_NONE, DROPOUT_SPIKES, LdvSettings, PeriodicTable,
                               PressureWaveform, cycle_phase, ldv_scan_grid, simulate_ldv_scan,
                               slow_f0_drift, subglottal_pressure, vertical_velocity_table,
                               video_pressure)

WAVE = PressureWaveform(mean_pa=800.0, amplitude_rel=0.45, harmonics=(1.0, 0.5, 0.25), phases_rad=(0.0, 1.0, -0.5))


def surface_w(points, phase):
    """An analytic vertical velocity field (mm/s): a travelling wave, no surface for y in (-0.3, 0.3)."""
    x, y = points[:, 0:1], points[:, 1:2]
    w = 200.0 * np.sin(2 * np.pi * (phase - 0.05 * x)) * np.exp(-np.abs(y) / 4) + 40 * np.cos(4 * np.pi * phase)
    return np.where(np.abs(y) < 0.3, np.nan, w)


def scan(seed=0, **kw):
    pts = ldv_scan_grid((0.0, 15.0, -8.0, 8.0), 22, 17, 0.03, 1.5, np.random.default_rng(seed))
    settings = LdvSettings(**kw)
    return simulate_ldv_scan(pts, surface_w, 120.0, WAVE, settings, np.random.default_rng(seed + 1)), settings


def test_pressure_spectrum_has_the_stated_f0_harmonics_and_levels():
    fs, f0 = 50_000.0, 125.0
    t = np.arange(50_000) / fs                      # 1 s: integer number of cycles, exact bins
    p = subglottal_pressure(t, f0, WAVE)
    spec = np.abs(np.fft.rfft(p)) * 2 / len(p)
    freqs = np.fft.rfftfreq(len(p), 1 / fs)
    assert spec[0] / 2 == pytest.approx(800.0, rel=1e-9)
    peaks = np.sort(freqs[np.argsort(spec[1:])[-3:] + 1])
    assert np.allclose(peaks, [125.0, 250.0, 375.0])
    amps = spec[[125, 250, 375]]
    assert np.allclose(amps / amps[0], [1.0, 0.5, 0.25], rtol=1e-6)
    assert np.allclose(amps, WAVE.harmonic_amplitudes_pa(), rtol=1e-6)
    assert (p.max() - p.min()) / 2 == pytest.approx(0.45 * 800.0, rel=1e-3)
    assert spec[1:][~np.isin(freqs[1:], [125.0, 250.0, 375.0])].max() < 1e-6


def test_drifting_phase_is_the_integral_of_f0():
    t = np.linspace(0.0, 0.5, 25_001)
    f0 = 120.0 + 8.0 * t                            # linear ramp: phase = 120 t + 4 t^2
    assert np.allclose(cycle_phase(t, f0, 0.25), 0.25 + 120 * t + 4 * t ** 2, atol=1e-9)
    drift = slow_f0_drift(t, 120.0, 0.005, 0.2, np.random.default_rng(0))
    assert np.abs(drift / 120.0 - 1).max() == pytest.approx(0.005)
    rec = video_pressure(0.5, 50_000.0, lambda tt: slow_f0_drift(tt, 120.0, 0.005, 0.2, np.random.default_rng(0)),
                         WAVE, 0.1, 0.0, np.random.default_rng(1))
    assert np.allclose(rec.phase_cycles, cycle_phase(rec.t, drift[:-1], 0.1))
    assert np.allclose(rec.true_pa, WAVE.at_phase(rec.phase_cycles))


def test_video_pressure_noise_is_as_stated_and_phases_of_frames_interpolate():
    rec = video_pressure(0.2, 50_000.0, 130.0, WAVE, 0.3, 3.0, np.random.default_rng(4))
    assert len(rec.t) == 10_000
    assert np.std(rec.measured_pa - rec.true_pa) == pytest.approx(3.0, rel=0.03)
    frames = np.arange(2000) / 10_000.0
    assert np.allclose(rec.phase_at(frames), 0.3 + 130.0 * frames)


def test_scan_grid_is_17_by_22_and_not_exactly_regular():
    pts = ldv_scan_grid((0.0, 15.0, -8.0, 8.0), 22, 17, 0.03, 0.0, np.random.default_rng(2))
    assert pts.shape == (374, 2)
    regular = ldv_scan_grid((0.0, 15.0, -8.0, 8.0), 22, 17, 0.0, 0.0, np.random.default_rng(2))
    dev = (pts - regular) / np.array([15.0 / 21, 16.0 / 16])
    assert dev.std() == pytest.approx(0.03, rel=0.1)
    rotated = ldv_scan_grid((0.0, 15.0, -8.0, 8.0), 22, 17, 0.0, 2.0, np.random.default_rng(2))
    step = rotated[17] - rotated[0]                 # one grid column along x
    assert np.degrees(np.arctan2(step[1], step[0])) == pytest.approx(2.0)


def test_ldv_noise_level_matches_the_stated_one():
    s, settings = scan(0, noise_rel=0.01)
    clean = np.isfinite(s.truth.velocity) & ~s.truth.dropout_mask
    rms = np.sqrt(np.nanmean(s.truth.velocity ** 2))
    resid = (s.velocity - s.truth.velocity)[clean]
    assert s.truth.noise_std == pytest.approx(0.01 * rms)
    assert resid.std() == pytest.approx(0.01 * rms, rel=0.02)
    assert abs(resid.mean()) < 0.05 * resid.std()
    assert s.velocity.shape == (374, 5000) and s.pressure.shape == (374, 5000)
    assert np.std((s.pressure - s.truth.pressure)) == pytest.approx(settings.pressure_noise_pa, rel=0.02)
    # no surface under the laser: the signal is lost, only noise remains
    lost = ~np.isfinite(s.truth.velocity) & ~s.truth.dropout_mask
    assert lost.any() and np.abs(s.velocity[lost]).max() < 6 * s.truth.noise_std


def test_dropouts_are_where_the_truth_says():
    s, _ = scan(3, dropout_fraction=0.03)
    kind = s.truth.dropout_kind
    assert (kind != DROPOUT_NONE).sum() == round(0.03 * 374)
    expected = np.where(np.isfinite(s.truth.velocity), s.truth.velocity, 0.0)
    outlier = np.abs(s.velocity - expected) > 6 * s.truth.noise_std
    # outside the dropout mask the data are clean
    assert not outlier[~s.truth.dropout_mask].any()
    assert not s.truth.dropout_mask[kind == DROPOUT_NONE].any()
    assert (kind == DROPOUT_SPIKES).any() and (kind == DROPOUT_FLAT).any()  # both loops below run
    for p in np.flatnonzero(kind == DROPOUT_SPIKES):
        assert outlier[p][s.truth.dropout_mask[p]].all()
    for p in np.flatnonzero(kind == DROPOUT_FLAT):
        held = s.velocity[p][s.truth.dropout_mask[p]]
        assert s.truth.dropout_mask[p].sum() >= 100 and np.unique(held).size <= 3   # at most 3 flat runs


def test_epoch_phase_truth_is_consistent_with_the_signals():
    s, settings = scan(5)
    t = np.arange(settings.n_samples) / settings.fs_hz
    phase = s.truth.start_phase[:, None] + s.truth.f0_hz[:, None] * t
    assert np.allclose(s.truth.pressure, WAVE.at_phase(phase))
    assert np.allclose(s.truth.velocity, surface_w(s.points_mm, phase), equal_nan=True)
    # independent estimate from the noisy pressure reference: the fundamental's phase
    # (least-squares fit of a constant and three harmonics at the epoch's f0; the phase of the first)
    some = np.arange(0, len(s.pressure), 7)
    est = np.empty(len(some))
    for i, p in enumerate(some):
        arg = 2 * np.pi * s.truth.f0_hz[p] * t
        design = np.column_stack([np.ones_like(t)] + [f(k * arg) for k in (1, 2, 3) for f in (np.cos, np.sin)])
        coef, *_ = np.linalg.lstsq(design, s.pressure[p], rcond=None)
        est[i] = (np.angle(coef[1] - 1j * coef[2]) - WAVE.phases_rad[0]) / (2 * np.pi)
    err = np.angle(np.exp(2j * np.pi * (est - s.truth.start_phase[some]))) / (2 * np.pi)
    assert np.abs(err).max() < 2e-4
    # f0 drifts between epochs, within +-1 %, and start phases are spread over the cycle
    rel = s.truth.f0_hz / 120.0 - 1
    assert np.abs(rel).max() <= 0.01 + 1e-12 and rel.std() > 1e-3
    assert np.all(np.diff(s.truth.start_time_s) >= settings.epoch_s)
    assert np.histogram(s.truth.start_phase, bins=4, range=(0, 1))[0].min() > 50
    # the video time of the same phase
    vt = s.truth.video_time_s(120.0, 0.2)
    assert np.allclose(np.mod(0.2 + 120.0 * vt - s.truth.start_phase + 0.5, 1.0), 0.5)


def test_periodic_table_interpolates_a_sampled_cycle():
    m = 64
    grid = np.arange(m) / m
    pts = np.array([[1.0, 2.0], [3.0, -1.0], [5.0, 0.1]])
    table = surface_w(pts, np.broadcast_to(grid, (3, m)))
    f = PeriodicTable(table)
    phase = np.random.default_rng(0).uniform(-2, 3, size=(3, 500))
    got = f(pts, phase)
    want = surface_w(pts, phase)
    assert np.isnan(got[2]).all() and np.isnan(want[2]).all()
    assert np.allclose(got[:2], want[:2], rtol=0, atol=0.5)          # 200 mm/s amplitude, 64 samples
    assert np.allclose(f(pts, np.broadcast_to(grid, (3, m)))[:2], table[:2])


def test_same_seed_same_bytes_and_bad_settings_are_value_errors():
    a, _ = scan(9, epoch_s=0.02)
    b, _ = scan(9, epoch_s=0.02)
    assert a.velocity.tobytes() == b.velocity.tobytes() and a.pressure.tobytes() == b.pressure.tobytes()
    with pytest.raises(ValueError):
        LdvSettings(dropout_fraction=1.5)
    with pytest.raises(ValueError):
        PressureWaveform(harmonics=(1.0, 0.5), phases_rad=(0.0,))


def test_vertical_velocity_table_follows_a_moving_sheet_and_its_edge():
    # a flat sheet x in [0, 10], y in [0.5, 5] mm; it heaves with w = 100 sin(2 pi phase) mm/s
    # and its medial edge (y = 0.5) moves laterally by -0.4 cos(2 pi phase): a beam at
    # y = 0.3 sees it only while the edge has passed y = 0.3
    xs, ys = np.meshgrid(np.linspace(0, 10, 11), np.linspace(0.5, 5, 10), indexing="ij")
    rest = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    i = (np.arange(10)[:, None] * 10 + np.arange(9)[None, :]).ravel()
    tris = np.concatenate([np.stack([i, i + 10, i + 11], 1), np.stack([i, i + 11, i + 1], 1)])
    m = 40
    phase = np.arange(m) / m
    edge_weight = (5 - rest[:, 1]) / 4.5                  # 1 at the medial edge, 0 laterally
    verts = np.repeat(rest[None], m, axis=0)
    verts[:, :, 1] += -0.4 * np.cos(2 * np.pi * phase)[:, None] * edge_weight
    verts[:, :, 2] += (100 / (2 * np.pi)) * (1 - np.cos(2 * np.pi * phase))[:, None]
    vel = np.zeros_like(verts)
    vel[:, :, 2] = 100 * np.sin(2 * np.pi * phase)[:, None]
    pts = np.array([[5.0, 3.0], [5.0, 0.3], [12.0, 3.0]])
    table = vertical_velocity_table(pts, verts, vel, tris)
    assert np.allclose(table[0], 100 * np.sin(2 * np.pi * phase))
    edge_y = 0.5 - 0.4 * np.cos(2 * np.pi * phase)
    assert np.array_equal(np.isfinite(table[1]), edge_y <= 0.3)
    assert np.isnan(table[2]).all()
