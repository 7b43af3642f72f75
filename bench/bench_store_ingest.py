"""## Ingest into the store: `vfcli ingest-hsc` throughput against copying the file.

In one run, on the same disk: a realistic 12-bit SA-X2 style MRAW (textured frames with
sensor noise, ~400 MB) is

* copied with ``shutil.copyfile`` and fsync'ed, after dropping the source from the page
  cache (``posix_fadvise(DONTNEED)``): the disk's plain copy speed;
* ingested with the library call behind ``vfcli ingest-hsc`` (hash the raw files, stream,
  encode one chunk per frame, atomic commit with fsync) into a new store, for each frame
  filter, with the source dropped from the cache the same way. ``nbit`` (what the default,
  ``auto``, picks for a 12-bit packed MRAW) copies each frame's packed bytes as they are;
  the gzip filters decode the 12-bit pixels and deflate them.

Then the frames of the last round's stores are read back (from the page cache) in batches
of 16 frames, as ``vfcli flow`` reads them: by h5py (libhdf5's filters) and by vfcli's
:class:`vfcli.store.frames.FrameReader` (N-bit chunks unpacked by numpy; other filters by h5py).

The machine is shared, so both are timed in ``--rounds`` interleaved rounds (copy, then
each filter) and each ingest is compared with the copy of its own round: the table shows
median times, and the median (min-max) over rounds of copy time / ingest time. The CPU
time (all threads) does not depend on the other jobs much: on N free cores an ingest
cannot take less than CPU time / N.

MB/s are MB of MRAW per second (1 MB = 10**6 bytes); the ratio is against the copy.

Reproduce::

    .venv/bin/python bench/bench_store_ingest.py [--mb 400] [--rounds 3] [--dir DIR]
        [--compressions none,nbit,gzip,gzip4]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vfcli.io.video.photron import write_mraw  # noqa: E402
from vfcli.stages.base import RunContext  # noqa: E402
from vfcli.flow.pipeline import CHUNK_FRAMES  # noqa: E402
from vfcli.stages.ingest import run_ingest_hsc  # noqa: E402
from vfcli.store import FrameReader  # noqa: E402

#: Rows' labels of the filters, by ``ingest_hsc.compression`` value.
LABELS = {"nbit": "nbit (default for 12-bit MRAW: auto)", "gzip": "gzip (deflate 1 + shuffle)"}


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


def _timed(fn, *args) -> tuple[float, float]:
    """(wall seconds, CPU seconds of every thread of this process) of ``fn(*args)``."""
    t, c = time.perf_counter(), time.process_time()
    fn(*args)
    return time.perf_counter() - t, time.process_time() - c


def _ingest(root: Path, cihx: Path, comp: str) -> tuple[float, float, int]:
    """(wall s, CPU s, stored bytes) of one ingest into a new store."""
    store = root / f"{comp}.h5"
    for p in (store, root / f".{store.name}.lock"):
        p.unlink(missing_ok=True)
    ctx = RunContext.open(store, None, [f"ingest_hsc.compression={comp!r}"])
    return (*_timed(run_ingest_hsc, ctx, cihx), store.stat().st_size)


def _copy(root: Path, mraw: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one copy of the MRAW, fsync'ed."""
    dst = root / "copy.mraw"
    dst.unlink(missing_ok=True)

    def copy() -> None:
        shutil.copyfile(mraw, dst)
        _drop_cache(dst)

    return _timed(copy)


def _read_ms_per_frame(store: Path, reader: str, repeats: int = 3) -> float:
    """Median over ``repeats`` of the time to read every frame of /hsc/frames in batches of
    :data:`CHUNK_FRAMES`, ms per frame, by h5py (``reader="h5py"``) or vfcli's FrameReader."""
    times = []
    with h5py.File(store, "r") as f:
        ds = f["hsc/frames"]
        frames = FrameReader(ds) if reader == "vfcli" else ds
        n = len(ds)
        for _ in range(repeats):
            t = time.perf_counter()
            for i in range(0, n, CHUNK_FRAMES):
                frames[i:i + CHUNK_FRAMES]
            times.append((time.perf_counter() - t) / n * 1e3)
    return statistics.median(times)


def _ratio_cell(ratios: list[float]) -> str:
    return f"{statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=400.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--compressions", default="none,nbit,gzip,gzip4",
                    help="comma-separated ingest_hsc.compression values")
    ap.add_argument("--dir", default=None)
    args = ap.parse_args()
    comps = args.compressions.split(",")
    h = w = 512
    n = int(args.mb * 1e6 / (h * w * 1.5))
    root = Path(tempfile.mkdtemp(dir=args.dir))
    try:
        mraw, cihx = write_mraw(root / "v.mraw", _frames(n, h, w), 10000.0)
        size = mraw.stat().st_size
        load0 = os.getloadavg()[0]
        names = ["copy", *comps]
        wall: dict[str, list[float]] = {k: [] for k in names}
        cpu: dict[str, list[float]] = {k: [] for k in names}
        ratios: dict[str, list[float]] = {k: [] for k in comps}
        stored = {"copy": size}
        for _ in range(args.rounds):
            _drop_cache(mraw)
            copy_s, copy_cpu = _copy(root, mraw)
            wall["copy"].append(copy_s)
            cpu["copy"].append(copy_cpu)
            for comp in comps:
                _drop_cache(mraw)
                secs, cpus, stored[comp] = _ingest(root, cihx, comp)
                wall[comp].append(secs)
                cpu[comp].append(cpus)
                ratios[comp].append(copy_s / secs)
            print("round: " + ", ".join(f"{k} {wall[k][-1]:.2f} s" for k in names), file=sys.stderr)
        print(f"MRAW: {n} frames of {h} x {w}, 12-bit packed, {size / 1e6:.0f} MB; {args.rounds} rounds; "
              f"{os.cpu_count()} cores, load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after\n")
        print("| operation | time (s) | CPU time (s) | MB/s of MRAW | vs copy (min-max) | stored size (MB) |")
        print("| --- | ---: | ---: | ---: | ---: | ---: |")
        for name in names:
            secs = statistics.median(wall[name])
            label = "copy (shutil.copyfile + fsync)" if name == "copy" else \
                f"vfcli ingest-hsc, frames {LABELS.get(name, name)}"
            vs = "1.00" if name == "copy" else _ratio_cell(ratios[name])
            print(f"| {label} | {secs:.2f} | {statistics.median(cpu[name]):.2f} | {size / 1e6 / secs:.0f} | {vs} | "
                  f"{stored[name] / 1e6:.0f} |")
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"\nMedians over rounds; CPU time is summed over all threads. Peak RSS of the ingests: {peak:.0f} MB.")
        read = [c for c in comps if c in ("nbit", "gzip")]
        if read:
            print(f"\nReading the stored frames back ({CHUNK_FRAMES} frames at a time, from the page cache, "
                  "median of 3 reads), ms per 512 x 512 frame:\n")
            print("| frames | h5py (libhdf5's filters) | vfcli FrameReader |")
            print("| --- | ---: | ---: |")
            for comp in read:
                store = root / f"{comp}.h5"
                print(f"| {LABELS.get(comp, comp)} | {_read_ms_per_frame(store, 'h5py'):.2f} | "
                      f"{_read_ms_per_frame(store, 'vfcli'):.2f} |")
        print("Reproduce: `.venv/bin/python bench/bench_store_ingest.py --mb %g --rounds %d`" % (args.mb, args.rounds))
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
