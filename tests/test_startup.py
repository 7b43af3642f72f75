"""A command's start-up (issue 18): `vfcli <command> --help` imports no heavy library, and a
stage call with nothing to do imports no science it would not use. Measured by what Python
imports (`python -X importtime` in a real subprocess), not by timing."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from conftest import ROOT, VFCLI, run_vfcli
from vfcli.cli import choices
from vfcli.cli.main import COMMANDS

HEAVY = {"numpy", "scipy", "h5py", "cv2", "matplotlib", "pydantic", "tqdm", "skfem", "tetgen", "cholespy", "pyuff",
         "nptdms", "tifffile", "tomli_w"}


def _imported(*args) -> tuple[subprocess.CompletedProcess, set[str]]:
    """The top-level packages a `vfcli ARGS` run imports."""
    res = subprocess.run([sys.executable, "-X", "importtime", *VFCLI[1:], *map(str, args)], capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    names = {line.split("|")[-1].strip().split(".")[0] for line in res.stderr.splitlines()
             if line.startswith("import time:") and "self [us]" not in line}
    assert "click" in names  # the import log was read
    return res, names


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_commands_help_imports_no_heavy_library(command):
    res, names = _imported(command, "--help")
    assert res.returncode == 0 and "Usage: vfcli " + command in res.stdout, res.stderr
    assert not names & HEAVY, f"`vfcli {command} --help` imports {sorted(names & HEAVY)}"


def test_the_mesh_help_imports_no_numpy():
    _, names = _imported("mesh", "--help")
    assert "numpy" not in names and "vfcli" in names


def test_an_up_to_date_mesh_call_imports_no_meshing_library(tmp_path):
    store = tmp_path / "rec.h5"
    assert run_vfcli("mesh", store, "--set", "mesh.target_edge_mm=3").returncode == 0
    res, names = _imported("mesh", store, "--set", "mesh.target_edge_mm=3")
    assert res.returncode == 0 and "/mesh: up to date" in res.stdout, res.stdout + res.stderr
    assert not names & {"scipy", "skfem", "tetgen", "matplotlib", "cv2"}, sorted(names & HEAVY)
    res, names = _imported("mesh", store, "--set", "mesh.target_edge_mm=3.5")  # a real rewrite does import them
    assert res.returncode == 0 and "/mesh: written" in res.stdout and "scipy" in names


def test_the_spelled_out_choices_equal_their_sources():
    from vfcli.config import OptimizeConfig, SynthConfig, literal_choices
    from vfcli.stages.export_job import WHAT
    from vfcli.stages.run import STEPS
    from vfcli.store.frames import COMPRESSIONS

    assert choices.SYNTH_EFFECTS == literal_choices(SynthConfig, "effect")
    assert choices.OPTIMIZE_SETUPS == literal_choices(OptimizeConfig, "setup")
    assert choices.OPTIMIZE_LOADS == literal_choices(OptimizeConfig, "loads")
    assert choices.OPTIMIZE_METHODS == literal_choices(OptimizeConfig, "method")
    assert choices.FRAME_COMPRESSIONS == tuple(COMPRESSIONS)
    assert choices.EXPORT_WHAT == tuple(WHAT)
    assert choices.RUN_STEPS == tuple(STEPS)
