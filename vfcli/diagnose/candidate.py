"""The seam between Locate and Explain: what a candidate physics term provides.

A candidate is a small named physics term the baseline model left out (inertia, damping,
contact, left-right asymmetry ...).  Screening needs from it only the Jacobian of the
*predicted measurement* with respect to the term's few parameters, at the baseline fit
(the term switched off, theta = theta_0): with the baseline's residual r (measured minus
predicted) and the baseline's own Jacobian, a score test asks whether r leans on those
columns beyond noise.

The predicted measurement is the vector :class:`Baseline` defines (the same rows the
residual has, in the same order):

* **motion rows**: per frame f (0..F-1) and compared pixel (the pixels valid in both the
  recording and the simulation at the baseline's frozen raster), the simulated surface
  velocity at the frame time ``M_f V_f`` (``Problem.frame_velocity``, mm/s), 3 components (model x, y, z);
  frame-major, then pixel (in ``Problem.freeze``'s order), then component;
* **gap rows**: per frame and silhouette crossing (each ray and fold side the baseline's
  frozen silhouettes use), the simulated lateral silhouette position, mm.

A candidate whose effect is a change of vertex displacements ``dU`` (F + 1, N, 3) per unit
parameter (most are) gets its columns from :meth:`Baseline.measure_linear`; one that acts on
the measurement directly (a sync timing error) builds them itself in the same row order.
"""
from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from vfcli.inverse.terms.gap import gap_rows
from vfcli.inverse.terms.motion import frame_change, frame_prediction


@dataclass
class Baseline:
    """The fitted baseline a candidate is linearised at.

    problem : the run's :class:`vfcli.inverse.problem.Problem` (mesh, camera, response, measurement, settings).
    x : (n_params,) fitted control values of the run.
    displacements : (F + 1, N, 3) mm, the baseline's vertex displacements at ``problem.sim_times``.
    frames : the frozen rasters and silhouettes at x (``problem.freeze(x, displacements)``).
    f0_hz : fundamental frequency of the window (from the gap area's cycle), Hz.
    model : the run's own :class:`vfcli.model.fem.ElasticModel` (its mesh, E, nu and density: the
        one the run was fitted with, :func:`vfcli.store.fit.run_model`), or None when unknown (then a
        candidate that needs K or M builds a default-material model of the mesh, which scales its columns).
    finer_model : None, or a callable returning the run's folds and material on a finer mesh
        (:func:`vfcli.model.refine.finer_model`; the stage sets it): a term states from it how far the fit
        mesh's discretisation moves its parameter (:meth:`vfcli.diagnose.candidates.inertia.Inertia.mesh_shift`).
    """

    problem: object
    x: np.ndarray
    displacements: np.ndarray
    frames: list
    f0_hz: float = float("nan")
    model: object | None = None
    finer_model: object | None = None

    @classmethod
    def at(cls, problem, x: np.ndarray, f0_hz: float = float("nan"), model=None) -> "Baseline":
        """The baseline of ``problem`` at control values ``x`` (displacements and frozen frames computed),
        with the run's elastic ``model`` when known."""
        x = np.asarray(x, dtype=float)
        u = problem.displacements(x)
        return cls(problem, x, u, problem.freeze(x, u), float(f0_hz), model)

    # ------------------------------------------------------------------ rows
    @property
    def n_motion_rows(self) -> int:
        """3 per compared pixel and frame."""
        return int(sum(3 * fr.m_both.shape[0] for fr in self.frames))

    def motion_vector(self, disp: np.ndarray) -> np.ndarray:
        """(n_motion_rows,) simulated velocity (mm/s) at the compared pixels for displacements disp (F + 1, N, 3)
        (the frozen frames' model, with the surface sliding under the pixels when the run's settings have it)."""
        p = self.problem
        return np.concatenate([frame_prediction(fr, p.frame_velocity(disp, f), disp[f]).ravel()
                               for f, fr in enumerate(self.frames)] or [np.zeros(0)])

    def motion_change(self, du: np.ndarray) -> np.ndarray:
        """(n_motion_rows,) change of :meth:`motion_vector` (mm/s) for a displacement change du (F + 1, N, 3), mm."""
        p = self.problem
        return np.concatenate([frame_change(fr, p.frame_velocity(du, f), du[f]).ravel()
                               for f, fr in enumerate(self.frames)] or [np.zeros(0)])

    def measured_motion(self) -> np.ndarray:
        """(n_motion_rows,) measured velocity (mm/s) at the compared pixels, in the rows' order."""
        return np.concatenate([fr.v_both.ravel() for fr in self.frames] or [np.zeros(0)])

    def gap_jacobian(self, dudp: np.ndarray) -> np.ndarray:
        """(n_gap_rows, P) silhouette position change (mm) per unit parameter.

        dudp : (F + 1, N, 3, P) vertex displacement change (mm) per unit parameter.
        """
        p = self.problem
        out = []
        for f, fr in enumerate(self.frames):
            pos = p.mesh.nodes + self.displacements[f]
            q, _ = gap_rows(p, pos, fr.sil, dudp[f])
            out.append(q / p.camera.px_per_mm)
        return np.concatenate(out) if out else np.zeros((0, dudp.shape[-1]))

    def gap_residual(self) -> np.ndarray:
        """(n_gap_rows,) measured minus simulated silhouette position, mm (rows of :meth:`gap_jacobian`)."""
        p = self.problem
        out = []
        for f, fr in enumerate(self.frames):
            pos = p.mesh.nodes + self.displacements[f]
            _, dist = gap_rows(p, pos, fr.sil, np.zeros((len(pos), 3, 0)))
            out.append(-dist / p.camera.px_per_mm)
        return np.concatenate(out) if out else np.zeros(0)

    def measure_linear(self, dudp: np.ndarray) -> np.ndarray:
        """(n_motion_rows + n_gap_rows, P) Jacobian columns of the predicted measurement.

        dudp : (F + 1, N, 3, P) vertex displacement change (mm) per unit parameter at
        ``problem.sim_times``.  Rows: motion rows (mm/s per unit) then gap rows (mm per unit).
        """
        dudp = np.asarray(dudp, dtype=float)
        if dudp.ndim != 4 or dudp.shape[:3] != self.displacements.shape:
            raise ValueError(f"dudp must be {self.displacements.shape + ('P',)}, got {dudp.shape}")
        motion = np.stack([self.motion_change(dudp[..., j]) for j in range(dudp.shape[-1])], axis=1) \
            if dudp.shape[-1] else np.zeros((self.n_motion_rows, 0))
        return np.concatenate([motion, self.gap_jacobian(dudp)], axis=0)

    def residual_vector(self) -> np.ndarray:
        """(n_motion_rows + n_gap_rows,) measured minus predicted, rows of :meth:`measure_linear`."""
        return np.concatenate([self.measured_motion() - self.motion_vector(self.displacements), self.gap_residual()])


@runtime_checkable
class Candidate(Protocol):
    """A candidate physics term (implementations live in :mod:`vfcli.diagnose.candidates`).

    name : short identifier ("inertia", "damping", "contact", "asymmetry" ...).
    n_params : number of the term's parameters theta (few).
    parameter_names : (n_params,) names with units, e.g. ("retardation_time_s",).
    signature : one or two sentences, in plain words, of the residual the term leaves when it
        is missing (e.g. "content rising with the square of frequency, phase flip above resonance").
    one_sided : optional (default False): True when the term's one parameter is physical only when
        positive (a retardation time): the calibrated screening counts only evidence for a positive
        value (:mod:`vfcli.diagnose.calibrate`).
    evidence : optional ``evidence(baseline) -> str``: what the baseline shows of the signature (contact's midplane
        crossing), said after the screening line.
    reading : optional ``reading(theta) -> str``: an estimate of theta in the lab's terms (the mounting offsets as
        the folds' mounting), said after the screening's one-step estimate and the refit's estimate.
    missing_signature : optional ``missing_signature(baseline) -> str``: "" when the baseline shows what the term's
        signature says it must, else why not; a refit of a term whose signature is missing confirms nothing
        (:attr:`vfcli.diagnose.confirmation.Confirmation.signature_missing`; contact's crossing with the closure).
    """

    name: str
    n_params: int
    parameter_names: tuple[str, ...]
    signature: str

    def jacobian(self, baseline: Baseline) -> np.ndarray:
        """(n_motion_rows + n_gap_rows, n_params) d(predicted measurement)/d(theta) at the baseline
        fit with the term switched off (theta_0), rows as :meth:`Baseline.measure_linear`."""
        ...


@dataclass(frozen=True)
class Screening:
    """The screening result of one candidate.

    name : the candidate's name.  statistic : the test statistic (e.g. a score statistic).
    p_value : its naive p-value under the baseline (chi2; null: the term is absent).
    p_calibrated, p_family : its bootstrap p-value alone and family-wise over all candidates
        (:mod:`vfcli.diagnose.calibrate`; NaN when not calibrated).
    identifiable : False when the load model can absorb the term ("not identifiable with this load model").
    estimate, interval : (n_params,) one-step estimate of theta and its (n_params, 2) interval, or None.
    words : one line in plain words.
    """

    name: str
    statistic: float
    p_value: float
    identifiable: bool
    estimate: np.ndarray | None = None
    interval: np.ndarray | None = None
    words: str = ""
    p_calibrated: float = float("nan")
    p_family: float = float("nan")


def screen(located, candidates: Sequence[Candidate], baseline: Baseline) -> list[Screening]:
    """Screen every candidate against the located residual (the Explain step's entry point).

    located : :class:`vfcli.diagnose.locate.Located` (hotspots, noise floor, cycles).
    candidates : the candidate terms to screen.  baseline : the fit they are linearised at.

    Returns one :class:`Screening` per candidate, in the given order.  With no candidates
    there is nothing to screen (the command then says "candidate screening: not built yet").
    """
    if not candidates:
        return []
    from vfcli.diagnose.candidates.blocks import screen_run

    return screenings(candidates, screen_run(candidates, baseline), baseline)


def screenings(candidates: Sequence[Candidate], tests, baseline: Baseline) -> list[Screening]:
    """One :class:`Screening` per candidate from its score test
    (:class:`vfcli.diagnose.candidates.screening.ScoreTest`), in the given order; each line followed by
    the evidence the candidate reads off the baseline, when it states one."""
    from vfcli.diagnose.candidates.screening import words

    return [Screening(c.name, t.statistic, t.p_value, t.identifiability.identifiable, t.estimate,
                      np.column_stack([t.estimate - 1.96 * t.std, t.estimate + 1.96 * t.std]),
                      _with_evidence(_with_reading(words(c, t, len(candidates)), c, t), c, baseline))
            for c, t in zip(candidates, tests)]


def _with_evidence(line: str, candidate, baseline) -> str:
    """The screening line, followed by what the baseline shows of the term's signature when the
    candidate states it (an optional ``evidence(baseline) -> str``, e.g. contact's midplane crossing)."""
    evidence = getattr(candidate, "evidence", None)
    return f"{line}; {evidence(baseline)}" if callable(evidence) else line


def _with_reading(line: str, candidate, test) -> str:
    """The screening line, followed by the one-step estimate in the lab's terms when the candidate reads it (an
    optional ``reading(theta) -> str``) and the term acts and is identifiable (else there is no estimate)."""
    reading = getattr(candidate, "reading", None)
    acts = np.any(test.identifiability.own_information) and test.identifiability.identifiable
    return f"{line}; {reading(test.estimate)}" if callable(reading) and acts else line


#: the package of candidate terms; it exposes ``CANDIDATES``: a sequence of :class:`Candidate` instances
CANDIDATES_PACKAGE = "vfcli.diagnose.candidates"


def available_candidates() -> list[Candidate]:
    """The candidate terms of :data:`CANDIDATES_PACKAGE` (its ``CANDIDATES``); empty until that package exists."""
    if importlib.util.find_spec(CANDIDATES_PACKAGE) is None:
        return []
    return list(getattr(importlib.import_module(CANDIDATES_PACKAGE), "CANDIDATES", ()))
