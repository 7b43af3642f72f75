"""Physics-constrained load model: normal pressure tied in time to the measured subglottal pressure.

:class:`PressureLoad` is a :class:`vfcli.model.loads.force_field.LoadModel` (plug it into
:class:`vfcli.model.response.quasi_static.QuasiStaticResponse`).  Unlike the paper's free force field
(:class:`vfcli.model.loads.force_field.ForceField`, independent per fold, per time and per
component), it encodes what the rig fixes (the project reference note "What superior-surface data
can and cannot reveal (a numerical study)"):

Space (``n_spatial`` shapes, Pa per unit control value, normal, pushing into the body)
-------------------------------------------------------------------------------------
- inferior surface (faces ``TAG_INFERIOR``): one uniform pressure, and with
  ``inferior_linear_x`` also a linear variation ``xi = 2 x / L - 1`` along the fold;
- medial surface (faces ``TAG_MEDIAL``): products ``P_i(zeta) P_j(xi)`` of Legendre
  polynomials, ``i < medial_z`` in the normalised medial height ``zeta`` (-1 at the
  bottom of the fold's medial surface, +1 at its top) and ``j`` the first
  ``medial_x`` EVEN degrees (0, 2, ...) in ``xi`` (even about mid-length);
- no load on the superior surface;
- the same shapes on both folds (each evaluated at the fold's own x, z; the pressure
  pushes along each fold's own inward normal, so the loads are mirror images).

Time (``n_time = time_degree + 2`` columns)
-------------------------------------------
``time_basis(t) = [p_s(t) / p_ref, B_0(s), ..., B_n(s)]`` with ``p_s`` the recorded
subglottal pressure (Pa, linearly interpolated), ``p_ref`` its RMS over the window
``t_range`` and ``B_k`` the Bernstein polynomials of degree ``n = time_degree`` in
``s = (t - t1) / (t2 - t1)``.  With ``C`` (n_spatial, n_time) the amplitude of
shape k is therefore

    a_k(t) = C[k, 0] * p_s(t) / p_ref + sum_j C[k, 1 + j] B_j(s)      (Pa)

a gain on the measured pressure (``C[k, 0]`` is the pressure the shape carries when
``p_s = p_ref``; the inferior uniform shape of an aerodynamic load has
``C[k, 0] = p_ref``) plus a smooth free correction.

Bounding the free correction
----------------------------
:attr:`vfcli.inverse.problem.ObjectiveSettings.ridge_weight` weighs ``x^T Omega x / n``
with Omega = :meth:`PressureLoad.penalty_operator`: the size of the free Bernstein
correction (the gains on the measured pressure carry a 1e-6 share only), so the fit
explains by the measured pressure what it can and the bound does not shrink the gains.  :meth:`PressureLoad.free_mask` marks the free
control values (for reporting their size).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.polynomial import legendre

from vfcli.model.loads.bernstein import bernstein
from vfcli.errors import ConfigError, InputDataError
from vfcli.model.loads.force_field import LoadModel
from vfcli.model.mesh import TAG_INFERIOR, TAG_MEDIAL


def _legendre(degree: int, t: np.ndarray) -> np.ndarray:
    """Legendre polynomial P_degree at t (any shape)."""
    c = np.zeros(degree + 1)
    c[degree] = 1.0
    return legendre.legval(t, c)


def band_limited(pressure_time: np.ndarray, pressure_pa: np.ndarray, f0_hz: float,
                 harmonics: float | None) -> np.ndarray:
    """(S,) the recorded pressure (S,) Pa at uniform times (S,) s, low-passed at ``harmonics`` times ``f0_hz``.

    A pressure sensor sampled at tens of kHz records noise across its whole band; the load model samples it at
    each frame, so all of it would reach the loads (white noise of 50 Pa at 50 kHz on a widened phantom: the
    inferior surface 47 % off and its stated 90 % intervals covering 11 %; docs/benchmarks.md, "Rigs off the
    widened draw (session 27)").  The filter is a 4th-order Butterworth run forwards and backwards (zero phase),
    on the record extended at each end by one period of itself (the phonation is periodic), so that its ends
    carry no filter transient: a sum of harmonics up to the 8th of f0 comes back within 3 Pa in 1000 anywhere,
    odd-reflected ends were 8-40 Pa off (tests/test_loads.py).  No ``harmonics`` (None: the record as recorded), a
    cutoff at or above 0.45 of the sampling rate, a missing f0 or a record shorter than two periods returns the
    record unchanged.
    """
    from scipy import signal

    p = np.asarray(pressure_pa, dtype=float)
    t = np.asarray(pressure_time, dtype=float)
    if harmonics is None:
        return p
    cutoff = float(harmonics) * float(f0_hz)
    if p.size < 2 or not np.isfinite(cutoff) or cutoff <= 0:
        return p
    fs = 1.0 / float(np.median(np.diff(t)))
    period = int(round(fs / float(f0_hz)))
    if cutoff >= 0.45 * fs or p.size < 2 * period:
        return p
    ext = np.concatenate([p[:period], p, p[p.size - period:]])      # x(t -+ T) = x(t) at each end
    return signal.sosfiltfilt(signal.butter(4, cutoff, btype="low", fs=fs, output="sos"), ext)[period:period + p.size]


class PressureLoad(LoadModel):
    """Shared normal pressure on the inferior and medial surfaces, tied to the measured p_s(t).

    Parameters
    ----------
    pressure_time : (S,) s, increasing sample times of the recorded subglottal pressure.
    pressure_pa : (S,) Pa, the recorded subglottal pressure.
    t_range : (t1, t2) s, window of the Bernstein correction (t1 < t2); the
        pressure record must cover it.
    time_degree : degree of the Bernstein correction in time (>= 0).
    medial_z : Legendre degrees 0..medial_z-1 in the medial height (>= 1).
    medial_x : even Legendre degrees 0, 2, .., 2 (medial_x - 1) along the fold (>= 1).
    inferior_linear_x : add a linear variation along x on the inferior surface.
    """

    #: the time basis holds a recorded signal (the subglottal pressure, with its sensor noise): a periodic
    #: measurement that differences must not differentiate (vfcli.diagnose.candidates.inertia uses its
    #: harmonics of f0 instead)
    measured_time_basis = True

    def __init__(self, pressure_time: np.ndarray, pressure_pa: np.ndarray, t_range: tuple[float, float],
                 time_degree: int = 4, medial_z: int = 3, medial_x: int = 2, inferior_linear_x: bool = False) -> None:
        t = np.asarray(pressure_time, dtype=float).ravel()
        p = np.asarray(pressure_pa, dtype=float).ravel()
        if t.shape != p.shape or len(t) < 2 or not np.all(np.isfinite(t)) or not np.all(np.isfinite(p)) \
                or not np.all(np.diff(t) > 0):
            raise ValueError("pressure load: the pressure record must be finite samples at increasing times")
        t1, t2 = (float(v) for v in t_range)
        if not (np.isfinite(t1) and np.isfinite(t2) and t2 > t1):
            raise ValueError(f"pressure load time range must be t1 < t2, got {t_range!r}")
        tol = 0.5 * float(np.median(np.diff(t)))
        if t1 < t[0] - tol or t2 > t[-1] + tol:
            raise ConfigError(f"pressure load: the pressure record covers {t[0]:.5f}..{t[-1]:.5f} s, "
                              f"the fitted window {t1:.5f}..{t2:.5f} s (optimize.first_frame, optimize.n_frames)")
        for name, v, lo in (("time_degree", time_degree, 0), ("medial_z", medial_z, 1), ("medial_x", medial_x, 1)):
            if int(v) != v or v < lo:
                raise ValueError(f"pressure load: {name} must be an integer >= {lo}, got {v!r}")
        self.pressure_time, self.pressure_pa = t, p
        self.t_range = (t1, t2)
        inside = (t >= t1 - tol) & (t <= t2 + tol)
        self.p_ref = float(np.sqrt(np.mean(p[inside] ** 2)))
        if not self.p_ref > 0:
            raise InputDataError("pressure load: the recorded pressure is zero over the fitted window")
        self.time_degree, self.medial_z, self.medial_x = int(time_degree), int(medial_z), int(medial_x)
        self.inferior_linear_x = bool(inferior_linear_x)
        self.n_spatial = 1 + int(self.inferior_linear_x) + self.medial_z * self.medial_x
        self.n_time = self.time_degree + 2

    def richer(self) -> "PressureLoad":
        """The next richer pressure load: one more Legendre degree in the medial height, one more even degree
        along the fold, and the inferior surface's linear variation; the same pressure record, window and time
        basis. Its fit against this one's says how much the reconstruction hangs on the load's spatial family
        (:func:`vfcli.inverse.uncertainty.load_family_fit`)."""
        return PressureLoad(self.pressure_time, self.pressure_pa, self.t_range, time_degree=self.time_degree,
                            medial_z=self.medial_z + 1, medial_x=self.medial_x + 1, inferior_linear_x=True)

    def embedding(self, other: "PressureLoad") -> np.ndarray:
        """(n_params,) int: the index in ``other``'s control values of each of this load's (the same shape and
        time column); ``other`` must hold every shape of this one (as :meth:`richer` does)."""
        if other.n_time != self.n_time:
            raise ValueError(f"pressure loads with {self.n_time} and {other.n_time} time columns do not nest")
        where = {name: k for k, name in enumerate(other.spatial_names())}
        missing = [name for name in self.spatial_names() if name not in where]
        if missing:
            raise ValueError(f"the other pressure load has no shape {missing[0]!r}")
        rows = np.array([where[name] for name in self.spatial_names()])
        return (rows[:, None] * other.n_time + np.arange(self.n_time)[None, :]).ravel()

    # ------------------------------------------------------------ space
    def spatial_names(self) -> list[str]:
        names = ["inferior/uniform"] + (["inferior/x1"] if self.inferior_linear_x else [])
        return names + [f"medial/z{i}x{2 * j}" for i in range(self.medial_z) for j in range(self.medial_x)]

    def shape_values(self, quadrature) -> tuple[np.ndarray, np.ndarray]:
        """Pressure shapes at the loaded quadrature points.

        Parameters
        ----------
        quadrature : :class:`vfcli.model.fem.FacetQuadrature` (Q points).

        Returns
        -------
        mask : (Q,) bool, points on inferior or medial facets.
        values : (mask.sum(), n_spatial) float64, Pa per unit control value.
        """
        mask = np.isin(quadrature.tag, [TAG_INFERIOR, TAG_MEDIAL])
        pos, tag, fold = quadrature.positions[mask], quadrature.tag[mask], quadrature.fold[mask]
        x_lo, x_hi = quadrature.positions[:, 0].min(), quadrature.positions[:, 0].max()
        xi = 2.0 * (pos[:, 0] - x_lo) / (x_hi - x_lo) - 1.0
        zeta = np.zeros(len(pos))
        for k in np.unique(fold):
            med = (tag == TAG_MEDIAL) & (fold == k)
            if med.any():
                z = pos[med, 2]
                zeta[med] = 2.0 * (z - z.min()) / max(z.max() - z.min(), 1e-12) - 1.0
        inf, med = (tag == TAG_INFERIOR).astype(float), (tag == TAG_MEDIAL).astype(float)
        cols = [inf] + ([inf * xi] if self.inferior_linear_x else [])
        cols += [med * _legendre(i, zeta) * _legendre(2 * j, xi) for i in range(self.medial_z) for j in range(self.medial_x)]
        return mask, np.column_stack(cols)

    def spatial_loads(self, model) -> sp.csr_matrix:
        """(n_dofs, n_spatial) FEM loads, Pa mm^2: ``model.pressure_operator(mask) @ shapes``."""
        mask, values = self.shape_values(model.quadrature)
        return sp.csr_matrix(model.pressure_operator(mask) @ values)

    # ------------------------------------------------------------ time
    def pressure_at(self, times: np.ndarray) -> np.ndarray:
        """(T,) recorded subglottal pressure at ``times`` (s), Pa (linear interpolation)."""
        return np.interp(np.asarray(times, dtype=float), self.pressure_time, self.pressure_pa)

    def time_basis(self, times: np.ndarray) -> np.ndarray:
        """(T, time_degree + 2): ``[p_s / p_ref, Bernstein basis of degree time_degree]``."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        t1, t2 = self.t_range
        return np.column_stack([self.pressure_at(times) / self.p_ref, bernstein(self.time_degree, (times - t1) / (t2 - t1))])

    def parameter_names(self) -> list[str]:
        """``"<shape>@ps"`` (gain on the measured pressure) then ``"<shape>@t<k>"`` (correction)."""
        return [f"{s}@{'ps' if k == 0 else f't{k - 1}'}" for s in self.spatial_names() for k in range(self.n_time)]

    def penalty_operator(self) -> sp.csr_matrix:
        """(n_params, n_params) ridge matrix Omega: the free correction's size (the gains on the measured
        pressure carry a 1e-6 share only, which keeps the problem well posed without shrinking them)."""
        return sp.diags(np.where(self.free_mask(), 1.0, 1e-6)).tocsr()

    def free_mask(self) -> np.ndarray:
        """(n_params,) bool: control values of the free Bernstein correction (not the gains)."""
        m = np.ones((self.n_spatial, self.n_time), bool)
        m[:, 0] = False
        return m.ravel()

    def amplitudes(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, n_spatial) shape amplitudes a_k(t), Pa."""
        return self.time_basis(times) @ self.control_matrix(x).T
