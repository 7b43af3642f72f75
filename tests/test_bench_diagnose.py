"""The scoring of the blind diagnose panel (bench/bench_diagnose.py) on hand-made results: the
confusion matrix's arithmetic, the false-alarm rate and its exact interval, the targets' counts,
the strength draw and the parameter in the candidates' units."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest
from scipy.stats import binom

from conftest import ROOT
from vfcli.synth.effects import STRENGTH_RANGE

_spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "bench_diagnose.py")
bd = importlib.util.module_from_spec(_spec)
sys.modules["bench_diagnose"] = bd  # its dataclasses look their module up
_spec.loader.exec_module(bd)

EFFECTS = ["none", "inertia", "damping", "contact", "asymmetry"]


def _r(effect, named, **kw):
    return {"effect": effect, "named": named, "correct": named == effect, "strength": 0.1, "seed": 0,
            "steps": {}, **kw}


def test_confusion_matrix_counts_every_recording_once_in_its_cell():
    results = ([_r("none", "none")] * 5 + [_r("none", "damping")] + [_r("inertia", "inertia")] * 2
               + [_r("inertia", "damping+inertia")] + [_r("asymmetry", "offset")] + [_r("contact", "failed")])
    rows, cols, m = bd.confusion(results, EFFECTS)
    assert rows == EFFECTS and bd.confusion([_r("none", "x", leads="inertia")], EFFECTS, "leads")[2][0, 1] == 1
    assert cols == EFFECTS + ["damping+inertia", "failed", "offset"]  # other labels after the effects, sorted
    assert m.sum() == len(results) and m.shape == (5, 8)
    assert m[0, 0] == 5 and m[0, 2] == 1
    assert m[1, 1] == 2 and m[1, cols.index("damping+inertia")] == 1
    assert m[4, cols.index("offset")] == 1 and m[3, cols.index("failed")] == 1
    assert m[2].sum() == 0  # no damping recording
    # the row sums are the recordings per hidden effect, the diagonal the correct ones
    assert list(m.sum(axis=1)) == [6, 3, 0, 1, 1] and np.trace(m[:, :5]) == sum(r["correct"] for r in results)


def test_named_label_reads_the_findings_and_says_when_there_is_no_decision():
    assert bd.named_label(bd.findings({"findings": []})) == "none"
    assert bd.named_label(bd.findings({"findings": [{"name": "collision"}]})) == "contact"
    assert bd.named_label(bd.findings({"decision": {"findings": ["damping", "inertia"]}})) == "damping+inertia"
    assert bd.named_label(bd.findings({"screening": "4 candidates screened"})) == "no decision"
    calibrated = {"alpha": 0.05, "candidates": {"alpha_family": 0.01, "leads": ["inertia"], "findings": ["inertia"]}}
    assert bd.named_label(bd.findings(calibrated)) == "inertia" and bd.family_alpha(calibrated) == 0.01
    assert bd.family_alpha({"alpha": 0.05}) == 0.05 and bd.family_alpha(None) is None
    assert bd.leads_label(calibrated) == "inertia" and bd.leads_label({"alpha": 0.05}) == "no decision"
    tests = {"candidates": {"leads": [], "tests": [{"name": "inertia", "p_family": 0.5},
                                                   {"name": "collision", "p_family": 0.02}]}}
    assert bd.leads_label(tests) == "none" and bd.family_p(tests, "contact") == 0.02
    assert bd.family_p(tests, "damping") is None
    assert bd.findings(None) is None


def test_false_alarm_rate_and_its_clopper_pearson_interval():
    results = [_r("none", "none", alpha=0.05)] * 8 + [_r("none", "inertia", alpha=0.05)] * 2 + [
        _r("none", "failed"), _r("damping", "none", alpha=0.05)]
    fa = bd.false_alarms(results)
    assert (fa["alarms"], fa["nulls"]) == (2, 10) and fa["rate"] == pytest.approx(0.2) and fa["alpha"] == [0.05]
    lo, hi = fa["ci95"]
    # the exact interval's defining property: each end leaves 2.5 % in its tail
    assert binom.sf(1, 10, lo) == pytest.approx(0.025, rel=1e-6)
    assert binom.cdf(2, 10, hi) == pytest.approx(0.025, rel=1e-6)
    leads = bd.false_alarms([_r("none", "none", leads="inertia", alpha=0.05), _r("none", "none", leads="none")], "leads")
    assert (leads["alarms"], leads["nulls"]) == (1, 2)
    assert bd.clopper_pearson(0, 6)[0] == 0.0 and bd.clopper_pearson(0, 6)[1] == pytest.approx(1 - 0.025 ** (1 / 6))


def test_targets_count_only_the_recordings_that_state_the_figure():
    results = [
        _r("inertia", "inertia", param_within=True, param_inside=False, heldout_drop=0.5,
           inferior_before=0.3, inferior_after=0.2),
        _r("damping", "damping", param_within=False, param_inside=True, heldout_drop=0.29,
           inferior_before=0.3, inferior_after=0.31),
        _r("asymmetry", "none"),
        _r("none", "none"), _r("none", "asymmetry"),
    ]
    t = bd.targets(results)
    assert t["hidden effect named"] == (2, 3) and t["'none' on nulls"] == (1, 2)
    assert t["parameter within 25 %"] == (1, 2) and t["truth inside the stated interval"] == (1, 2)
    assert t["held-out error down >= 30 %"] == (1, 2)
    assert t["inferior surface closer to truth after the refit"] == (1, 2)


def test_strengths_fall_in_their_strata_and_depend_on_the_seed_only():
    cases = bd.panel_cases([2001], EFFECTS, 3, 6)
    assert len(cases) == 21 and [c.seed for c in cases] == list(range(2001, 2022))
    assert [c.effect for c in cases[:5]] == EFFECTS and all(c.effect == "none" for c in cases[15:])
    for c in cases:
        lo, hi = STRENGTH_RANGE[c.effect]
        if c.effect == "none":
            assert c.strength == 0.0
            continue
        width = (hi - lo) / c.strata
        assert lo + c.stratum * width - 1e-4 <= c.strength <= lo + (c.stratum + 1) * width + 1e-4
    assert bd.panel_cases([2001], EFFECTS, 3, 6) == cases
    again = bd.panel_cases([3001], ["damping"], 3, 0)
    assert [c.stratum for c in again] == [0, 1, 2] and len({c.strength for c in again}) == 3
    with pytest.raises(ValueError, match="need 4 seeds"):
        bd.panel_cases([1, 2], ["none", "inertia"], 2, 0)
    assert bd.parse_seeds(["3001-3003", "3007"]) == [3001, 3002, 3003, 3007]


def test_the_true_parameter_in_the_candidates_units():
    attrs = {"f0_hz": 125.0, "widened_density_kg_m3": 1070.0 * 1.02, "widened_youngs_modulus_pa": 4400.0 * 0.85}
    # damping: loss factor w0 beta at f0 -> tau = beta, ms
    assert bd.true_parameter("damping", 0.2, attrs) == pytest.approx(1e3 * 0.2 / (2 * np.pi * 125.0))
    # inertia: rho / E at the nominal E
    assert bd.true_parameter("inertia", 1.5, attrs) == pytest.approx(1.5 * 1.02 / 0.85)
    assert bd.true_parameter("asymmetry", 0.3, attrs) == 0.3
    # a pose half a turn off: the model's left fold is the phantom's right, E_right = 0.7 E_left, so the
    # model's own left softening is 1 - 1 / 0.7
    assert bd.true_parameter("asymmetry", 0.3, attrs, turned=True) == pytest.approx(1 - 1 / 0.7)
    assert bd.true_parameter("damping", 0.2, attrs, turned=True) == bd.true_parameter("damping", 0.2, attrs)
    assert bd.true_parameter("contact", 0.6, attrs) == 1.0 and bd.true_parameter("none", 0.0, attrs) is None


def test_refit_figures_read_the_confirmation_as_the_diagnosis_states_it():
    refit = {"candidate": "asymmetry", "run": "default+asymmetry", "uncertainty": "sandwich", "improves": True,
             "parameters": {"left_softening": {"estimate": 0.2, "sd": 0.02, "interval": [0.16, 0.24]}},
             "heldout": [{"kind": "cycles", "units": "mm/s", "baseline": [3.0, 4.0], "extended": [1.0, 2.0],
                          "reduction": 0.37, "spread": 0.1, "beyond_spread": True}]}
    f = bd.refit_figures(refit)
    assert (f["candidate"], f["run"], f["parameter"], f["estimate"], f["lo"], f["hi"]) == (
        "asymmetry", "default+asymmetry", "left_softening", 0.2, 0.16, 0.24)
    h = f["heldout_cycles"]
    assert h["before"] == pytest.approx(np.sqrt(12.5)) and h["after"] == pytest.approx(np.sqrt(2.5))
    assert h["drop"] == 0.37 and "heldout_instruments" not in f  # the diagnosis's own reduction is reported
    assert bd.refit_figures(None) == {} and bd.refit_figures({"candidate": "damping", "run": ""})["run"] is None


def test_the_markdown_section_holds_both_confusion_matrices_and_the_targets():
    steps = {"synth": {"rc": 0, "seconds": 10.0, "note": ""}, "run": {"rc": 0, "seconds": 20.0, "note": ""},
             "optimize": {"rc": 0, "seconds": 15.0, "note": "ran"}, "diagnose": {"rc": 0, "seconds": 5.0, "note": ""}}
    results = [_r("none", "none", leads="none", alpha=0.05, steps=steps),
               _r("inertia", "inertia", leads="inertia", p_family=0.01, refit_candidate="inertia", estimate=1.1,
                  lo=0.9, hi=1.3, true_parameter=1.0, param_within=True, param_inside=True,
                  heldout_cycles={"before": 2.0, "after": 1.0, "drop": 0.5, "units": "mm/s"},
                  heldout_drop=0.5, inferior_before=0.3, inferior_after=0.2, steps=steps)]
    meta = {"command": "x", "commit": "abc", "n": 2, "of": 21, "duration": 0.04, "jobs": 2, "load": "20",
            "wall_min": 3.0}
    md = bd.markdown(results, EFFECTS, meta)
    assert "2 of 21 recordings finished" in md
    assert md.count("| hidden \\ ") == 2 and "| inertia | 0 | 1 | 0 | 0 | 0 |" in md
    assert "| hidden effect named | 1 of 1 |" in md and "1.1 [0.9, 1.3] / 1" in md
    assert "2 -> 1 mm/s (50%)" in md and "30% -> 20%" in md
    # wall time: median (largest) per stage; the whole recording = synth + run + diagnose
    assert "| 10 (10) | - (-) |" in md and "| 35 (35) |" in md
