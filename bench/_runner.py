"""Shared helpers of the benchmarks: run the real CLI, time a callable."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]


def vfcli(*args) -> float:
    """Run ``vfcli ARGS -q`` in a subprocess (as a user does); wall time in s. Exits on failure."""
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args), "-q"], capture_output=True,
                         text=True, cwd=ROOT)
    if res.returncode:
        raise SystemExit(f"vfcli {args[0]} failed: {res.stderr}")
    return time.perf_counter() - t


def best(fn: Callable[[], object], repeat: int) -> float:
    """Smallest wall time of ``repeat`` calls of ``fn``, s."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)
