"""Candidate physics terms the baseline left out (issue 16, Explain), one small class per term.

Each class follows :class:`vfcli.diagnose.candidate.Candidate` (name, parameters, signature,
Jacobian of the predicted measurement at the baseline fit):

- :class:`~vfcli.diagnose.candidates.inertia.Inertia`: density factor;
- :class:`~vfcli.diagnose.candidates.damping.KelvinVoigtDamping`: retardation time;
- :class:`~vfcli.diagnose.candidates.asymmetry.StiffnessAsymmetry`: left/right stiffness ratio;
- :class:`~vfcli.diagnose.candidates.asymmetry.MountingOffset`: lateral offset per fold;
- :class:`~vfcli.diagnose.candidates.contact.Contact`: collision at the midplane (share of the
  rigid-contact correction);
- :class:`~vfcli.diagnose.candidates.delay.LoadDelay`: the load's delay behind the recorded pressure
  (not screened: its column is damping's; the alternative explanation of a lag, docs/diagnose.md).

:mod:`~vfcli.diagnose.candidates.identifiability` says whether the load model can absorb a term,
:mod:`~vfcli.diagnose.candidates.screening` tests each term with a score test (no refit).
"""
from vfcli.diagnose.candidates.asymmetry import MountingOffset, StiffnessAsymmetry
from vfcli.diagnose.candidates.contact import Contact
from vfcli.diagnose.candidates.damping import KelvinVoigtDamping
from vfcli.diagnose.candidates.delay import LoadDelay
from vfcli.diagnose.candidates.inertia import Inertia

#: the candidate terms screened by ``vfcli diagnose`` (instances; :func:`vfcli.diagnose.candidate.available_candidates`)
_INERTIA = Inertia()
#: (damping shares inertia's modal reduction: both profiles and refits use the same steady state)
CANDIDATES = (_INERTIA, KelvinVoigtDamping(modal=_INERTIA), StiffnessAsymmetry(), MountingOffset(), Contact())

__all__ = ["CANDIDATES", "Contact", "Inertia", "KelvinVoigtDamping", "LoadDelay", "MountingOffset",
           "StiffnessAsymmetry"]
