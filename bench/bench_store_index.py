"""## The store file (index) over many writes (issue 18)

Size of the store file after each of N writes that change only the recording config, on a copy
of a store (its parts folder included): in-process (``Store.write`` + ``set_recording_config``,
what `vfcli config --set` does) and, with ``--cli K``, K real `vfcli config --set` commands.
Before each commit wrote a fresh compact index, the file grew about 3.9 kB per write
(docs/benchmarks.md).

Reproduce::

    .venv/bin/python bench/bench_store_index.py STORE [N] [--cli K]    # e.g. demo/recording.h5 50 --cli 10
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vfcli.store import Store
from vfcli.store.parts import copy_store


def in_process(path: Path, n: int) -> None:
    with Store(path).read() as r:
        config = json.loads(r.recording_config_json() or "{}")
    sizes, times = [path.stat().st_size], []
    for i in range(n):
        config.setdefault("camera", {})["px_per_mm"] = 9.0 + (i % 2) * 0.5
        t = time.perf_counter()
        with Store(path).write("bench config") as w:
            w.set_recording_config(json.dumps(config))
        times.append(time.perf_counter() - t)
        sizes.append(path.stat().st_size)
    print(f"  in-process, {n} writes: index {sizes[0] / 1e3:.1f} kB before, {sizes[1] / 1e3:.1f} kB after the first, "
          f"{sizes[-1] / 1e3:.1f} kB after the last ({(sizes[-1] - sizes[1]) / max(n - 1, 1):+.0f} B per write "
          f"after the first); median write {sorted(times)[n // 2] * 1e3:.0f} ms")


def cli(path: Path, k: int) -> None:
    sizes = [path.stat().st_size]
    for i in range(k):
        res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", "config", str(path), "--set",
                              f"camera.px_per_mm={9.0 + (i % 2) * 0.5}"], capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(res.stderr)
        sizes.append(path.stat().st_size)
    print(f"  `vfcli config --set`, {k} commands: index {sizes[0] / 1e3:.1f} kB before, {sizes[-1] / 1e3:.1f} kB after "
          f"({(sizes[-1] - sizes[1]) / max(k - 1, 1):+.0f} B per write after the first)")


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args:
        print("usage: bench_store_index.py STORE [N] [--cli K] (e.g. demo/recording.h5 50 --cli 10)", file=sys.stderr)
        sys.exit(2)
    k = int(args[args.index("--cli") + 1]) if "--cli" in args else 0
    if "--cli" in args:
        del args[args.index("--cli"):args.index("--cli") + 2]
    src, n = Path(args[0]), int(args[1]) if len(args) > 1 else 50
    with tempfile.TemporaryDirectory() as d:
        copy = copy_store(src, Path(d) / "rec.h5")
        in_process(copy, n)
        if k:
            cli(copy, k)
