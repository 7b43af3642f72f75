"""## Sync error of a phantom's store against its truth.h5.

Prints the RMS timing error of the vibrometer epochs `vfcli sync` aligned (the points it marks ok), split into the
offset all points share (the video pressure's phase reference) and the scatter between points, in us. The figures
of docs/benchmarks.md, "Sync: the strided phase fit averages the samples it skips (session 28)".

Reproduce::

    .venv/bin/vfcli sync STORE --force          # on a copy, to rerun sync with the current code
    .venv/bin/python bench/bench_sync_error.py STORE RAW/truth.h5
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.store import Store, read_truth  # noqa: E402
from vfcli.synth.scoring import rms, sync_offset_error  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", type=Path)
    ap.add_argument("truth", type=Path)
    args = ap.parse_args()
    t, _ = read_truth(args.truth, ["ldv/sync_offset_s", "ldv/f0_hz"])
    with Store(args.store).read() as r:
        off, ok = r.read("sync", "offset_s"), r.read("sync", "ok")
    err = 1e6 * sync_offset_error(off, t["ldv/sync_offset_s"], t["ldv/f0_hz"])[ok]
    print(f"{args.store}: RMS {rms(err):.2f} us over {ok.sum()} of {ok.size} points; shared offset "
          f"{np.mean(err):+.2f} us, scatter (sd) {np.std(err):.2f} us")


if __name__ == "__main__":
    main()
