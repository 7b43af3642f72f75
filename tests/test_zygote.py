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



def test_two_replies_that_arrive_together_are_both_read_at_once():
    """A child that ends before its pid is read leaves both reply lines in the pipe together. Read through a
    buffered ``readline``, the second sat in the reader's buffer while ``select`` waited on the empty pipe until
    the timeout (a command that had ended, reported as timed out). The helper's replies are read with
    ``os.read`` into the Zygote's own buffer: both lines come back, the second without waiting."""
    import types

    r, w = os.pipe()
    z = Zygote.__new__(Zygote)
    z.proc = types.SimpleNamespace(stdout=os.fdopen(r, "rb", buffering=0))
    z._pending = b""
    os.write(w, b'{"pid": 12}\n{"status": 0}\n')
    assert z._line(None) == b'{"pid": 12}'
    assert z._line(0.01) == b'{"status": 0}'
    assert z._line(0.01) is None            # nothing more: the timeout, not a hang
    os.close(w)
    z.proc.stdout.close()


def test_quick_commands_in_a_row_each_get_their_answer(zygote, tmp_path):
    for _ in range(40):
        res = zygote.run(["--version"], tmp_path, dict(os.environ), 120)
        assert res.returncode == 0 and res.stdout.startswith("vfcli")
