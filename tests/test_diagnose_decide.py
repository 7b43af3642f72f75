"""The decision (vfcli.diagnose.decide): a finding needs a calibrated family-wise lead AND a confirmation
whose held-out error improves beyond its spread; otherwise "no missing physics detected"."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from vfcli.diagnose.decide import decide


@dataclass(frozen=True)
class _Confirmation:
    candidate: str
    improves: bool


NAMES = ("inertia", "damping", "asymmetry", "offset")


def test_no_lead_says_no_missing_physics():
    d = decide(NAMES, np.array([0.3, 0.9, 0.06, 1.0]), [True] * 4, 199)
    assert d.leads == () and d.findings == () and d.verdict == "no missing physics detected"
    assert d.lines[-1] == "no missing physics detected"


def test_a_lead_without_confirmation_is_not_a_finding():
    d = decide(NAMES, np.array([0.005, 0.04, 0.2, 1.0]), [True, True, True, False], 199)
    assert d.leads == ("inertia", "damping") and d.findings == ()
    assert d.lines[-1].startswith("no missing physics detected (unconfirmed leads: inertia, damping")
    assert any("p <= 0.005" in line for line in d.lines)


def test_a_confirmed_lead_is_a_finding_and_a_failed_confirmation_is_not():
    conf = {"inertia": _Confirmation("inertia", True), "damping": _Confirmation("damping", False)}
    d = decide(NAMES, np.array([0.005, 0.01, 0.2, 1.0]), [True] * 4, 199, confirmations=conf)
    assert d.findings == ("inertia",) and d.verdict == "missing physics: inertia"
    # an unidentifiable candidate is never a lead, whatever its p-value
    d = decide(NAMES, np.array([0.005, 0.01, 0.2, 1.0]), [False, True, True, True], 199, confirmations=conf)
    assert d.leads == ("damping",) and d.findings == ()


def test_alpha_out_of_range_is_a_bug():
    with pytest.raises(ValueError):
        decide(NAMES, np.zeros(4), [True] * 4, 199, alpha=1.5)
