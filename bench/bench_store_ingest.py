"""## Ingest into the store: `vfcli ingest-hsc` throughput against copying the file.

In one run, on the same disk: a realistic 12-bit SA-X2 style MRAW (textured frames with
sensor noise, ~400 MB) is

* copied with ``shutil.copyfile`` and fsync'ed, after dropping the source from the page
  cache (``posix_fadvise(DONTNEED)``): the disk's plain copy speed;
* ingested with the library call behind ``vfcli ingest-hsc`` (stream, decode 12-bit,
  write one chunk per frame, atomic commit with fsync) for each frame filter, with the
  source dropped from the cache the same way.

MB/s are MB of MRAW per second (1 MB = 10**6 bytes); the ratio is against the copy.

Reproduce::

    .venv/bin/python bench/bench_store_ingest.py [--mb 400] [--dir DIR]
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vfcli.io.photron import write_mraw  # noqa: E402
from vfcli.stages.base import RunContext  # noqa: E402
from vfcli.stages.ingest import run_ingest_hsc  # noqa: E402


def _drop_cache(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def _frames(n: int, h: int, w: int):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:h, 0:w]
    texture = 1800 + 600 * np.sin(xx / 7.0) * np.cos(yy / 5.0) + rng.normal(0, 200, (h, w))
    for k in range(n):
        shift = np.roll(texture, k % w, axis=1)
        yield np.clip(shift + rng.normal(0, 25, (h, w)), 0, 4095).astype(np.uint16)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=400.0)
    ap.add_argument("--dir", default=None)
    args = ap.parse_args()
    h = w = 512
    n = int(args.mb * 1e6 / (h * w * 1.5))
    root = Path(tempfile.mkdtemp(dir=args.dir))
    try:
        mraw, cihx = write_mraw(root / "v.mraw", _frames(n, h, w), 10000.0)
        size = mraw.stat().st_size
        _drop_cache(mraw)
        t = time.perf_counter()
        shutil.copyfile(mraw, root / "copy.mraw")
        _drop_cache(root / "copy.mraw")
        copy_s = time.perf_counter() - t
        rows = [("copy (shutil.copyfile + fsync)", copy_s, size)]
        for comp in ("none", "gzip", "gzip4"):
            _drop_cache(mraw)
            store = root / f"{comp}.h5"
            ctx = RunContext.open(store, None, [f"ingest_hsc.compression={comp!r}"])
            t = time.perf_counter()
            run_ingest_hsc(ctx, cihx)
            rows.append((f"vfcli ingest-hsc, frames {comp}", time.perf_counter() - t, store.stat().st_size))
        print(f"MRAW: {n} frames of {h} x {w}, 12-bit packed, {size / 1e6:.0f} MB\n")
        print("| operation | time (s) | MB/s of MRAW | vs copy | stored size (MB) |")
        print("| --- | ---: | ---: | ---: | ---: |")
        for name, secs, out_size in rows:
            print(f"| {name} | {secs:.2f} | {size / 1e6 / secs:.0f} | {copy_s / secs:.2f} | {out_size / 1e6:.0f} |")
        print("\nReproduce: `.venv/bin/python bench/bench_store_ingest.py --mb %g`" % args.mb)
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
