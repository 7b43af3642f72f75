"""Tests of vfcli.sync.align: f0 estimation, phase tracking and phase-locked LDV alignment.

The fixture ``SyncScene`` is a synthetic scan with known truth (not the project's phantom):
a pressure waveform with harmonics, periodic in a cycle phase that drifts slowly (linear
trend plus a slow wobble of the instantaneous f0); the video's pressure and each LDV
epoch's reference channel follow their own phase (random start, f0 within +-1.5% of the
video's); the LDV velocity of each point is a known periodic function of the epoch's phase,
so the true epoch time matching every video frame is known.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from vfcli.errors import InputDataError
from vfcli.sync.align import (
    align_epoch,
    estimate_f0,
    matched_times,
    sync_scan,
    video_phase_reference,
)

FS = 50_000.0
FPS = 10_000.0


@dataclass
class Phase:
    """phi(t) = phi0 + f0 (t + lin t^2 / 2 - wob P / (2 pi) (cos(2 pi t / P + c) - cos c))."""

    f0: float
    phi0: float
    lin: float = 0.0
    wob: float = 0.0
    period: float = 0.5
    wob_phase: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        w = 2 * np.pi / self.period
        return self.phi0 + self.f0 * (
            t + 0.5 * self.lin * t**2
            - self.wob / w * (np.cos(w * t + self.wob_phase) - np.cos(self.wob_phase)))

    def freq(self, t: np.ndarray) -> np.ndarray:
        w = 2 * np.pi / self.period
        return self.f0 * (1 + self.lin * t + self.wob * np.sin(w * t + self.wob_phase))


def harmonic(coeffs: np.ndarray, phi: np.ndarray) -> np.ndarray:
    h = np.arange(1, coeffs.size + 1)
    return (coeffs[None, :] * np.exp(2j * np.pi * np.asarray(phi)[..., None] * h)).real.sum(-1)


def pressure_coeffs(rng: np.random.Generator, amp: float = 320.0) -> np.ndarray:
    """Harmonic amplitudes (Pa) of a glottal-like pressure cycle, peak ~ amp."""
    mags = np.array([1.0, 0.5, 0.3, 0.15, 0.08, 0.04])
    c = mags * np.exp(2j * np.pi * rng.uniform(size=mags.size))
    return amp / mags.sum() * c


@dataclass
class SyncScene:
    video_p: np.ndarray
    t0: float
    frame_times: np.ndarray
    ref: np.ndarray
    vel: np.ndarray
    video_phase: Phase
    epoch_phases: list
    vel_coeffs: np.ndarray  # (P, Hv) complex
    f0: float


def make_scene(
    n_points: int = 374, n_samples: int = 10_000, seed: int = 0, noise: float = 0.02,
    f0: float = 150.0, max_df: float = 0.015, lin: float = 0.025, wob: float = 0.002,
    n_frames: int = 1500, video_len: float = 0.2, t0: float = -0.002,
    gain: float = 1 / 250.0, offset: float = 0.3, vel_noise: float = 0.01,
    wob_period: float = 0.5, shape_jitter: float = 0.0,
) -> SyncScene:
    rng = np.random.default_rng(seed)
    coeffs = pressure_coeffs(rng)
    osc_std = np.sqrt(np.sum(np.abs(coeffs) ** 2) / 2)
    vph = Phase(f0, rng.uniform(), lin=rng.uniform(-lin, lin), wob=wob, period=wob_period,
                wob_phase=rng.uniform(0, 2 * np.pi))
    tv = t0 + np.arange(int(video_len * FS)) / FS
    video_p = (800.0 + harmonic(coeffs, vph(tv)) + 15.0 * (tv - t0) / video_len
               + noise * osc_std * rng.standard_normal(tv.size))
    frame_times = np.arange(n_frames) / FPS
    t = np.arange(n_samples) / FS
    ref = np.empty((n_points, n_samples))
    vel = np.empty((n_points, n_samples))
    hv = 8
    vel_coeffs = (300.0 / np.arange(1, hv + 1) ** 1.5)[None, :] * rng.uniform(
        0.5, 1.0, (n_points, hv)) * np.exp(2j * np.pi * rng.uniform(size=(n_points, hv)))
    phases = []
    for p in range(n_points):
        ph = Phase(f0 * (1 + rng.uniform(-max_df, max_df)), rng.uniform(0, 100),
                   lin=rng.uniform(-lin, lin), wob=wob, period=wob_period,
                   wob_phase=rng.uniform(0, 2 * np.pi))
        phases.append(ph)
        phi = ph(t)
        drift = rng.uniform(-20, 20) * t / t[-1]
        c_p = coeffs.copy()
        if shape_jitter:   # the waveform of this epoch differs: harmonics >= 2 perturbed
            c_p[1:] *= (1 + shape_jitter * rng.standard_normal(c_p.size - 1)) * np.exp(
                1j * shape_jitter * rng.standard_normal(c_p.size - 1))
        pr = 800.0 + harmonic(c_p, phi) + drift + noise * osc_std * rng.standard_normal(t.size)
        ref[p] = gain * pr + offset
        v = harmonic(vel_coeffs[p], phi)
        vel[p] = v + vel_noise * v.std() * rng.standard_normal(t.size)
    return SyncScene(video_p, t0, frame_times, ref, vel, vph, phases, vel_coeffs, f0)


def timing_errors(scene: SyncScene, res) -> np.ndarray:
    """Error (s) of every mapped epoch time (all frames, all averaged cycles, ok points).

    The estimated epoch phase is inverted at the estimated video phase of each frame; the
    error of a mapped time tau is (true epoch phase at tau - true video phase at the frame),
    wrapped to +-1/2 cycle, divided by the true epoch frequency at tau.
    """
    t = np.arange(scene.ref.shape[1]) / FS
    true_v = scene.video_phase(scene.frame_times)
    errs = []
    phases = res.tracks.phase_at(t)
    for p in np.flatnonzero(res.ok):
        ph_est = phases[p]
        times, valid = matched_times(ph_est, FS, res.video_phase)
        tau = times[valid]
        frame_phase = np.broadcast_to(true_v[:, None], times.shape)[valid]
        truth = scene.epoch_phases[p]
        d = truth(tau) - frame_phase
        d = d - np.round(d)
        errs.append(d / truth.freq(tau))
    return np.concatenate(errs)


def true_velocity(scene: SyncScene) -> np.ndarray:
    """Velocity truth on the frame times: each point's waveform at the video's true phase."""
    phi = scene.video_phase(scene.frame_times)
    return np.array([harmonic(c, phi) for c in scene.vel_coeffs])


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def run_sync(scene: SyncScene, **kwargs):
    return sync_scan(scene.video_p, FS, scene.t0, scene.frame_times, scene.ref, scene.vel, FS,
                     **kwargs)


@pytest.fixture(scope="module")
def small_scan():
    scene = make_scene(n_points=40, seed=1)
    return scene, run_sync(scene)


def periodic_pressure(f0: float, n: int, seed: int, noise: float = 0.02, fs: float = FS,
                      coeffs: np.ndarray | None = None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    c = pressure_coeffs(rng) if coeffs is None else coeffs
    t = np.arange(n) / fs
    osc_std = np.sqrt(np.sum(np.abs(c) ** 2) / 2)
    return (800.0 + harmonic(c, f0 * t + rng.uniform())
            + noise * osc_std * rng.standard_normal(n))


# --------------------------------------------------------------------------- f0 estimation
def test_estimate_f0_precision_better_than_0_01_percent_at_2_percent_noise():
    errors = []
    for seed, f0 in enumerate([100.0, 123.456, 150.0, 171.3, 249.0]):
        p = periodic_pressure(f0, 10_000, seed)
        errors.append(estimate_f0(p, FS) / f0 - 1.0)
    worst = float(np.max(np.abs(errors)))
    print(f"\nf0 relative error (0.2 s, 2% noise): worst {worst:.2e}, rms {rms(errors):.2e}")
    assert worst < 1e-4, f"worst relative f0 error {worst:.2e} (rms {rms(errors):.2e})"


def test_estimate_f0_is_sub_bin_on_short_records():
    # 0.05 s: the FFT bin is 20 Hz, the estimate must still be within 0.05%
    f0 = 131.7
    p = periodic_pressure(f0, 2_500, seed=3)
    assert abs(estimate_f0(p, FS) / f0 - 1.0) < 5e-4


def test_estimate_f0_invariant_to_gain_offset_and_baseline_drift():
    f0 = 142.0
    p = periodic_pressure(f0, 8_000, seed=4)
    t = np.arange(p.size) / FS
    volts = p / 250.0 + 1.7 + 0.4 * t / t[-1] + 0.2 * (t / t[-1]) ** 2
    assert estimate_f0(volts, FS) == pytest.approx(estimate_f0(p, FS), rel=2e-5)
    assert abs(estimate_f0(volts, FS) / f0 - 1.0) < 1e-4


def test_estimate_f0_picks_the_fundamental_not_an_octave():
    rng = np.random.default_rng(5)
    weak_fundamental = np.array([0.3, 1.0, 0.6, 0.4]) * np.exp(2j * np.pi * rng.uniform(size=4))
    f0 = 118.0
    p = periodic_pressure(f0, 10_000, seed=5, coeffs=100.0 * weak_fundamental)
    assert estimate_f0(p, FS) == pytest.approx(f0, rel=1e-4)
    # strong odd harmonics do not make 3 f0 win either
    c = np.array([1.0, 0.1, 0.9, 0.05, 0.5]) * 100.0
    assert estimate_f0(periodic_pressure(f0, 10_000, seed=6, coeffs=c), FS) == pytest.approx(
        f0, rel=1e-4)


@pytest.mark.parametrize(
    "signal, match",
    [
        (np.random.default_rng(0).standard_normal(10_000), "no periodicity"),
        (np.full(10_000, 812.5), "constant"),
        (np.sin(2 * np.pi * 150.0 * np.arange(100) / FS), "too short"),
        (np.where(np.arange(10_000) == 17, np.nan, 1.0), "non-finite"),
    ],
    ids=["white-noise", "constant", "too-short", "nan"],
)
def test_estimate_f0_raises_input_data_error_naming_the_source(signal, match):
    with pytest.raises(InputDataError, match=match) as err:
        estimate_f0(signal, FS, source="scan.tdms:p_sub")
    assert "scan.tdms:p_sub" in str(err.value)


def test_estimate_f0_rejects_a_record_shorter_than_two_cycles_of_its_f0():
    p = periodic_pressure(60.0, int(1.5 / 60.0 * FS), seed=7)
    with pytest.raises(InputDataError, match="too short|periodicity"):
        estimate_f0(p, FS, f_range=(50.0, 500.0))


# --------------------------------------------------------------------------- phase tools
def test_invert_monotonic_equals_numpy_interp():
    from vfcli.sync.align import invert_monotonic

    rng = np.random.default_rng(8)
    t = np.arange(10_000) / FS
    ph = 3.3 + 151.0 * (t + 0.3 * t**2 + 0.001 * np.sin(2 * np.pi * 20 * t))
    targets = rng.uniform(ph[0] - 0.2, ph[-1] + 0.2, size=(700, 3))
    expect = np.interp(targets, ph, np.arange(ph.size, dtype=float))
    np.testing.assert_allclose(invert_monotonic(ph, targets), expect, atol=1e-9)


def test_video_phase_reference_puts_phase_zero_at_the_fundamental_maximum():
    scene = make_scene(n_points=1, seed=2, noise=0.0)
    video = video_phase_reference(scene.video_p, FS, scene.t0, scene.frame_times)
    c = video.template.coeffs
    assert abs(c[0].imag) < 1e-9 * abs(c[0]) and c[0].real > 0
    assert 0.0 <= video.frame_phase[0] < 1.0
    # the template's phase 0 maps to the true waveform's fundamental maximum
    true_c1 = pressure_coeffs(np.random.default_rng(2))[0]
    offset = video.frame_phase - scene.video_phase(scene.frame_times)
    expected = np.angle(true_c1) / (2 * np.pi)
    d = offset - expected
    d = d - np.round(d)
    assert np.max(np.abs(d)) / 150.0 < 1e-6, f"phase zero off by {np.max(np.abs(d)):.2e} cycles"


def test_video_phase_reference_rejects_frames_outside_the_pressure_record():
    scene = make_scene(n_points=1, seed=2)
    with pytest.raises(InputDataError, match="does not cover"):
        video_phase_reference(scene.video_p, FS, 0.1, scene.frame_times)


# --------------------------------------------------------------------------- alignment
def _report_timing(scene: SyncScene, res, label: str) -> float:
    err = timing_errors(scene, res)
    value = rms(err)
    print(f"\n{label}: RMS timing error {value * 1e6:.2f} us over {res.ok.sum()} points "
          f"({err.size} mapped times), max {np.max(np.abs(err)) * 1e6:.1f} us")
    return value


def test_timing_error_is_below_half_an_ldv_sample(small_scan):
    scene, res = small_scan
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "40 points")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us (target < 10 us)"


@pytest.mark.slow
def test_timing_error_for_a_full_374_point_scan():
    scene = make_scene(n_points=374, seed=0)
    res = run_sync(scene)  # its time: bench/bench_unit_timings.py
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "374 points")
    rel = rms(res.aligned_w - true_velocity(scene)) / rms(true_velocity(scene))
    print(f"aligned velocity relative RMS error {rel:.2e}")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us (target < 10 us)"
    assert rel < 0.01, f"aligned velocity relative RMS error {rel:.2e}"


def test_aligned_velocity_matches_the_truth_on_the_frame_times(small_scan):
    scene, res = small_scan
    truth = true_velocity(scene)
    rel = rms(res.aligned_w - truth) / rms(truth)
    print(f"\naligned velocity relative RMS error {rel:.2e} (1% LDV noise, phase-averaged)")
    assert rel < 0.01, f"aligned velocity relative RMS error {rel:.2e}"
    assert res.aligned_w.shape == (40, scene.frame_times.size)
    assert np.all(res.n_cycles >= 25)


def test_offset_f0_and_drift_match_the_truth(small_scan):
    scene, res = small_scan
    t = np.arange(scene.ref.shape[1]) / FS
    phi_v0 = scene.video_phase(scene.frame_times[:1])[0]
    offset_err = []
    for p in range(len(res.ok)):
        truth = scene.epoch_phases[p]
        ph = truth(t)
        (tau,), (valid,) = matched_times(ph, FS, np.array([phi_v0]), margin=0)
        true_offset = tau[valid][0]
        period = 1.0 / truth.f0
        d = (res.offset_s[p] - true_offset + period / 2) % period - period / 2
        offset_err.append(d)
        f_true = np.polyfit(t, ph, 1)[0]           # mean f0: slope of the phase's LS line
        assert res.f0_hz[p] == pytest.approx(f_true, rel=1e-4)
        tv = scene.t0 + np.arange(scene.video_p.size) / FS
        f_v = np.polyfit(tv, scene.video_phase(tv), 1)[0]
        assert res.drift[p] == pytest.approx(f_true / f_v - 1.0, abs=1e-4)
        f_inst = truth.freq(t)
        rate = np.polyfit(t, f_inst, 1)[0] / f_inst.mean()
        assert res.drift_rate_per_s[p] == pytest.approx(rate, abs=2e-3)
    assert res.f0_video_hz == pytest.approx(f_v, rel=1e-5)
    # the offset is read near the epoch's start, where the phase spline is least constrained
    worst = np.max(np.abs(offset_err))
    assert rms(offset_err) < 3e-6 and worst < 10e-6, (
        f"offset error rms {rms(offset_err) * 1e6:.2f} us, max {worst * 1e6:.2f} us")
    assert np.all((res.quality > 0.999) & (res.quality <= 1.0))


def test_alignment_is_invariant_to_the_reference_channels_gain_and_offset():
    scene = make_scene(n_points=6, seed=9, gain=1.0, offset=0.0)
    res_pa = run_sync(scene)
    scene.ref = scene.ref * 0.0043 - 2.5            # the same signal in volts
    res_v = run_sync(scene)
    np.testing.assert_allclose(res_v.offset_s, res_pa.offset_s, atol=1e-9)
    # the aligned records may differ by what the offsets' own difference (round-off, 6e-11 s with numpy 2.4)
    # moves them: at most their steepest slope times it
    slope = np.max(np.abs(np.diff(res_pa.aligned_w, axis=1))) / np.min(np.diff(scene.frame_times))
    moved = slope * np.max(np.abs(res_v.offset_s - res_pa.offset_s))
    np.testing.assert_allclose(res_v.aligned_w, res_pa.aligned_w, rtol=0, atol=moved + 1e-6)
    np.testing.assert_allclose(res_v.quality, res_pa.quality, atol=1e-9)


def test_alignment_is_robust_to_a_strong_baseline_drift():
    scene = make_scene(n_points=8, seed=10)
    t = np.arange(scene.ref.shape[1]) / FS
    scene.ref = scene.ref + 0.4 * (t / t[-1]) + 0.3 * (t / t[-1]) ** 2   # ~ 100 Pa + 75 Pa
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "strong baseline drift")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"


def test_bad_points_are_flagged_with_reasons_and_do_not_stop_the_scan():
    scene = make_scene(n_points=8, seed=11)
    rng = np.random.default_rng(0)
    n = scene.ref.shape[1]
    scene.ref[0, 1234] = np.nan                                   # NaN in the reference
    scene.ref[1] = 0.3 + 0.01 * rng.standard_normal(n)            # no periodicity
    scene.ref[2] = 1.234                                          # constant
    t = np.arange(n) / FS
    c = pressure_coeffs(np.random.default_rng(11))
    scene.ref[3] = (800 + harmonic(c, 1.25 * 150.0 * t)) / 250.0  # f0 25% off the video's
    scene.vel[4] = np.nan                                         # no velocity at all
    scene.vel[5, 3000:3300] = np.nan                              # a speckle dropout
    res = run_sync(scene)
    assert list(res.ok) == [False, False, False, False, False, True, True, True]
    assert "non-finite" in res.reason[0]
    assert "periodicity" in res.reason[1]
    assert "periodicity" in res.reason[2]
    assert "f0" in res.reason[3] and "%" in res.reason[3]
    assert "velocity" in res.reason[4]
    assert np.all(np.isnan(res.aligned_w[~res.ok]))
    assert np.all(res.reason[res.ok] == "")
    truth = true_velocity(scene)
    rel = rms(res.aligned_w[5] - truth[5]) / rms(truth[5])
    assert rel < 0.01, f"dropout point: relative error {rel:.2e}"


def test_low_quality_points_are_rejected_at_the_documented_threshold():
    scene = make_scene(n_points=2, seed=12, noise=0.6)   # SNR ~ 1.7: correlation ~ 0.86
    res = run_sync(scene)
    assert np.all(res.quality < 0.9) and np.all(res.quality > 0.5)
    assert not res.ok.any()
    assert all("quality" in r for r in res.reason)
    assert run_sync(scene, min_quality=0.8).ok.all()


def test_too_short_epochs_are_flagged():
    scene = make_scene(n_points=3, seed=13, n_samples=500)   # 10 ms = 1.5 cycles
    res = run_sync(scene)
    assert not res.ok.any()
    assert all("too short" in r for r in res.reason)


def test_align_epoch_equals_the_row_of_sync_scan(small_scan):
    scene, res = small_scan
    video = video_phase_reference(scene.video_p, FS, scene.t0, scene.frame_times)
    one = align_epoch(scene.ref[3], scene.vel[3], FS, video)
    assert one.ok and one.reason == ""
    assert one.offset_s == pytest.approx(res.offset_s[3], abs=1e-9)  # stride, tolerance
    np.testing.assert_allclose(one.aligned_w, res.aligned_w[3], rtol=1e-6, atol=1e-4)


def test_sync_scan_rejects_mismatched_ldv_arrays():
    scene = make_scene(n_points=2, seed=14)
    with pytest.raises(InputDataError, match="points, samples"):
        sync_scan(scene.video_p, FS, scene.t0, scene.frame_times, scene.ref,
                  scene.vel[:, :-1], FS)


def test_alignment_follows_a_fast_f0_modulation_within_epochs():
    # instantaneous f0 wobbling by +-0.2% with a 50 ms period (7.5 cycles) in every record
    scene = make_scene(n_points=10, seed=15, wob=0.002, wob_period=0.05)
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "f0 wobble of period 50 ms")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"


@pytest.mark.parametrize("f0", [100.0, 250.0])
def test_alignment_across_the_f0_range_with_short_records(f0):
    # 0.06 s of video pressure (0.05 s of frames), 0.1 s LDV epochs
    scene = make_scene(n_points=6, seed=16, f0=f0, n_samples=5_000, n_frames=500,
                       video_len=0.06)
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, f"f0 {f0:.0f} Hz, short records")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"
    rel = rms(res.aligned_w - true_velocity(scene)) / rms(true_velocity(scene))
    assert rel < 0.01, f"aligned velocity relative RMS error {rel:.2e}"


def test_alignment_is_invariant_to_the_video_pressures_gain_and_offset():
    scene = make_scene(n_points=4, seed=17)
    res_pa = run_sync(scene)
    scene.video_p = scene.video_p * 0.0037 + 0.8
    res_v = run_sync(scene)
    np.testing.assert_allclose(res_v.video_phase, res_pa.video_phase, atol=1e-9)
    np.testing.assert_allclose(res_v.offset_s, res_pa.offset_s, atol=1e-9)


def test_a_strongly_drifting_video_pressure_is_still_tracked():
    # f0 changes by 2% over the 0.2 s video record (and by up to 2% within each epoch)
    scene = make_scene(n_points=4, seed=18, lin=0.1)
    scene.video_phase.lin = 0.1
    rng = np.random.default_rng(18)
    tv = scene.t0 + np.arange(scene.video_p.size) / FS
    coeffs = pressure_coeffs(np.random.default_rng(18))
    osc_std = np.sqrt(np.sum(np.abs(coeffs) ** 2) / 2)
    scene.video_p = (800.0 + harmonic(coeffs, scene.video_phase(tv))
                     + 0.02 * osc_std * rng.standard_normal(tv.size))
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "2% f0 drift over the video")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"


def test_sync_scan_raises_when_the_video_pressure_is_not_periodic():
    scene = make_scene(n_points=2, seed=19)
    noise = np.random.default_rng(0).standard_normal(scene.video_p.size)
    with pytest.raises(InputDataError, match="periodicity") as err:
        sync_scan(noise, FS, scene.t0, scene.frame_times, scene.ref, scene.vel, FS,
                  source="hsv_pressure.tdms")
    assert "hsv_pressure.tdms" in str(err.value)


def test_fundamental_phase_reference_is_robust_to_a_changed_waveform_shape():
    # every epoch's pressure harmonics 2.. differ by ~5% in amplitude and 0.05 rad in phase
    # from the video's; the velocity stays locked to the fundamental's phase
    scene = make_scene(n_points=12, seed=20, shape_jitter=0.05)
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "5% waveform-shape change, fundamental reference")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"
    # the whole-template reference is biased by the shape change (what the default avoids)
    biased = rms(timing_errors(scene, run_sync(scene, phase_reference="template")))
    print(f"template reference: {biased * 1e6:.2f} us")
    assert biased > 2 * value


def test_template_phase_reference_meets_the_target_on_an_unchanged_waveform(small_scan):
    scene, _ = small_scan
    res = run_sync(scene, phase_reference="template")
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, "template reference")
    assert value < 5e-6, f"RMS timing error {value * 1e6:.2f} us"


def test_invalid_sync_settings_are_bugs_in_the_core_and_user_errors_in_the_config(small_scan):
    """The core refuses bad settings with ValueError; the [sync] config refuses them first as ConfigError."""
    from vfcli.config import load_config
    from vfcli.errors import ConfigError

    scene, _ = small_scan
    with pytest.raises(ValueError, match="phase_reference"):
        run_sync(scene, phase_reference="peak")
    with pytest.raises(ValueError, match="min_quality"):
        run_sync(scene, min_quality=1.5)
    with pytest.raises(ValueError, match="knot_cycles"):
        run_sync(scene, knot_cycles=0.0)
    with pytest.raises(ValueError, match="f_range"):
        run_sync(scene, f_range=(300.0, 100.0))
    for override, field in (("sync.phase_reference=peak", "phase_reference"), ("sync.min_quality=1.5", "min_quality"),
                            ("sync.knot_cycles=0", "knot_cycles"), ("sync.f0_min_hz=600", "f0_min_hz")):
        with pytest.raises(ConfigError, match=field):
            load_config(overrides=[override])


def test_an_inverted_reference_channel_is_rejected():
    scene = make_scene(n_points=3, seed=21)
    scene.ref[1] = -scene.ref[1]
    res = run_sync(scene)
    assert list(res.ok) == [True, False, True]
    assert res.quality[1] < 0.9


def test_phase_track_follows_the_true_phase_of_a_drifting_pressure():
    from vfcli.sync.align import phase_track

    rng = np.random.default_rng(22)
    coeffs = pressure_coeffs(rng)
    truth = Phase(160.0, 0.37, lin=0.05, wob=0.002, period=0.1)
    t = np.arange(10_000) / FS
    osc_std = np.sqrt(np.sum(np.abs(coeffs) ** 2) / 2)
    p = 800 + harmonic(coeffs, truth(t)) + 0.02 * osc_std * rng.standard_normal(t.size)
    track, template = phase_track(p, FS)
    d = track.phase_at(t)[0] - truth(t)
    d -= np.median(d)
    assert rms(d) / 160.0 < 2e-6, f"phase error {rms(d) / 160.0 * 1e6:.2f} us"
    # phase zero = fundamental maximum: the offset is the true fundamental's phase
    off = (track.phase_at(t)[0] - truth(t)).mean() - np.angle(coeffs[0]) / (2 * np.pi)
    assert abs(off - np.round(off)) < 1e-3
    # the same record measured against its own template gives the same phase
    again, _ = phase_track(p, FS, template=template)
    assert rms(again.phase_at(t)[0] - track.phase_at(t)[0]) < 1e-3


def test_banded_normal_equations_equal_the_dense_gemm_ones():
    from vfcli.sync.gauss_newton import BandedBasis, normal_equations, normal_equations_banded
    from vfcli.sync.phase import baseline_basis, phase_basis

    rng = np.random.default_rng(23)
    basis, _ = phase_basis(np.sort(rng.uniform(0, 1, 900)), 7, 3)
    base = baseline_basis(900)
    a, r = rng.standard_normal((2, 5, 900))
    cols = rng.standard_normal((5, 3, 900))
    dense = normal_equations(a, cols, r, basis, base)
    banded = normal_equations_banded(a, cols, r, BandedBasis(basis), base)
    for d, b in zip(dense, banded):
        np.testing.assert_allclose(b, d, rtol=1e-10, atol=1e-10 * np.abs(d).max())


def test_the_core_defaults_of_sync_are_the_configs():
    """One source for the sync settings: every default of the core's public functions is the
    [sync] config's default, under its core name."""
    import inspect

    from vfcli.config import SyncConfig
    from vfcli.sync import align, f0, phase

    d = SyncConfig()
    names = {"n_harmonics": d.n_harmonics, "knot_cycles": d.knot_cycles, "max_f0_deviation": d.max_drift,
             "min_quality": d.min_quality, "min_cycles": d.min_cycles, "smooth": d.smooth,
             "phase_reference": d.phase_reference, "f_range": (d.f0_min_hz, d.f0_max_hz)}
    seen = 0
    for fn in (align.sync_scan, align.align_epoch, align.phase_track, align.video_phase_reference,
               align.epoch_phase_tracks, f0.estimate_f0, f0.coarse_f0, phase.track_phase, phase.fit_free_phase):
        for name, param in inspect.signature(fn).parameters.items():
            if name in names and param.default is not inspect.Parameter.empty:
                assert param.default == names[name], (fn.__name__, name)
                seen += 1
    assert seen >= 25


@pytest.mark.parametrize("noise, limit_us", [(0.02, 1.2), (0.10, 5.5)])
def test_the_strided_fit_averages_the_samples_it_skips(noise, limit_us):
    """The phase fit runs on every stride-th sample; without averaging the skipped ones first it saw their whole white
    noise (vfcli.sync.phase.prefiltered).  40 points, pressure noise 2 % / 10 % of the pulse: RMS timing error 1.50 /
    6.94 us strided alone, 0.87 / 4.28 us averaged (measured)."""
    scene = make_scene(n_points=40, seed=21, noise=noise)
    res = run_sync(scene)
    assert res.ok.all(), set(res.reason)
    value = _report_timing(scene, res, f"pressure noise {noise:.0%}")
    assert value < limit_us * 1e-6, f"RMS timing error {value * 1e6:.2f} us"


def test_the_average_before_striding_keeps_a_harmonic_in_phase_and_the_ends_as_recorded():
    """vfcli.sync.phase.prefiltered with stride 6 (7 samples): a sinusoid of 48 samples per period comes out in
    phase, scaled by the moving average's gain; white noise keeps 1/7 of its variance; the first and last 3 samples
    are the record's own (a reflected average there moved 47 of rig 1111's 374 points by about -6 us)."""
    from vfcli.sync.phase import prefiltered

    n, period = 4800, 48.0
    k = np.arange(n)
    sine = np.sin(2 * np.pi * k / period + 0.3)
    out = prefiltered(sine, 6)
    gain = np.mean(np.cos(2 * np.pi * np.arange(-3, 4) / period))
    np.testing.assert_allclose(out[3:-3], gain * sine[3:-3], atol=1e-12)
    np.testing.assert_array_equal(out[:3], sine[:3])
    np.testing.assert_array_equal(out[-3:], sine[-3:])
    noise = np.random.default_rng(5).normal(size=(4, 20_000))
    ratio = prefiltered(noise, 6)[:, 3:-3].var() / noise.var()
    assert ratio == pytest.approx(1 / 7, rel=0.05)
    assert prefiltered(noise, 1) is noise


def test_pressure_levels_over_whole_cycles_and_their_tolerance():
    """vfcli.sync.levels: the mean and swing of 800 + 300 sin over 2.6 cycles are those of its 2 whole cycles
    (800 Pa and 300 / sqrt 2 exactly); a level 5 % off agrees, one 20 % off does not, and a scan whose points
    spread widely widens the tolerance to 4 of their standard deviations."""
    from vfcli.sync.levels import cycle_levels, level_mismatch

    fs, f0 = 50_000.0, 125.0
    t = np.arange(int(2.6 * fs / f0)) / fs
    mean, swing = cycle_levels(800 + 300 * np.sin(2 * np.pi * f0 * t), fs, f0)
    assert mean == pytest.approx(800.0, abs=1e-9) and swing == pytest.approx(300 / np.sqrt(2), rel=1e-9)
    assert cycle_levels(t[:100], fs, f0) is None                                  # no whole cycle
    points = np.column_stack([np.full(50, 800.0), np.full(50, 212.0)])
    assert level_mismatch((840.0, 212.0), points) == []
    assert [m[0] for m in level_mismatch((960.0, 170.0), points)] == ["mean", "swing"]
    spread = points + np.column_stack([np.linspace(-60, 60, 50), np.zeros(50)])   # sd 35 Pa: tolerance 140 Pa
    assert level_mismatch((930.0, 212.0), spread) == [] and level_mismatch((960.0, 212.0), spread)[0][0] == "mean"


def test_frame_times_beyond_the_pressure_record_name_the_frame_rate():
    """A CIHX recordRate of 1000 for 10000 (frame times ten times too long) was refused without naming the frame
    rate: the message now says what to check."""
    from vfcli.errors import InputDataError
    from vfcli.sync.align import video_phase_reference

    fs = 50_000.0
    p = 800 + 300 * np.sin(2 * np.pi * 120.0 * np.arange(1500) / fs)          # 30 ms of pressure
    with pytest.raises(InputDataError, match=r"does not cover the frame times \(0.000000-0.299000 s\): check the "
                                             r"video's frame rate \(the file's, or camera.fps_hz\)"):
        video_phase_reference(p, fs, 0.0, np.arange(300) / 1000.0)
