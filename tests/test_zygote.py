"""The tests' way of starting `vfcli` (tests/_zygote.py: a child forked from a helper that imported
vfcli once) gives what a fresh ``python -m vfcli.cli.main`` gives: the same exit code, standard
output and standard error, in the caller's working directory and environment; a command past its
timeout is killed and the helper serves the next one."""
from __future__ import annotations

import os
import subprocess

import h5py
import numpy as np
import pytest

from conftest import ROOT, VFCLI
from _zygote import Zygote


@pytest.fixture(scope="module")
def zygote():
    z = Zygote(ROOT)
    yield z
    z.close()


def _fresh(args, cwd, env):
    return subprocess.run([*VFCLI, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def _cases(tmp_path):
    (tmp_path / "junk.h5").write_bytes(b"not an HDF5 file at all")
    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["x"] = np.arange(3)
    return [
        ["--version"],
        ["--help"],
        ["info", "junk.h5"],                 # relative: resolved in the caller's folder
        ["info", "foreign.h5"],
        ["info", "missing.h5"],
        ["optimize", "missing.h5", "--set", "optimize.no_such_key=1"],
        ["sync", "--no-such-option"],
        ["config", "junk.h5"],
    ]


def test_each_command_ends_as_in_a_fresh_interpreter(zygote, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "97"}
    codes = set()
    for args in _cases(tmp_path):
        want = _fresh(args, tmp_path, env)
        got = zygote.run(args, tmp_path, env, 120)
        assert (got.returncode, got.stdout, got.stderr) == (want.returncode, want.stdout, want.stderr), args
        codes.add(want.returncode)
    assert len(codes) >= 3, codes   # success, usage errors and bad input among them


def test_a_command_past_its_timeout_is_killed_and_the_next_one_runs(zygote, tmp_path):
    with pytest.raises(subprocess.TimeoutExpired):
        zygote.run(["synth", str(tmp_path / "raw"), "--seed", "3"], tmp_path, dict(os.environ), 0.5)
    res = zygote.run(["--version"], tmp_path, dict(os.environ), 60)
    assert res.returncode == 0 and "vfcli" in res.stdout and zygote.alive()


def test_a_child_is_its_own_process_with_the_callers_environment(zygote, tmp_path):
    """A value set in the caller's environment reaches the command (here the terminal width click
    wraps the help's description at)."""
    narrow = zygote.run(["--help"], tmp_path, {**os.environ, "COLUMNS": "50"}, 60)
    wide = zygote.run(["--help"], tmp_path, {**os.environ, "COLUMNS": "200"}, 60)
    assert narrow.returncode == wide.returncode == 0
    first = lambda text: next(line for line in text.splitlines() if "vfcli: 3D" in line)  # noqa: E731
    assert len(first(narrow.stdout)) <= 50 < len(first(wide.stdout))
