"""The checkpoint file of an optimize run beside its store: ``<store>.optimize-<run>.ckpt.npz``.

`vfcli optimize` writes it after every iteration and removes it once the run is stored; one that
is left is a fit that was stopped (kill, SIGTERM, a job's time limit), which ``--resume`` continues.
"""
from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np

from vfcli.overrides import override_item, settings_changes

_SUFFIX = ".ckpt.npz"


def checkpoint_path(store_path: str | Path, run: str) -> Path:
    """The checkpoint file of run ``run`` of the store at ``store_path``."""
    p = Path(store_path)
    return p.with_name(f"{p.name}.optimize-{run}{_SUFFIX}")


def resume_flags(saved_settings_json: str, current_settings_json: str | None) -> list[str]:
    """The ``--set`` options (shell-quoted) that make the settings ``current_settings_json`` (the run's settings
    under the recording config, as ``optimize_settings_json`` gives them) the checkpoint's ``saved_settings_json``:
    what `vfcli optimize --resume` needs to continue the fit (its --method/--setup/--loads are optimize.* too)."""
    current = json.loads(current_settings_json) if current_settings_json else {}
    return [f"--set {shlex.quote(override_item(key, saved))}"
            for key, saved, _ in settings_changes(json.loads(saved_settings_json), current)]


def stopped_fits(store_path: str | Path) -> list[dict]:
    """The checkpoints left beside the store: ``[{"run", "iteration", "settings", "path"}]`` sorted by run
    (settings: the optimize settings JSON the fit was started with); iteration and settings None where the
    file cannot be read (a partly written copy)."""
    p = Path(store_path)
    pattern = re.compile(rf"^{re.escape(p.name)}\.optimize-([A-Za-z0-9_-]+){re.escape(_SUFFIX)}$")
    out = []
    for f in sorted(p.parent.glob(f"{p.name}.optimize-*{_SUFFIX}")):
        m = pattern.match(f.name)
        if m is None:
            continue
        try:
            with np.load(f, allow_pickle=False) as z:
                iteration, settings = int(z["iteration"]), str(z["settings_json"])
        except (OSError, ValueError, KeyError):
            iteration = settings = None
        out.append({"run": m.group(1), "iteration": iteration, "settings": settings, "path": str(f)})
    return out
