"""The score test of vfcli.diagnose.candidates.screening on a linear problem with known noise.

r = J_L a + J_c theta + e, e ~ N(0, I): under the null (theta = 0) the statistic is chi2(p), so
its false-alarm rate at alpha = 0.05 is 0.05 (checked both ways over many draws); with an effect
its rejection rate is the noncentral chi2 power (scipy.stats.ncx2, an independent formula).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from vfcli.diagnose.candidates.identifiability import identifiability, load_basis
from vfcli.diagnose.candidates.screening import score_test

M, Q, P = 300, 15, 2
N_DRAWS = 3000
ALPHA = 0.05


def _problem(seed: int = 0):
    rng = np.random.default_rng(seed)
    jl = rng.normal(size=(M, Q))
    # a candidate partly, not wholly, in the load span
    jc = 0.7 * jl[:, :P] @ rng.normal(size=(P, P)) + rng.normal(size=(M, P))
    return rng, jl, jc


def _rejections(theta: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng, jl, jc = _problem(seed)
    q = load_basis(jl)
    stat = np.empty(N_DRAWS)
    est = np.empty((N_DRAWS, P))
    for i in range(N_DRAWS):
        r = jl @ rng.normal(scale=5.0, size=Q) + jc @ theta + rng.normal(size=M)
        t = score_test(jc, r, q=q)
        stat[i] = t.statistic
        est[i] = t.estimate
    return stat, est


def test_score_statistic_is_chi2_under_the_null():
    stat, _ = _rejections(np.zeros(P), seed=1)
    rate = np.mean(stats.chi2.sf(stat, P) < ALPHA)
    se = np.sqrt(ALPHA * (1 - ALPHA) / N_DRAWS)
    assert abs(rate - ALPHA) < 3.5 * se, rate                     # neither too many nor too few alarms
    assert abs(stat.mean() - P) < 3.5 * np.sqrt(2 * P / N_DRAWS)
    assert stats.kstest(stat, stats.chi2(P).cdf).pvalue > 1e-3


def test_score_test_has_the_noncentral_chi2_power_and_an_unbiased_estimate():
    _, jl, jc = _problem(2)
    info = identifiability(jc, jl).information
    theta = np.array([1.0, -0.5])
    theta *= np.sqrt(12.0 / (theta @ info @ theta))               # noncentrality 12
    stat, est = _rejections(theta, seed=2)
    power = stats.ncx2.sf(stats.chi2.ppf(1 - ALPHA, P), P, 12.0)  # 0.83
    rate = np.mean(stats.chi2.sf(stat, P) < ALPHA)
    assert abs(rate - power) < 3.5 * np.sqrt(power * (1 - power) / N_DRAWS), (rate, power)
    sd = np.sqrt(np.diag(np.linalg.inv(info)))
    assert np.all(np.abs(est.mean(axis=0) - theta) < 3.5 * sd / np.sqrt(N_DRAWS))


def test_a_term_inside_the_load_span_is_not_identifiable_and_never_alarms():
    rng, jl, _ = _problem(3)
    jc = jl[:, :P] @ rng.normal(size=(P, P))                       # the loads can make exactly this
    t = score_test(jc, jl @ rng.normal(size=Q) + jc @ np.ones(P) + rng.normal(size=M), jl)
    assert not t.identifiability.identifiable
    assert t.identifiability.residual_fraction < 1e-20
    assert t.p_value == 1.0 and t.dof == 0
