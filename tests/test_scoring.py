"""The phantom scores' own arithmetic (vfcli/synth/scoring.py)."""
import numpy as np

from vfcli.synth.scoring import interval_coverage


def test_coverage_leaves_out_what_the_model_fixes_and_counts_a_wrong_zero_interval_as_a_miss():
    """A clamped node (stated sd 0, estimate right up to round-off) has no interval: it neither adds
    a hit nor, through a 1e-17 mm round-off error, a miss.  Of 1000 normal errors with their true sd,
    90 % intervals cover 90 % within the binomial spread, whatever share of clamped entries is added,
    and an sd-0 entry that is wrong is a miss."""
    rng = np.random.default_rng(3)
    sd = rng.uniform(0.01, 0.1, 1000)
    truth = rng.normal(size=1000)
    est = truth + sd * rng.normal(size=1000)
    free = interval_coverage(est, sd, truth)
    assert abs(free - 0.90) < 3 * np.sqrt(0.9 * 0.1 / 1000)
    for roundoff in (0.0, 1e-17):
        clamped_est = np.concatenate([est, np.full(300, roundoff)])
        clamped_sd = np.concatenate([sd, np.zeros(300)])
        clamped_truth = np.concatenate([truth, np.zeros(300)])
        assert interval_coverage(clamped_est, clamped_sd, clamped_truth) == free
    wrong = interval_coverage(np.append(est, 0.5), np.append(sd, 0.0), np.append(truth, 0.0))
    assert wrong == (free * 1000) / 1001
