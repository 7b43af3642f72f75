"""The checkpoint file of an optimize run beside its store: ``<store>.optimize-<run>.ckpt.npz``.

`vfcli optimize` writes it after every iteration and removes it once the run is stored; one that
is left is a fit that was stopped (kill, SIGTERM, a job's time limit), which ``--resume`` continues.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

_SUFFIX = ".ckpt.npz"


def checkpoint_path(store_path: str | Path, run: str) -> Path:
    """The checkpoint file of run ``run`` of the store at ``store_path``."""
    p = Path(store_path)
    return p.with_name(f"{p.name}.optimize-{run}{_SUFFIX}")


def stopped_fits(store_path: str | Path) -> list[dict]:
    """The checkpoints left beside the store: ``[{"run", "iteration", "path"}]`` sorted by run; iteration
    None where the file cannot be read (a partly written copy)."""
    p = Path(store_path)
    pattern = re.compile(rf"^{re.escape(p.name)}\.optimize-([A-Za-z0-9_-]+){re.escape(_SUFFIX)}$")
    out = []
    for f in sorted(p.parent.glob(f"{p.name}.optimize-*{_SUFFIX}")):
        m = pattern.match(f.name)
        if m is None:
            continue
        try:
            with np.load(f) as z:
                iteration = int(z["iteration"])
        except (OSError, ValueError, KeyError):
            iteration = None
        out.append({"run": m.group(1), "iteration": iteration, "path": str(f)})
    return out
