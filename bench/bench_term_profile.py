"""## A term's profile: does contact or damping fit a recording better once the loads are refitted? (issue 16)

The score tests of contact and damping linearise at theta = 0 with the baseline's own loads, and the blind
panel's contact and damping phantoms gave some of them no lead (contact seeds 2004, 2009: calibrated p 0.89,
0.98; damping seeds 2008, 2013).  As inertia's profile does (:func:`vfcli.diagnose.refit.load_profile`),
this measures E with the term switched on at a few values and the loads refitted, against the baseline
given the same number of load-only Gauss-Newton steps (all of them, ``rtol = 0``: on the contact phantoms
E differs by hundredths of a percent, below what one more step gains):

* contact: the share of the rigid contact of the linear folds (0.5, 1), E's gradient pulled back through
  the contact forces (``Contact.pullback``; the load block is the baseline's);
* damping: the Kelvin-Voigt retardation time at loss factors 0.05, 0.1, 0.2, 0.4 at the recording's f0
  (``tau = loss / (2 pi f0)``), the loads refitted under the viscoelastic steady state
  (``KelvinVoigtDamping.response``, exact x-columns);
* delay: the load's delay behind the recorded subglottal pressure (``LoadDelay``, the alternative
  explanation of a lag: the same column as damping's at 0) at 0.01, 0.02, 0.05, 0.1 cycles of f0.

Reads only the stores (no truth.h5); the baseline is the store's run ``default``; f0 is the subglottal
pressure's (/sync), the one the diagnosis counts the glottal cycles with.

Reproduce (stores of a kept panel, e.g. ``bench_diagnose.py --keep DIR``)::

    .venv/bin/python bench/bench_term_profile.py contact DIR/seed2004_contact/recording.h5 ... [--steps 8]
    .venv/bin/python bench/bench_term_profile.py damping DIR/seed2003_damping/recording.h5 ...
    .venv/bin/python bench/bench_term_profile.py delay DIR/seed2003_damping/recording.h5 ...
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

#: the values profiled: contact shares; damping loss factors at f0
VALUES = {"contact": (0.5, 1.0), "damping": (0.05, 0.1, 0.2, 0.4), "delay": (0.01, 0.02, 0.05, 0.1)}


def profile(store: Path, term_name: str, steps: int, values=None) -> dict:
    """E of the baseline and of the term at :data:`VALUES`, the loads refitted by up to ``steps`` steps each."""
    from vfcli.config import load_config
    from vfcli.diagnose.candidates.contact import Contact
    from vfcli.diagnose.candidates.damping import MS, KelvinVoigtDamping
    from vfcli.diagnose.candidates.delay import LoadDelay
    from vfcli.diagnose.refit import load_profile
    from vfcli.stages.diagnose import read_inputs
    from vfcli.store import Store

    with Store(store).read() as r:
        _, cfg = load_config(stored_json=r.recording_config_json())
        inputs = read_inputs(r, cfg, "default")
    base = inputs.baseline
    base.f0_hz = float(inputs.recording.pressure_f0_hz)
    values = VALUES[term_name] if values is None else tuple(values)
    if term_name == "contact":
        term, thetas = Contact(), list(values)
    elif term_name == "delay":
        term, thetas = LoadDelay(), [v / base.f0_hz / MS for v in values]
    else:
        term = KelvinVoigtDamping(getattr(base, "model", None))
        thetas = [v / (2 * np.pi * base.f0_hz) / MS for v in values]
    t = time.perf_counter()
    e0, e = load_profile(base, term, [np.array([v]) for v in thetas], steps=steps, best_steps=steps, rtol=0.0)
    out = {"store": str(store), "f0_hz": float(base.f0_hz), "e0": e0, "values": list(values),
           "theta": [float(v) for v in thetas], "e": [float(v) for v in e], "seconds": time.perf_counter() - t}
    if term_name == "contact":
        out["overlap_mm"] = float(term.overlap(base).max())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("term", choices=sorted(VALUES))
    ap.add_argument("stores", nargs="+", type=Path)
    ap.add_argument("--steps", type=int, default=8, help="load steps at each value (and for the baseline)")
    ap.add_argument("--values", type=float, nargs="+", help="the values profiled instead of the term's defaults")
    args = ap.parse_args()
    values = VALUES[args.term] if args.values is None else tuple(args.values)
    label = {"contact": "share", "damping": "loss factor", "delay": "cycles"}[args.term]
    extra = " crossing of the no-contact fit, mm |" if args.term == "contact" else ""
    print(f"| store |{extra} E baseline | " + " | ".join(f"E {label} {v:g}" for v in values) + " | best change | s |")
    print("|---|" + "---|" * (len(values) + 3 + bool(extra)))
    for store in args.stores:
        r = profile(store, args.term, args.steps, values)
        best = min(r["e"])
        cross = f" {r['overlap_mm']:.3g} |" if extra else ""
        print(f"| {store.parent.name} |{cross} {r['e0']:.6g} | " + " | ".join(f"{v:.6g}" for v in r["e"])
              + f" | {100 * (best / r['e0'] - 1):+.3g} % | {r['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
