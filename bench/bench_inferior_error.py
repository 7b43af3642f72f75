"""## The inferior surface's error of stored runs against a phantom's truth (scoring only).

For a kept phantom folder (``bench/bench_diagnose.py --keep DIR`` or ``bench/bench_unseen.py --keep DIR``, holding
``recording.h5`` and the sealed ``truth/*.h5``), prints for each run the RMS error of its inferior-surface displacement
over its window relative to the RMS true displacement (``bench_diagnose.inferior_error``, as the panel scores it).
It reads the truth, so it belongs after the diagnoses, never before.

Reproduce::

    .venv/bin/python bench/bench_inferior_error.py DIR/seed2012_inertia default bslide bslide+inertia
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_diagnose import inferior_error  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="kept phantom folder (recording.h5, truth/)")
    ap.add_argument("runs", nargs="+", help="/optimize runs to score")
    args = ap.parse_args()
    truth = next(args.folder.glob("truth/*.h5"), None)
    if truth is None:
        sys.exit(f"{args.folder}: no truth/*.h5 (a kept phantom folder holds its sealed truth there)")
    for run in args.runs:
        err, turned = inferior_error(args.folder / "recording.h5", run, truth)
        turn = " (pose half a turn off: scored in the fit's frame)" if turned else ""
        print(f"{args.folder.name} {run}: inferior error {100 * err:.1f} %{turn}")


if __name__ == "__main__":
    main()
