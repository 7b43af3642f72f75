"""## The gap term on rays the camera sees closed: kept stores refitted under each rule (issue 15 items 5-6, issue 16).

``optimize.gap_closed_rays``: ``meet`` (before session 47) asks both simulated silhouettes to meet at the last known
opening location on every ray the camera sees closed, so the model's overlapping folds (it has no contact) are pulled
apart to touch; ``overlap-allowed`` (the default since) leaves such a ray out where the simulated folds overlap;
``overlap-bounded`` (session 50) leaves it out while the overlap is within the widest opening measured and charges the
excess quadratically. For each kept store (``bench/bench_unseen.py --keep DIR`` or ``bench/bench_diagnose.py --keep
DIR``), ``vfcli optimize`` is run under each rule (``--rules``, all three unless given) as the runs ``closedmeet``,
``closedoverlap`` and ``closedbounded``, in the same process of this script, then
each run is scored against the phantom's truth (read after the fits, to score only) as ``bench_gap_weight.py`` scores:
the inferior surface's oscillating, static (mm) and total error, its mean vertical displacement true / estimated and
the coverage of the stated 90 % intervals; and the gap term's final value.

Reproduce (prints a markdown table and the means)::

    .venv/bin/python bench/bench_unseen.py 4125 4126 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_closed_rays.py DIR/seed4125 DIR/seed4126

``--slide`` fits each rule also with ``optimize.motion_slide = true`` (the surface sliding under the pixels in the
gradient and Gauss-Newton model, session 51).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_gap_weight import refit, row, score  # noqa: E402

from vfcli.store import Store  # noqa: E402

RULES = {"meet": "closedmeet", "overlap-allowed": "closedoverlap", "overlap-bounded": "closedbounded"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", type=Path, nargs="+", help="kept store folders (holding recording.h5)")
    ap.add_argument("--rules", nargs="+", choices=list(RULES), default=list(RULES), help="the rules to fit (all three)")
    ap.add_argument("--slide", action="store_true", help="each rule with optimize.motion_slide = true too (runs named "
                    "with 'slide' appended)")
    args = ap.parse_args()
    rules = {rule: RULES[rule] for rule in args.rules}
    if args.slide:
        rules.update({f"{rule}+slide": f"{RULES[rule]}slide" for rule in args.rules})
    print("| store | rule | inferior oscillating | static (mm) | total | mean z true / est (mm) | 90 % coverage | "
          "E_gap final |")
    print("| --- | --- | ---: | ---: | ---: | --- | ---: | ---: |")
    table: dict[str, list[dict]] = {rule: [] for rule in rules}
    for work in args.stores:
        got = {}
        for rule, name in rules.items():
            sets = [f"optimize.gap_closed_rays={rule.removesuffix('+slide')}"]
            if rule.endswith("+slide"):
                sets.append("optimize.motion_slide=true")
            if not refit(work, sets, name, force=True):
                continue
            s = score(work, name)
            with Store(work / "recording.h5").read() as r:
                s["gap_final"] = float(r.read("optimize", "history_gap", name)[-1])
            got[rule] = s
            print(f"{row(f'{work.name} | {rule}', s)} {s['gap_final']:.3f} |", flush=True)
        if len(got) == len(rules):
            for rule in rules:
                table[rule].append(got[rule])
    n = len(next(iter(table.values())))
    if not n:
        return
    print(f"\nOver the {n} stores fitted under every rule:")
    for rule, rows in table.items():
        bias = np.array([100 * (s["inf_mean_z_est_mm"] / s["inf_mean_z_true_mm"] - 1) for s in rows])
        cov = np.array([s["coverage90"] for s in rows])
        print(f"- {rule}: total error mean {100 * np.mean([s['inf_total_err'] for s in rows]):.2f} %, static mean "
              f"{np.mean([s['inf_static_err_mm'] for s in rows]):.4f} mm, mean z bias {bias.mean():+.2f} % "
              f"({bias.min():+.1f} .. {bias.max():+.1f} %, low on {int((bias < 0).sum())} of {n}), coverage within "
              f"85-95 % on {int(((cov >= 0.85) & (cov <= 0.95)).sum())} of {n}")
    pairs = [("meet", "overlap-allowed"), ("overlap-allowed", "overlap-bounded")]
    pairs += [(rule, f"{rule}+slide") for rule in args.rules if args.slide]
    for a, b in pairs:
        if a in table and b in table:
            lower = sum(y["inf_total_err"] < x["inf_total_err"] for x, y in zip(table[a], table[b]))
            same = sum(y["inf_total_err"] == x["inf_total_err"] for x, y in zip(table[a], table[b]))
            print(f"- {b}'s total error lower than {a}'s on {lower} of {n}, the same on {same}")


if __name__ == "__main__":
    main()
