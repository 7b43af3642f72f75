"""## False alarms of the run screening on noise-only residuals (docs/diagnose.md).

The pressure-model case of tests/_candidates_case.py (coarse 2 mm mesh, 4 px/mm camera, one cycle of
170 Hz in 12 frames), its baseline at the controls that made the data, and white velocity noise of
2 mm/s on every valid pixel, drawn anew per replicate; each replicate is screened with
:func:`vfcli.diagnose.candidates.blocks.screen_run` (all four candidates).  Printed: the share of
replicates with any candidate below 0.05 / 4 (the family-wise false-alarm rate, nominal <= 0.05),
and per candidate the share below 0.05 (nominal 0.05).

White noise only: the residual of a real recording is correlated and holds model error; this measures
the test's calibration where its assumptions hold, not on recordings.

Reproduce::

    .venv/bin/python bench/bench_screening_null.py [--draws 40]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from _candidates_case import pressure_case  # noqa: E402
from vfcli.diagnose.candidate import Baseline  # noqa: E402
from vfcli.diagnose.candidates import CANDIDATES  # noqa: E402
from vfcli.diagnose.candidates.blocks import screen_run  # noqa: E402
from vfcli.inverse.problem import Problem  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--noise", type=float, default=2.0, help="velocity noise, mm/s")
    args = ap.parse_args()
    t0 = time.perf_counter()
    base = pressure_case()
    p = base.problem
    m = p.meas
    rng = np.random.default_rng(2026)
    pv = np.zeros((args.draws, len(CANDIDATES)))
    for i in range(args.draws):
        noisy = m.velocity + rng.normal(scale=args.noise, size=m.velocity.shape) * m.valid[..., None]
        meas = type(m)(m.times, noisy, m.valid, m.gap_lo, m.gap_hi, m.gap)
        b = Baseline.at(Problem(p.mesh, p.camera, p.response, meas, p.settings), base.x, base.f0_hz)
        pv[i] = [t.p_value for t in screen_run(CANDIDATES, b)]
        print(i, np.round(pv[i], 3), flush=True)
    n = len(CANDIDATES)
    fam = np.mean(np.any(pv < 0.05 / n, axis=1))
    print(f"\n{args.draws} noise-only draws: family-wise false alarms {fam:.3f} (nominal <= 0.05)")
    for c, col in zip(CANDIDATES, pv.T):
        print(f"  {c.name}: share p < 0.05 = {np.mean(col < 0.05):.3f}, median p = {np.median(col):.2f}")
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
