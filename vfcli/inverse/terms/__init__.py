"""The terms of the paper's error E: motion, gap and ridge (:mod:`vfcli.inverse.terms.base`)."""
from vfcli.inverse.terms.base import Evaluation, KronBlocks, Term, Terms
from vfcli.inverse.terms.gap import GapTerm
from vfcli.inverse.terms.motion import MotionTerm
from vfcli.inverse.terms.ridge import RidgeTerm

#: the terms of :class:`vfcli.inverse.problem.Problem` unless it is given others
DEFAULT_TERMS = (MotionTerm, GapTerm, RidgeTerm)

__all__ = ["DEFAULT_TERMS", "Evaluation", "GapTerm", "KronBlocks", "MotionTerm", "RidgeTerm", "Term", "Terms"]
