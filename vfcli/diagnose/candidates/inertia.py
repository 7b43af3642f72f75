"""Inertia: the mass of the folds, a density factor rho (1 = the model's tissue density).

The baseline is quasi-static, ``K u0 = F``: massless.  With the mass switched on (and a small
structural loss eta, :attr:`Inertia.loss`), the periodic steady state of the window's load, harmonic
k of f0 at a time, is ``(c K - rho (k w0)^2 M)^-1 F_k``, ``c = 1 + i eta``
(:class:`vfcli.model.response.steady_state.SteadyStateResponse`: the extended model, exact at any
density, linear in the loads).  Its derivative at rho = 0 is the column

    dU/drho = Re sum_k (k w0)^2 / c^2  K^-1 M K^-1 L C beta_k e^{i k w0 t}

(L the load model's spatial loads, C its controls, beta_k the harmonics of f0 of its time basis
fitted over the window): content rising with the square of frequency.  That is the column of a load
model tied in time to a recorded signal (``measured_time_basis``: the pressure load, whose time basis
holds the measured subglottal pressure): the screening then tests the very model the refit fits.
Differences of such a time basis differentiate the *recorded* pressure twice at half a frame
interval, and its sensor noise dominates (on a phantom with 4 Pa of pressure noise at 50 kHz the
second difference's RMS was 23 times the pressure's own at f0; the column was 3.5 times its own size
away from the derivative of the steady state, cosine 0.26).  A load model with a free polynomial time
basis (the force field) keeps the exact time-domain derivative of that load history,
``-K^-1 M K^-1 L C b''(t)`` (the periodic extension of a polynomial over the window jumps at its
ends, which is not that load's inertia); so does any load model when f0 is unknown (NaN).

The derivative at rho = 0 says little about the tissue's own density: the folds' lowest mode lies
near 50 Hz (E = 4.4 kPa, 1070 kg/m^3), so at f0 = 120 Hz the series in rho converges only for
rho < (50 / 120)^2 = 0.17 and at rho = 1 the steady state differs from the quasi-static motion by
about its own size.  The confirmation refit therefore fits the density with the loads refitted
under the extended response (:meth:`Inertia.response`, :mod:`vfcli.diagnose.refit`), not by the
column.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp

from vfcli.diagnose.candidates.base import DisplacementTerm, derivative_step, time_derivative
from vfcli.model.refine import density_shift
from vfcli.model.response.modal import COMPLETE_MAX_DOFS, ModalReduction, harmonic_fit
from vfcli.model.response.steady_state import SteadyStateResponse

log = logging.getLogger(__name__)

#: largest relative distance in frequency, ``|sqrt(rho / centre) - 1|``, between the refit's density and the
#: density the shifted Ritz vectors are centred on before :meth:`Inertia.recentre` rebuilds them
RECENTRE_TOL = 0.01


def complete_expansion(model) -> bool:
    """True when every fold of ``model`` is small enough for the complete modal expansion (at most
    :data:`vfcli.model.response.modal.COMPLETE_MAX_DOFS` free DOFs), exact at any density."""
    return max(len(f.free) for f in model.folds) <= COMPLETE_MAX_DOFS


def elastic_model_of(baseline):
    """The baseline's :class:`vfcli.model.fem.ElasticModel`: ``baseline.model`` (the run's own: its
    E, nu and density) when the baseline carries one, else a default-material model of its mesh
    (E = 4.4 kPa, nu = 0.499, 1070 kg/m^3; the column then scales with 4.4 kPa / E of the run)."""
    model = getattr(baseline, "model", None)
    if model is None:
        from vfcli.model.fem import ElasticModel

        log.warning("the baseline carries no elastic model; candidate terms use a default-material model of its mesh")
        model = ElasticModel(baseline.problem.mesh)
    return model


def term_model(term, baseline):
    """The elastic model a term uses: its own ``term.model`` if given, else the baseline's, else a
    default-material model of the baseline's mesh (kept in ``term._own``, built once per mesh:
    CANDIDATES' instances are shared)."""
    if term.model is not None:
        return term.model
    if getattr(baseline, "model", None) is not None:
        return baseline.model
    if term._own[0] is not baseline.problem.mesh:
        term._own = (baseline.problem.mesh, elastic_model_of(baseline))
    return term._own[1]


def load_harmonics(baseline, x: np.ndarray, n_harmonics: int) -> np.ndarray:
    """(n_harmonics + 1, S) complex one-sided harmonics of ``baseline.f0_hz`` of the load pattern amplitudes
    ``C(x) b(t)`` over the window's simulated times (:func:`vfcli.model.response.modal.harmonic_fit`)."""
    p = baseline.problem
    load_model = p.response.load_model
    amp = load_model.time_basis(p.sim_times) @ load_model.control_matrix(np.asarray(x, dtype=float)).T   # (T, S)
    return harmonic_fit(amp, p.sim_times, baseline.f0_hz, n_harmonics)


class Inertia(DisplacementTerm):
    """Density factor rho of the folds (1 = tissue density of the elastic model), one parameter.

    Parameters
    ----------
    model : the :class:`vfcli.model.fem.ElasticModel` of the baseline (default: ``baseline.model``
        or a default-material model of the baseline's mesh).
    """

    name = "inertia"
    parameter_names = ("density_factor",)
    signature = ("residual content rising with the square of frequency (the higher harmonics of f0 "
                 "under-predicted), with the phase flipping above a resonance of the folds")

    #: densities the confirmation refit tries before its Gauss-Newton steps (:mod:`vfcli.diagnose.refit`):
    #: above a resonance the change is far from linear in the density
    start_values = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0)
    #: the score test's derivative at density 0 does not reach the tissue's density when the folds' lowest
    #: mode lies below f0 (:meth:`evidence`): the diagnosis also profiles E over :attr:`start_values` with the
    #: loads refitted (:mod:`vfcli.diagnose.profile`)
    profile_screening = True
    #: structural loss factor eta of the steady state (``K (1 + i eta)``): it keeps the resonances of
    #: the folds' dense spectrum bounded (undamped, a harmonic near a mode made the change 100 times
    #: the motion).  An assumption of the term, not fitted; on an inertia phantom (seed 35) the density
    #: that minimised E with the loads refitted was the same (1.0 to 1.1) for eta = 0, 0.02 and 0.1.
    loss = 0.02
    #: harmonics of f0 of the load kept in the steady state
    n_harmonics = 6

    def __init__(self, model=None) -> None:
        self.model = model
        self._cache: tuple = (None, None, None)      # (response, model, its mass responses)
        self._own: tuple = (None, None)              # (mesh, the default model built for it)
        self._reduced: list = []                     # [(key, reduction)]: centre 1 and at most one other
        self._centre: tuple = (None, 1.0)            # (response, the density the refit re-centred on)

    def _model(self, baseline):
        return term_model(self, baseline)

    def mass_responses(self, baseline) -> np.ndarray:
        """(N, 3, S) vertex displacement of ``K^-1 M K^-1 L_s`` per spatial load pattern s, mm s^2."""
        response = baseline.problem.response
        model = self._model(baseline)
        if self._cache[0] is not response or self._cache[1] is not model:
            loads = response.load_model.spatial_loads(model)
            loads = loads.toarray() if sp.issparse(loads) else np.asarray(loads, dtype=float)
            z = model.solve(model.mass @ model.solve(loads))
            self._cache = (response, model, np.moveaxis(model.vertex_displacements(z), 0, -1))   # (N, 3, S)
        return self._cache[2]

    def displacement_jacobian(self, baseline) -> np.ndarray:
        """(F + 1, N, 3, 1) dU/drho at rho = 0 (module docstring), mm per unit density factor: the exact
        derivative of :meth:`extension` for a load tied to a recorded signal when ``baseline.f0_hz`` is
        known, else from differences of the load's time basis."""
        p = baseline.problem
        load_model = p.response.load_model
        c = load_model.control_matrix(baseline.x)                                  # (S, n_time)
        z = self.mass_responses(baseline)
        periodic = np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0
        if not (periodic and getattr(load_model, "measured_time_basis", False)):
            b2 = time_derivative(load_model.time_basis, p.sim_times, 2, derivative_step(baseline))   # (T, n_time)
            return -np.einsum("ncs,st->tnc", z, c @ b2.T)[..., None]
        t = p.sim_times
        beta = harmonic_fit(load_model.time_basis(t), t, baseline.f0_hz, self.n_harmonics)   # (K + 1, n_time)
        w0 = 2 * np.pi * baseline.f0_hz
        k = np.arange(beta.shape[0])
        amp = np.exp(1j * w0 * np.outer(t, k)) * ((k * w0) ** 2 / (1 + 1j * self.loss) ** 2)   # (T, K + 1)
        a = np.real(amp @ (beta @ c.T))                                            # (T, S) load amplitudes
        return np.einsum("ncs,ts->tnc", z, a)[..., None]

    def response(self, baseline, theta: np.ndarray) -> SteadyStateResponse:
        """The extended response at density factor theta[0]: the baseline's quasi-static response plus
        the steady-state change of the mass (:class:`vfcli.model.response.steady_state.SteadyStateResponse`,
        loss :attr:`loss`), linear in the loads (the confirmation refit fits the loads with it)."""
        rho = float(np.asarray(theta, dtype=float).reshape(-1)[0])
        p = baseline.problem
        red = self.reduction(baseline, self.n_harmonics, self.centre(baseline))
        return SteadyStateResponse(p.response, red, baseline.f0_hz,
                                   p.sim_times, density=rho, loss=self.loss, n_harmonics=self.n_harmonics)

    def lowest_mode_hz(self, baseline) -> float:
        """The folds' lowest natural frequency at the model's density (clamped fixture), Hz: from the
        modal reduction when it is built, else one shift-invert eigenpair per fold."""
        for key, red in self._reduced:
            if key[0] is baseline.problem.response and len(red.fold_frequencies_hz_):
                return float(red.fold_frequencies_hz_.min())
        model = self._model(baseline)
        return float(min(model.modes(1, fold=k)[0][0] for k in (0, 1)))

    def evidence(self, baseline) -> str:
        """Plain words: how far the screening's linearisation reaches in density.  The score test looks at
        densities near 0; the steady state's series in the density converges for harmonic k of f0 up to
        ``(f_1 / (k f0))^2`` (f_1 the folds' lowest mode), so where f_1 lies below f0 the model's own
        density (1) is beyond what the test can see and only its profile (:mod:`vfcli.diagnose.profile`) and refit see it
        (tests/test_candidates.py: the column predicts the change within 7 % at 0.02 (f_1 / f0)^2 and is
        16 times off at density 1)."""
        if not (np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0):
            return "f0 unknown: the density's reach of the test not assessed"
        f1 = self.lowest_mode_hz(baseline)
        r = (f1 / baseline.f0_hz) ** 2
        if r >= 1.0:
            return (f"the folds' lowest mode ({f1:.0f} Hz) lies above f0 ({baseline.f0_hz:.0f} Hz): the score test's "
                    f"linearisation reaches density factors up to {r:.2g} at f0 (less at its harmonics)")
        return (f"the folds' lowest mode ({f1:.0f} Hz) lies below f0 ({baseline.f0_hz:.0f} Hz): the score test's "
                f"linearisation reaches density factors up to {r:.2g} at f0 (less at its harmonics), so a missing mass "
                f"near the model's own density (1) is not seen by it; its profile (the loads refitted at each of "
                f"{', '.join(f'{v:g}' for v in self.start_values)}) is, where the diagnosis runs it (its own line, "
                f"'inertia: profile ...')")

    def reduction(self, baseline, n_harmonics: int = 6, centre: float = 1.0, map=None) -> ModalReduction:
        """The modal reduction of the baseline's model and load patterns, built once per response,
        model, f0 and centre: the complete modal expansion (exact at any density and retardation time)
        when each fold has at most :data:`vfcli.model.response.modal.COMPLETE_MAX_DOFS` free DOFs (a run's
        2.5 mm mesh: 3480), else the Ritz reduction with shifted Ritz vectors at the harmonics
        ``k f0 sqrt(centre)`` (k = 1..n_harmonics): exact there at density factor ``centre`` without
        damping, not at other densities (:meth:`recentre`).  map : runs its shifts' factorisations (an in-process
        map, :class:`vfcli.model.response.modal.ModalReduction`); default one after the other."""
        response = baseline.problem.response
        model = self._model(baseline)
        complete = complete_expansion(model)
        centre = 1.0 if complete else float(centre)
        key = (response, model, float(baseline.f0_hz), int(n_harmonics), centre)
        for k, red in self._reduced:
            if k == key:
                return red
        loads = response.load_model.spatial_loads(model)
        if complete:
            red = ModalReduction.complete(model, loads)
        else:
            shifts = (baseline.f0_hz * np.sqrt(centre) * np.arange(1, n_harmonics + 1)
                      if np.isfinite(baseline.f0_hz) else ())
            red = ModalReduction(model, loads, shifts_hz=shifts, map=map)
        # keep the one at centre 1 (the profile's and damping's) and the newest other one
        self._reduced = [(k, r) for k, r in self._reduced if k[:4] == key[:4] and k[4] == 1.0][:1] + [(key, red)]
        return red

    def centre(self, baseline) -> float:
        """The density factor the reduction of this baseline's response is centred on (1 until :meth:`recentre`)."""
        response, centre = self._centre
        return centre if response is baseline.problem.response else 1.0

    def recentre(self, baseline, theta: np.ndarray) -> bool:
        """Centre the Ritz reduction's shifts on the density factor theta[0] (the refit's estimate) when
        the harmonics at that density lie more than :data:`RECENTRE_TOL` (relative, in frequency) from the
        shifts; True if the response changed (the refit then steps again, :mod:`vfcli.diagnose.refit`).

        The shifted Ritz vectors make the steady state exact at their own density only: on a widened
        phantom's 1.5 mm mesh with shifts at density 1, the 3rd and 4th harmonics of 120 Hz were 0.45 %
        and 24 % off at density 1.5, 13 % and 88 % at 2 (docs/diagnose.md).  The complete expansion is
        exact at every density: never re-centred."""
        rho = float(np.asarray(theta, dtype=float).reshape(-1)[0])
        if complete_expansion(self._model(baseline)) or not rho > 0:
            return False
        if abs(np.sqrt(rho / self.centre(baseline)) - 1.0) <= RECENTRE_TOL:
            return False
        self._centre = (baseline.problem.response, rho)
        return True

    #: harmonics of f0, at the fitted density, up to which :meth:`mesh_shift` compares the two meshes' modes
    mesh_band = 3.5
    #: modes per fold :meth:`mesh_shift` starts from, and the most it takes
    mesh_modes = (60, 240)

    def mesh_shift(self, baseline, theta: np.ndarray, x: np.ndarray | None = None) -> np.ndarray | None:
        """(1,) delta, the relative shift of the density a fit on the run's mesh makes against one on the same
        folds ``baseline.finer_model()`` (edges 1.2 times shorter, :mod:`vfcli.model.refine`): the fit mesh's
        estimate is about ``(1 + delta)`` times the finer mesh's. For the loads ``x`` (the refit's; default the
        baseline's) at the camera's visible vertices, the larger of their displacements' and velocities'
        (:func:`vfcli.model.refine.density_shift`); None without a finer model or an f0.

        The fit finds the density that puts the folds' resonances where the recording has them, and a mesh
        whose modes are stiff needs more density.  How much depends on which modes the harmonics of the load
        excite: on widened phantoms' 1.5 mm meshes the lowest six modes stiffen by 0.5-0.7 %, modes near 150-250
        Hz by 1.1-3.0 %, and the density refitted on the finer mesh fell by 2.1 % (2002) and 2.0 % (2007) where
        this states 2.5 and 2.1 % (the lowest six modes' mean, the mesh part until session 67, said 0.7 %:
        the panel's estimates came out 1-2 % high, outside their intervals; docs/diagnose.md)."""
        make = getattr(baseline, "finer_model", None)
        f0 = float(getattr(baseline, "f0_hz", float("nan")))
        if not callable(make) or not (np.isfinite(f0) and f0 > 0):
            return None
        fine = make()
        if fine is None:
            return None
        model = self._model(baseline)
        p = baseline.problem
        spec = load_harmonics(baseline, baseline.x if x is None else x, self.n_harmonics)     # (K + 1, S)
        forces = np.asarray(p.response.load_model.spatial_loads(model) @ spec.T)              # (n_dofs, K + 1)
        folds = (1,) if model.is_mirrored and fine.is_mirrored else (0, 1)      # mirror images: one is enough
        rho = float(np.asarray(theta, dtype=float).reshape(-1)[0])
        delta = density_shift(model, fine, forces, f0, rho, np.unique(p.tri), loss=self.loss,
                              band=self.mesh_band, modes=self.mesh_modes, folds=folds)
        return np.array([delta])

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) change at density factor theta[0], mm: the periodic steady state with that density
        minus the one without (both of the same harmonics of the load and the same loss, so theta = 0
        changes nothing), from :meth:`reduction` (exact with the complete modal expansion; see
        :mod:`vfcli.model.response.modal` for the Ritz reduction at other densities)."""
        if not (np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0):
            raise ValueError(f"the inertia steady state needs the baseline's f0, got {baseline.f0_hz!r}")
        return self.response(baseline, theta).change(baseline.x, baseline.problem.sim_times)

    def steady_state(self, baseline, density: float, reduction: ModalReduction | None = None,
                     n_harmonics: int = 6, retardation_s: float = 0.0, loss: float = 0.0) -> np.ndarray:
        """(F + 1, N, 3) periodic steady state of the baseline's load with density factor ``density``, mm.

        The load amplitudes ``C b(t)`` are fitted by ``n_harmonics`` harmonics of ``baseline.f0_hz``
        over the window (:func:`vfcli.model.response.modal.harmonic_fit`); ``density = 0`` (with
        ``loss = 0``) is the quasi-static response of that periodic load.  loss : structural loss factor.
        """
        p = baseline.problem
        if not np.isfinite(baseline.f0_hz) or baseline.f0_hz <= 0:
            raise ValueError(f"the inertia steady state needs the baseline's f0, got {baseline.f0_hz!r}")
        if reduction is None:
            reduction = self.reduction(baseline, n_harmonics)
        spec = load_harmonics(baseline, baseline.x, n_harmonics)
        return reduction.steady_state(spec, baseline.f0_hz, p.sim_times, density, retardation_s, loss)
