"""The bootstrap calibration of the candidates' screening (vfcli.diagnose.calibrate) on a linear problem.

A recording of whole cycles, each of T time samples on S spatial points: data = loads + noise,
the noise AR(1) in time within a cycle (rho 0.9, shared across neighbouring points: correlated in
space and time) and independent between cycles; the fit is cycle 0 (the window), the other cycles
are the pool the noise is resampled from.  Four candidates with smooth columns, partly inside the
load span.  Checked, each against an independent reference:

- under the null the naive chi2 score test (white noise of the residual's scale) over-rejects
  badly, the bootstrap p-values are uniform (Kolmogorov-Smirnov) and reject at 0.05 within
  binomial error, both ways;
- the family-wise rate over the four candidates (Westfall-Young) is at or below 0.05 within error;
- with a periodic model error (a smooth field repeated in every cycle, the loads' and candidates'
  own family) on top, the noise-only bootstrap and the naive test alarm on most draws, the
  calibrated test on about 0.1 (above nominal: the stated limit of the method);
- with an injected effect well above the model error the calibrated test has power and names the
  right candidate.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy import stats

from vfcli.diagnose.calibrate import (NullParts, ScoreBasis, calibrate, detection_thresholds, quadrature_scores,
                                     replicate_statistics, smallest_detectable, statistics, westfall_young)
from vfcli.diagnose.candidates.identifiability import load_basis, project_out
from vfcli.diagnose.candidates.screening import score_test
from vfcli.parallel import serial_map

S, T = 12, 40                   # spatial points, samples per cycle
M = S * T                       # rows per cycle, time-major: row = t * S + s
N_CYCLES = 13                   # cycle 0 is the window, 12 in the pool
RHO = 0.9
ALPHA = 0.05
N_DRAWS = 150
B = 199


def _smooth(rng, n_cols: int, n_modes: int = 3) -> np.ndarray:
    """(M, n_cols) smooth periodic space-time columns."""
    t = np.arange(T)[:, None, None] / T
    x = np.arange(S)[None, :, None] / S
    out = np.zeros((T, S, n_cols))
    for k in range(1, n_modes + 1):
        for j in range(1, n_modes + 1):
            a = rng.normal(size=(4, n_cols)) / (k * j)
            out += (a[0] * np.cos(2 * np.pi * k * t) + a[1] * np.sin(2 * np.pi * k * t)) * \
                   (a[2] * np.cos(np.pi * j * x) + a[3] * np.sin(np.pi * j * x))
    return out.reshape(M, n_cols)


def _problem(seed: int = 0):
    rng = np.random.default_rng(seed)
    jl = _smooth(rng, 6)
    cands = [0.5 * jl[:, :1] + _smooth(rng, 1), _smooth(rng, 1), 0.3 * jl[:, 2:4] + _smooth(rng, 2), _smooth(rng, 1)]
    q = load_basis(jl)
    cols = [project_out(c, q) for c in cands]
    basis = ScoreBasis(cols, [c.T @ c for c in cols], [True] * len(cols))
    return jl, q, cands, cols, basis


def _noise(rng, n: int) -> np.ndarray:
    """(n, M) AR(1) in time within each cycle, correlated across neighbouring points, unit-ish scale."""
    e = np.empty((n, T, S))
    w = rng.normal(size=(n, T, S))
    w = w + np.roll(w, 1, axis=2) + np.roll(w, -1, axis=2)
    e[:, 0] = w[:, 0] / np.sqrt(1 - RHO ** 2)
    for t in range(1, T):
        e[:, t] = RHO * e[:, t - 1] + w[:, t]
    return e.reshape(n, M)


def _calibrated(data: np.ndarray, q, cols, basis, seed: int, model_error_null: bool = True):
    """The pipeline of a run on a (N_CYCLES, M) recording: fit cycle 0, template and deviations from the pool."""
    y0, pool = data[0], data[1:]
    r = project_out(y0, q)                                       # the loads refitted on the window
    template = pool.mean(axis=0)
    dev = pool - template
    s = r - (y0 - template)                                      # the window's systematic residual
    s = project_out(s, q)                                        # what the loads cannot make
    shifts = quadrature_scores(s.reshape(T, S), [w.reshape(T, S, -1) for w in basis.weights]) if model_error_null \
        else np.zeros((0, sum(basis.sizes)))
    if model_error_null:                                         # as calibrate_run: the loads' share of each turn
        for j, a in enumerate(np.concatenate(cols, axis=1).T):
            h = _hilbert(a)
            shifts[:, j] /= np.sqrt(max(np.sum(project_out(h, q) ** 2) / np.sum(h ** 2), 0.05))
    parts = NullParts(basis.scores(dev.T).T, shifts)
    return r, calibrate(basis, r, parts, B, seed)


def _hilbert(v: np.ndarray) -> np.ndarray:
    x = np.fft.rfft(v.reshape(T, S), axis=0) * -1j
    x[0] = 0.0
    return np.fft.irfft(x, n=T, axis=0).ravel()


def _naive(r: np.ndarray, cols) -> np.ndarray:
    sigma = np.sqrt(np.mean(r ** 2) * M / (M - 6))
    return np.array([score_test(c / sigma, r / sigma, q=np.zeros((M, 0))).p_value for c in cols])


def _draws(effect: np.ndarray | None = None, model_error: bool = False, model_error_null: bool = True, seed: int = 1,
           one_sided: tuple[bool, ...] = ()):
    jl, q, cands, cols, basis = _problem(0)
    basis = ScoreBasis(basis.weights, basis.information, basis.identifiable, one_sided)
    rng = np.random.default_rng(seed)
    naive, boot, fam = [], [], []
    for i in range(N_DRAWS):
        data = jl @ rng.normal(scale=5.0, size=(jl.shape[1], 1)) + 0.0
        data = np.repeat(data.T, N_CYCLES, axis=0) + _noise(rng, N_CYCLES)
        if model_error:
            data += 3.0 * _smooth(rng, 1, n_modes=4)[:, 0]          # the same in every cycle, a new field per draw
        if effect is not None:
            data += effect
        r, cal = _calibrated(data, q, cols, basis, seed=i, model_error_null=model_error_null)
        naive.append(_naive(r, cols))
        boot.append(cal.p_value)
        fam.append(cal.p_family)
    return np.array(naive), np.array(boot), np.array(fam), cands


def _binomial_band(p: float, n: int, z: float = 3.5) -> float:
    return z * np.sqrt(p * (1 - p) / n)


def test_replicates_are_reproducible_and_independent_of_the_map():
    rng = np.random.default_rng(3)
    parts = NullParts(rng.normal(size=(7, 5)), rng.normal(size=(11, 5)))
    args = (parts, (1, 2, 2), (True, True, False), 150)
    a = replicate_statistics(*args, seed=4)
    with ThreadPoolExecutor(2) as pool:                  # a real parallel Mapper (vfcli.parallel)
        b = replicate_statistics(*args, seed=4, map=pool.map)
    c = replicate_statistics(*args, seed=5)
    d = replicate_statistics(*args, seed=4, map=serial_map)
    assert a.shape == (3, 150) and np.array_equal(a, b) and np.array_equal(a, d) and not np.allclose(a, c)
    assert np.all(a[2] == 0) and np.all(a[:2] > 0)


def test_batched_replicate_statistics_are_each_replicates_own():
    """The chunk's statistics, computed for all its replicates at once (one batched eigendecomposition per
    candidate), equal :func:`statistics` of each replicate's scores with that replicate's own covariances,
    redrawn one by one from the same stream: rank-deficient covariances (a pool column of zeros), one-sided
    and unidentifiable candidates included."""
    from vfcli.diagnose.calibrate import _replicate_chunk, model_error_covariances, noise_covariances

    rng = np.random.default_rng(8)
    noise = rng.normal(size=(6, 7))
    model_error = 0.4 * rng.normal(size=(9, 7))
    noise[:, 0] = model_error[:, 0] = 0.0                # the first candidate's first score never varies
    parts = NullParts(noise, model_error)
    sizes, ident, sided = (2, 1, 3, 1), (True, True, True, False), (False, True, False, False)
    got = _replicate_chunk(parts, sizes, ident, 21, 40, sided)
    draw = np.random.default_rng(21)
    d = parts.noise / np.sqrt(parts.n_pool - 1)
    for b in range(40):
        draws = draw.standard_normal((parts.n_pool + 1, parts.n_pool)) @ d
        u = draws[0] + draw.standard_normal(9) @ parts.model_error
        w = draw.standard_normal(9) ** 2
        covs = [a + e for a, e in zip(noise_covariances(draws[1:], sizes, centred=True),
                                      model_error_covariances(parts.model_error, sizes, w))]
        np.testing.assert_allclose(got[:, b], statistics(u, covs, ident, sided), rtol=1e-9, atol=1e-12)
    assert np.all(got[3] == 0) and np.any(got[1] == 0) and np.any(got[1] > 0)


def test_null_bootstrap_is_uniform_where_the_naive_chi2_over_rejects():
    naive, boot, fam, _ = _draws()
    band = _binomial_band(ALPHA, boot.size)
    naive_rate = np.mean(naive < ALPHA)
    boot_rate = np.mean(boot <= ALPHA)
    print(f"naive rate {naive_rate:.3f}, bootstrap rate {boot_rate:.3f}, family-wise {np.mean(fam.min(1) <= ALPHA):.3f}")
    assert naive_rate > 3 * ALPHA, naive_rate                       # correlated noise: the chi2 reference is wrong
    assert abs(boot_rate - ALPHA) < band, boot_rate                 # two-sided: neither too many nor too few
    assert stats.kstest(boot.ravel(), "uniform").pvalue > 1e-3
    fw = np.mean(fam.min(axis=1) <= ALPHA)
    assert fw <= ALPHA + _binomial_band(ALPHA, len(fam)), fw


def test_periodic_model_error_is_mostly_absorbed_by_the_calibration():
    """A smooth model error repeated in every cycle, drawn from the same low-dimensional family as the loads and
    the candidates (adversarial: the loads absorb about half of its quarter-period turn): the noise-only bootstrap
    and the naive test alarm on most recordings; the calibrated one much less, but still above nominal (measured
    0.107 over 150 draws): the known limit of the quadrature estimate (docs/diagnose.md)."""
    naive, boot, fam, _ = _draws(model_error=True, seed=2)
    fw = np.mean(fam.min(axis=1) <= ALPHA)
    _, _, fam_noise_only, _ = _draws(model_error=True, model_error_null=False, seed=2)
    fw_noise_only = np.mean(fam_noise_only.min(axis=1) <= ALPHA)
    fw_naive = np.mean(naive.min(axis=1) < ALPHA / 4)
    print(f"family-wise with model error: {fw:.3f}; noise-only null {fw_noise_only:.3f}; naive {fw_naive:.3f}")
    assert fw_noise_only > 0.25 and fw_naive > 0.8, (fw_noise_only, fw_naive)   # measured 0.33, 0.91
    assert fw < 0.16, fw                                                           # measured 0.107; nominal 0.05


def test_an_injected_effect_is_found_and_named_above_the_model_error():
    jl, q, cands, cols, basis = _problem(0)
    info = float(cols[1][:, 0] @ cols[1][:, 0])
    theta = 20.0 * np.sqrt(RHO_VAR / info)
    _, boot, fam, _ = _draws(effect=cands[1][:, 0] * theta, model_error=True, seed=3)
    found = np.mean(fam[:, 1] <= ALPHA)
    named = np.mean(np.argmin(fam, axis=1) == 1)
    print(f"power {found:.3f}, named {named:.3f}")
    assert found > 0.85 and named > 0.8, (found, named)                            # measured 0.95, 0.91


#: variance of the AR(1) noise per row (innovation variance 3 from the three shared points)
RHO_VAR = 3.0 / (1 - RHO ** 2)


def test_a_one_sided_candidate_keeps_its_level_and_counts_only_the_physical_sign():
    """Candidates 1 and 3 (one parameter each) one-sided, as a retardation time or a contact share: under the
    null their calibrated p-values still reject at 0.05 within binomial error (the null's atom at 0 gives
    p = 1); an effect of the unphysical sign on candidate 1 is no lead, the same size with the physical sign
    on candidate 3 is found."""
    sided = (False, True, False, True)
    _, boot, fam, _ = _draws(one_sided=sided, seed=4)
    rates = np.mean(boot[:, [1, 3]] <= ALPHA, axis=0)
    print(f"one-sided null rates {rates}, family-wise {np.mean(fam.min(1) <= ALPHA):.3f}")
    assert np.all(np.abs(rates - ALPHA) < _binomial_band(ALPHA, len(boot))), rates
    assert np.mean(boot[:, [1, 3]] == 1.0) > 0.35                     # the atom: about half the draws
    jl, q, cands, cols, basis = _problem(0)
    size = [8.0 * np.sqrt(RHO_VAR / float(cols[c][:, 0] @ cols[c][:, 0])) for c in (1, 3)]
    effect = -size[0] * cands[1][:, 0] + size[1] * cands[3][:, 0]
    _, boot, fam, _ = _draws(effect=effect, one_sided=sided, seed=5)
    wrong, right = np.mean(fam[:, 1] <= ALPHA), np.mean(fam[:, 3] <= ALPHA)
    print(f"unphysical sign found {wrong:.3f}, physical sign found {right:.3f}")
    assert wrong <= ALPHA and right > 0.8, (wrong, right)


def test_the_smallest_detectable_size_is_named_about_half_the_time():
    """:func:`smallest_detectable`: the size of a one-parameter candidate at which the calibrated screening
    names it about half the time (the noise-only null; its threshold and studentizing covariance do not depend
    on the window's residual).  Per draw: the limit of candidates 1 (two-sided) and 3 (one-sided), then each
    present at 0.5, 1 and 2 times it in the window's score (``I_c theta``, the linear model), decided by
    :func:`westfall_young` against the same replicates.  At the limit itself the one-sided candidate is named
    when the window's noise score is positive, the two-sided one also far on the other side: 0.5 within
    binomial error; at twice it nearly always, at half rarely.  And :func:`detection_thresholds` is the edge
    of the adjusted p-value: just above it a lead, just below not."""
    jl, q, cands, cols, basis = _problem(0)
    sided = (False, False, False, True)
    basis = ScoreBasis(basis.weights, basis.information, basis.identifiable, sided)
    rng = np.random.default_rng(6)
    named = {(c, k): [] for c in (1, 3) for k in (0.5, 1.0, 2.0)}
    limits = []
    for i in range(N_DRAWS):
        data = np.repeat((jl @ rng.normal(scale=5.0, size=(jl.shape[1], 1))).T, N_CYCLES, axis=0) + _noise(rng, N_CYCLES)
        r, cal = _calibrated(data, q, cols, basis, seed=i, model_error_null=False)
        lim = smallest_detectable(cal, basis.information, ALPHA)
        assert (lim[[0, 1, 3]] > 0).all() and np.isnan(lim[2])          # candidate 2 has two parameters
        limits.append(lim)
        t_star = detection_thresholds(cal.null_statistics, ALPHA)
        for c in range(4):
            obs = cal.statistic.copy()
            for eps, lead in ((1e-9, True), (-1e-9, False)):
                obs[c] = t_star[c] * (1 + eps)
                assert (westfall_young(obs, cal.null_statistics)[c] <= ALPHA) == lead, (i, c, eps)
        u = basis.scores(r)
        for c in (1, 3):
            for k in (0.5, 1.0, 2.0):
                uc = u.copy()
                at = sum(basis.sizes[:c])                              # its entry in the stacked scores
                uc[at] += basis.information[c][0, 0] * k * lim[c]      # the candidate present at k times its limit
                obs = statistics(uc, cal.covariances, basis.identifiable, sided)
                named[(c, k)].append(westfall_young(obs, cal.null_statistics)[c] <= ALPHA)
    rate = {key: float(np.mean(v)) for key, v in named.items()}
    print("named at 0.5, 1, 2 times the limit:", rate, "limits (median):", np.median(limits, axis=0))
    band = _binomial_band(0.5, N_DRAWS)
    for c in (1, 3):
        assert abs(rate[(c, 1.0)] - 0.5) < band, rate
        assert rate[(c, 2.0)] > 0.9 and rate[(c, 0.5)] < 0.25, rate
