"""## Ingest: read + decode throughput of a 12-bit packed MRAW, against copying the file.

Writes a ~500 MB SA-X2 style MRAW + CIHX (12-bit packed) with vfcli's streaming
writer, then in the same run and on the same disk measures:

* ``shutil.copyfile`` of the MRAW (the disk's plain copy speed);
* vfcli's streaming reader (``open_video(...).iter_frames()``: seek, read and
  vectorised numpy 12-bit decode, batch by batch, bounded memory);
* pyMRAW's ``load_video`` (numba decoder, decodes the whole file into memory)
  for reference;

and then writes and reads a full PSV-style UFF scan (374 points x 2 channels x
10,000 samples) with vfcli's writer, pyuff's reader and vfcli's reader.

Throughput is MB of MRAW file per second (1 MB = 10**6 bytes). The file is
read once before timing, so every row sees the same (warm) page cache.

Reproduce::

    .venv/bin/python bench/bench_ingest.py [--mb 500] [--dir DIR] [--batch N]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _runner import best  # noqa: E402
from vfcli.io.video.photron import write_mraw  # noqa: E402
from vfcli.io.video.base import open_video  # noqa: E402


def _frames(n: int, h: int, w: int, block: int = 32):
    rng = np.random.default_rng(0)
    base = rng.integers(0, 4096, (h, w), dtype=np.uint16)
    for k0 in range(0, n, block):
        ks = np.arange(k0, min(n, k0 + block), dtype=np.uint16)[:, None, None]
        yield (base[None] + ks * 13) % 4096


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=500.0, help="MRAW size, MB")
    ap.add_argument("--dir", type=Path, default=None, help="folder on the disk to test")
    ap.add_argument("--batch", type=int, default=None, help="frames per batch (default ~32 MB)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    h = w = 256
    frame_bytes = h * w * 3 // 2
    n = int(args.mb * 1e6 // frame_bytes)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        mraw, _ = write_mraw(tmp / "bench", _frames(n, h, w), fps=20000.0)
        t_write = time.perf_counter() - t
        size = mraw.stat().st_size
        mb = size / 1e6
        with open(mraw, "rb") as fh:                       # warm the page cache
            while fh.read(1 << 24):
                pass

        def copy():
            shutil.copyfile(mraw, tmp / "copy.mraw")
            os.remove(tmp / "copy.mraw")

        def stream():
            with open_video(mraw) as v:
                for batch in v.iter_frames(batch=args.batch):
                    batch[0, 0, 0]

        def pymraw():
            import warnings


            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                images, _ = pyMRAW.load_video(str(mraw.with_suffix(".cihx")))
            images[-1, -1, -1]
            del images

        import pyMRAW  # noqa: F401  (numba: ~150 MB RSS; imported by open_video too)

        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t_copy = best(copy, args.repeat)
        t_stream = best(stream, args.repeat)
        rss_stream = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        pymraw()  # numba JIT / cache warm-up
        t_pymraw = best(pymraw, args.repeat)
        rss_pymraw = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    print(f"\n{n} frames of {w} x {h}, 12-bit packed: {mb:.0f} MB MRAW; best of {args.repeat}; "
          f"{os.cpu_count()} CPUs\n")
    print("| operation | time (s) | MB/s of MRAW | peak RSS (MB) |")
    print("|---|---:|---:|---:|")
    print(f"| write (vfcli `write_mraw`, streaming pack) | {t_write:.2f} | {mb / t_write:.0f} | |")
    print(f"| copy (`shutil.copyfile`, same disk) | {t_copy:.2f} | {mb / t_copy:.0f} | |")
    print(f"| read + decode (vfcli `iter_frames`, streaming) | {t_stream:.2f} | "
          f"{mb / t_stream:.0f} | {rss_stream / 1024:.0f} |")
    print(f"| read + decode (pyMRAW `load_video`, whole file) | {t_pymraw:.2f} | "
          f"{mb / t_pymraw:.0f} | {rss_pymraw / 1024:.0f} |")
    print(f"\n(peak RSS before timing, after importing pyMRAW/numba: {rss0 / 1024:.0f} MB; RSS "
          "is the process high-water mark, so each row includes the rows above it.)")
    _bench_ldv()
    print("\nReproduce: `.venv/bin/python bench/bench_ingest.py --mb 500`")


def _bench_ldv(rows: int = 17, cols: int = 22, n_s: int = 10_000) -> None:
    """Write and read a full PSV-style UFF scan (374 points x 2 channels x 10,000 samples)."""
    import pyuff

    from vfcli.io.ldv.read import LdvScan, read_ldv
    from vfcli.io.ldv.write import write_ldv_uff

    rng = np.random.default_rng(0)
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    p = rows * cols
    coords = np.column_stack([cc.ravel() * 0.5, rr.ravel() * 0.4, np.zeros(p)])
    t = np.arange(n_s) / 50_000.0
    vel = rng.uniform(10, 100, (p, 1)) * np.sin(2 * np.pi * 150 * t) + rng.normal(0, 1, (p, n_s))
    ref = 800 + 200 * np.sin(2 * np.pi * 150 * t) + rng.normal(0, 1, (p, n_s))
    scan = LdvScan(np.arange(1, p + 1), coords, vel, 50_000.0, ref, "Pa")
    print(f"\nLDV scan, UFF (PSV layout): {p} points x 2 channels x {n_s} samples\n")
    print("| operation | time (s) | file (MB) |")
    print("|---|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for binary in (True, False):
            path = Path(tmp) / f"scan_{binary}.uff"
            t0 = time.perf_counter()
            write_ldv_uff(path, scan, binary=binary)
            t_w = time.perf_counter() - t0
            t0 = time.perf_counter()
            pyuff.UFF(str(path)).read_sets()
            t_p = time.perf_counter() - t0
            t0 = time.perf_counter()
            read_ldv(path)
            t_r = time.perf_counter() - t0
            kind = "binary 58" if binary else "ASCII 58"
            size = path.stat().st_size / 1e6
            print(f"| write, vfcli `write_ldv_uff` ({kind}) | {t_w:.2f} | {size:.0f} |")
            print(f"| read, pyuff `read_sets` ({kind}) | {t_p:.2f} | |")
            print(f"| read, vfcli `read_ldv` incl. grid + dropouts ({kind}) | {t_r:.2f} | |")


if __name__ == "__main__":
    main()
