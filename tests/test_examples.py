"""The scripts in examples/ run, and each gets its number (scikit-fem's habit: examples are tests).

Each example computes at module level; it is run here as a module (not as __main__, so it
prints nothing) and one figure it computes is checked against the truth it was built from.
Measured figures (this machine, numpy/scipy of the venv) are in the comments; the tolerances are
about 2x them.
"""
from __future__ import annotations

import runpy
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_example(name: str) -> dict:
    """The module globals of ``examples/<name>.py`` after running it."""
    return runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name=f"examples.{name}")


@pytest.mark.slow
def test_fit_forward_case_recovers_the_unseen_inferior_surface_within_its_stated_uncertainty():
    ns = run_example("fit_forward_case")
    # measured: error 7.1 %, stated 9.9 %, 90 % coverage 97 %
    assert ns["INFERIOR_ERROR_REL"] < 0.11
    assert ns["INFERIOR_ERROR_REL"] <= ns["INFERIOR_STD_REL"]


@pytest.mark.slow
def test_custom_load_model_recovers_the_pressure_history():
    ns = run_example("custom_load_model")
    assert ns["PRESSURE_ERROR_REL"] < 4e-4  # measured 2.0e-4 with 10 % velocity noise


def test_sync_of_synthetic_records_gives_the_velocity_on_the_frame_times():
    ns = run_example("sync_synthetic_records")
    assert ns["N_OK"] == 12
    assert ns["VELOCITY_ERROR_REL"] < 0.005  # measured 0.22 %
