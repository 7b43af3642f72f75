"""## Store writes that cost what they change (issue 18)

The time of a small stage write, `vfcli mesh --force` and `vfcli config --set`, as a user runs
them (real CLI in a subprocess, best of REPEAT), on stores of about 0.5 GB and 5 GB, against the
commit vfcli had before (every write copied the whole store file, then renamed the copy over
it): that commit's extra cost is measured in the same run by copying the store's bytes to a
temporary file, fsyncing it and renaming it, as it did. The old commit of a small write
therefore cost about (new time) + (copy time).

The stores are built cheaply: /hsc of 512 x 512 12-bit frames (a smooth image plus sensor noise
of 40 counts, N-bit: 393 kB per frame, as a real 12-bit MRAW stores them), in batches of the
same 64 frames, plus a recording config; they are deleted afterwards. The page cache is not
dropped (no root needed): the copy is timed as the machine performs it with the store
recently written, the favourable case for the old commit.

Reproduce::

    .venv/bin/python bench/bench_store_write.py [--sizes-gb 0.5,5] [--repeat 3] [--dir /tmp]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _runner import vfcli  # noqa: E402

from vfcli.store import Store  # noqa: E402
from vfcli.store.parts import own_parts  # noqa: E402

FRAME = (512, 512)
BYTES_PER_FRAME = FRAME[0] * FRAME[1] * 3 // 2  # N-bit 12-bit


def build_store(path: Path, size_gb: float) -> int:
    """A store with /hsc of about ``size_gb`` GB and a recording config; returns the frame count."""
    n = int(size_gb * 1e9 / BYTES_PER_FRAME)
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:FRAME[0], 0:FRAME[1]]
    base = 2000 + 1000 * np.sin(x / 40) * np.cos(y / 50)
    block = np.clip(base[None] + rng.normal(0, 40, (64, *FRAME)), 0, 4095).astype(np.uint16)
    batches = (block[: min(64, n - a)] for a in range(0, n, 64))
    with Store(path).write("bench") as w:
        w.set_recording_config("{}")
        with w.stage("hsc", config_json="{}") as s:
            s.write_frames("frames", (n, *FRAME), np.uint16, batches, compression="nbit")
            s.put("frame_time", np.arange(n) / 10000.0)
            s.set_attrs(fps_hz=10000.0, px_per_mm=20.0)
    return n


def store_bytes(path: Path) -> int:
    return path.stat().st_size + sum(p.stat().st_size for p in own_parts(path))


def old_commit_copy(path: Path) -> float:
    """The old commit's extra work: copy the store's bytes (one file then) to a temporary file,
    fsync it, rename it over a file; wall time in s."""
    files = [path, *own_parts(path)]
    tmp = path.with_name(f".{path.name}.bench-old-commit")
    t = time.perf_counter()
    with open(tmp, "wb") as out:
        for f in files:
            with open(f, "rb") as src:
                shutil.copyfileobj(src, out, 16 << 20)
        out.flush()
        os.fsync(out.fileno())
    os.replace(tmp, path.with_name(f".{path.name}.bench-old-renamed"))
    elapsed = time.perf_counter() - t
    path.with_name(f".{path.name}.bench-old-renamed").unlink()
    return elapsed


def measure(size_gb: float, repeat: int, where: Path) -> dict[str, float]:
    d = Path(tempfile.mkdtemp(prefix="vfcli-bench-write-", dir=where))
    try:
        path = d / "rec.h5"
        t = time.perf_counter()
        n = build_store(path, size_gb)
        built = time.perf_counter() - t
        vfcli("mesh", path)  # the first mesh (not timed)
        mesh = min(vfcli("mesh", path, "--force") for _ in range(repeat))
        config = min(vfcli("config", path, "--set", f"camera.px_per_mm={20 + k}") for k in range(repeat))
        copy = min(old_commit_copy(path) for _ in range(repeat))
        return {"gb": store_bytes(path) / 1e9, "frames": n, "index_kb": path.stat().st_size / 1e3,
                "build_s": built, "mesh_s": mesh, "config_s": config, "copy_s": copy}
    finally:
        shutil.rmtree(d, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes-gb", default="0.5,5")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", default=tempfile.gettempdir(), help="where to build the stores (deleted afterwards)")
    args = ap.parse_args()
    rows = [measure(float(s), args.repeat, Path(args.dir)) for s in args.sizes_gb.split(",")]
    print("| store | frames | store file | `mesh --force` now | `config --set` now | whole-store copy + fsync + rename "
          "(the old commit's extra) | `mesh --force` old (now + copy) | `config --set` old |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['gb']:.2f} GB | {r['frames']} | {r['index_kb']:.0f} kB | {r['mesh_s']:.2f} s | {r['config_s']:.2f} s "
              f"| {r['copy_s']:.2f} s | {r['mesh_s'] + r['copy_s']:.2f} s | {r['config_s'] + r['copy_s']:.2f} s |")
    for r in rows:
        print(f"(built the {r['gb']:.2f} GB store in {r['build_s']:.1f} s)")


if __name__ == "__main__":
    main()
