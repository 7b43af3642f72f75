"""How well the recording determines the reconstruction: posterior covariance of a fit.

The optimize stage states the fit's mean squared error by the sandwich covariance of
:mod:`vfcli.inverse.sandwich` (calibrated on residuals that are model error rather than white
noise), plus the instruments' disagreement below, each split into the static part and the
oscillating part over the window (:func:`instrument_split`, :func:`window_mean`,
:func:`window_oscillation`).  The Laplace posterior of this module is kept as a library function
(its scale follows the residual's total size: 98.6 % coverage of 90 % intervals on the test
phantom, where the sandwich gives 89.5 %).

Around the optimum the displacements are described by the response's linearisation
(``dU(t) = sum_j R_j dC B_j(t)``, exact for a linear response such as ``U(t) = R C b(t)``),
and E by its Gauss-Newton model (:mod:`vfcli.inverse.linearization`).  Reading E as a scaled negative
log-posterior, ``-log p(x | data) = kappa * E(x) + const`` (the ridge term then acts
as a Gaussian prior on x), the Laplace approximation gives

    Cov(x) = (kappa * H)^-1,        H the Gauss-Newton Hessian of E (ridge included).

The scale kappa is set from the motion residuals themselves, the way a
least-squares fit estimates its noise variance: at the optimum the data misfit
should be chi-square with ``n_eff - dof`` degrees of freedom, so

    kappa = (n_eff - dof) / (2 E_motion),      dof = trace(H^-1 H_data).

``n_eff`` is the number of *independent* motion residuals.  Optical flow and the
interpolated vibrometer field give residuals that are correlated over many pixels and
frames; counting every pixel as independent would make the stated uncertainty far too
small.  We measure the correlation in the residual images (:func:`effective_sample_size`):
``n_eff = n_residuals / (A * tau)``, with A the integral correlation area (px) of the
residual field in the image plane and tau the integral correlation time (frames), each
the sum of the normalised autocorrelation up to its first zero crossing.  Model error
(what the load model cannot represent) shows up as a larger and more correlated
residual, so it widens the stated uncertainty instead of being ignored.

From Cov(x) the standard deviation of every vertex displacement component at every
simulated time follows exactly (:func:`displacement_std`).  Where the data do not
determine the loads (the paper's free fields without a bound, H singular), the stated
uncertainty is correspondingly huge: that is the honest answer.

Systematic error: what the two instruments say apart
----------------------------------------------------
The posterior above knows only the scatter of the residuals.  The largest errors on
phantoms are systematic instead: errors of the measured velocity fields that are alike
over the whole image and every frame (optical flow and the interpolated vibrometer
field), which the fit absorbs and the residuals do not show.  The camera (in-plane
velocity by optical flow) and the vibrometer (vertical velocity) measure the same
surface independently, with errors of their own, so the reconstruction each implies
alone is an independent estimate of the same motion (:func:`instrument_fits`: one
Gauss-Newton step from the joint fit on E with the motion term of that instrument only,
gap and ridge kept, the ridge centred on the joint fit).  If each has a systematic error of standard deviation s, their
difference has standard deviation ``sqrt(2) s``; the joint fit is not credited with
averaging the two (the errors need not be independent of the fit's own), so

    s_sys(node, component) = RMS over time of (d_camera - d_vibrometer) / sqrt(2)

is added in quadrature to the posterior standard deviation (:func:`instrument_std`).
With one pair of instruments this is a one-degree-of-freedom estimate: an order of
magnitude, stated as such, not a calibrated interval.

Why the ridge is centred on the joint fit in the single-instrument steps: neither instrument
alone determines the loads as well as both together, so a single-instrument fit leans on the
ridge in the directions the other instrument fixed, and a ridge centred on 0 pulls the two fits
apart there by its own bias (``(H_a^-1 - H_b^-1) Lambda x`` for a linear model), which has
nothing to do with the instruments' errors; the joint fit's own ridge bias is already in the
MSE of :mod:`vfcli.inverse.sandwich`.  Measured on widened phantoms (seeds 300-302, 305-307,
the L-curve's ridge, inferior surface, RMS): with the ridge centred on 0 the two fits disagreed by
0.15-0.40 mm against a joint error of 0.013-0.088 mm; centred on the joint fit, by 0.012-0.054 mm.
Centred on the joint fit, the step is ``x - H_k^-1 (grad E_k(x) - grad ridge(x))``: for a
linear model its disagreement is the instruments' errors through each one's own Hessian, plus
the joint fit's error times ``(H_a^-1 - H_b^-1) Lambda``.  What it cannot see is an instrument's
error in the directions only that instrument determines (there the other one's step stays at the
joint fit): on the forward case of tests/test_uncertainty.py with the vibrometer's velocity 30 %
high, the stated part is 16 % of the motion against an error of 18 % at ridge weight 1e-9, but
4 % against 16 % at 1e-6 (centred on 0 it said 11 %, the ridge's bias, not the error's).

What the load model leaves open: two more splits (optimize method 8)
--------------------------------------------------------------------
The largest error left on widened phantoms is the load model's own: the recorded load is not one of
the model's family (its shape, its mean against its swing), mostly static and shared by both instruments,
so the instruments' split does not see it. Until session 74 the sandwich's expected bias of the pressure
gains' 1e-6 ridge share stood in for it (63-96 % of the inferior surface's stated vertical sd), a figure
that followed the share, not the data; the expected bias now leaves the ridge's device entries out
(:func:`vfcli.inverse.sandwich.prior_part`), and two splits measure what stood in:

* the kinds of data (:func:`data_kind_fits`, :data:`DATA_KINDS`): the velocities alone against the gap
  alone, one centred step each as above. The gap is what fixes the static shape beside the measured
  pressure's gains, so a load whose mean does not follow its swing as the model's does sets the two
  apart. Treated as two independent estimates, as the instruments (``/ sqrt(2)``). The split cannot
  tell which kind is wrong: where the joint fit leans on the right one it states what the other asks
  (tests/test_uncertainty.py: the velocities 30 % high, the fit 24.2 % off, stated 14.4 %; the gap a
  pixel wide, the fit right, stated 22.1 %).
* the load family (:func:`load_family_fit`): one step into the next richer pressure load family
  (:meth:`vfcli.model.loads.pressure.PressureLoad.richer`: a medial shape more in height and along the
  fold, the inferior surface's linear variation) from the joint fit. The richer fit nests the joint one, so
  the difference itself, not over sqrt(2), is how much the reconstruction hangs on the family
  (tests/test_load_family.py: a load outside the family, the fit 7.45 % off, stated 9.42 %).

On eleven kept stores refitted both ways (session 74; docs/benchmarks.md "Session 74: the stated
uncertainty measured") the 90 % intervals covered 82.4-92.9 % of the inferior surface (7 of 11 within
85-95 %) where the stand-in gave 88.8-96.6 % (9 of 11); on 40 fresh widened seeds 75.7-92.9 % (31 of
40; every miss too narrow; by component the horizontal is stated narrow, the vertical still wide).

How much the fit hangs on reading the L-curve's corner (optimize method 9)
--------------------------------------------------------------------------
The ridge weight is read off the L-curve's corner, a maximum of curvature that stands out over about a
decade of weight (:meth:`vfcli.inverse.regularization.LCurve.corner_width`: where the curvature falls to
half the corner's, on each side). Any weight across that width reads the curve as well, and the free
correction of the pressure loads, which carries the load's own time course beside the measured
pressure's, shrinks with the weight: on widened phantoms the inferior surface's lateral oscillation
is what it hangs on (seed 4424: 0.65 of the true amplitude at the corner, 0.75 a decade weaker, 0.87
two decades weaker, while the vertical changes little). :func:`corner_fits` takes one Gauss-Newton step
from the joint fit at each end of the width (the ridge as it is: the fit at that weight, to the gap
term's nonlinearity), and the RMS of the two moves is stated (the difference itself, not over sqrt(2):
the same data, another reading of one choice). It is how much the reconstruction hangs on the corner,
not the whole shrinkage: tests/test_corner_split.py, a free correction the ridge shrinks, the fit 3.06 %
off, the weaker side 2.46 % and the stronger 3.85 %, the split 1.13 %.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.linearization import QuadraticModel, gauss_newton_model
from vfcli.inverse.terms import Evaluation
from vfcli.model.response.base import Linearization, SeparableTerm

#: Motion-term component weights (model x, y, z) of each instrument's own data: the
#: camera's optical flow gives the in-plane velocity, the vibrometer the vertical one.
INSTRUMENTS: dict[str, tuple[float, float, float]] = {"camera": (1.0, 1.0, 0.0), "vibrometer": (0.0, 0.0, 1.0)}

#: The two kinds of data, by the term weights that keep each alone: the measured velocities (both instruments) and
#: the glottal gap's silhouettes.
DATA_KINDS: dict[str, dict] = {"motion": {"gap_weight": 0.0}, "gap": {"motion_weight": 0.0}}


@dataclass(frozen=True)
class ResidualCorrelation:
    """n_residuals : scalar motion residuals.  area_px : correlation area A.  tau_frames : correlation time.
    n_eff : ``n_residuals / (area_px * tau_frames)``."""

    n_residuals: int
    area_px: float
    tau_frames: float
    n_eff: float


def _radial_integral(rho: np.ndarray, max_lag: int) -> float:
    """Sum of a centred 2-D autocorrelation over the disc inside its first zero of the radial mean."""
    cy, cx = (np.array(rho.shape) - 1) // 2
    yy, xx = np.indices(rho.shape)
    r = np.rint(np.hypot(yy - cy, xx - cx)).astype(int)
    radial = np.bincount(r.ravel(), rho.ravel()) / np.maximum(np.bincount(r.ravel()), 1)
    stop = np.flatnonzero(radial[: max_lag + 1] <= 0.0)
    r_max = int(stop[0]) - 1 if stop.size else max_lag
    return float(max(rho[r <= r_max].sum(), 1.0))


def effective_sample_size(residuals: np.ndarray, max_lag_px: int = 64, pixel_stride: int = 1) -> ResidualCorrelation:
    """Independent-residual count of motion residual images.

    Parameters
    ----------
    residuals : (F, H, W, C) residuals (NaN where none), e.g.
        :meth:`vfcli.inverse.problem.Problem.motion_residuals`.
    max_lag_px : largest spatial lag considered, px of the grid the residuals are on.
    pixel_stride : s: the residuals are on every s-th pixel of every s-th row only (a thinned problem,
        ``Measurement.pixel_stride``); the correlation area A is then counted on that grid (A in px / s^2).

    Returns
    -------
    ResidualCorrelation (A >= 1 px, tau >= 1 frame).

    Memory: besides the input, one float64 copy of the values at the pixels valid in some frame and
    its (F, ...) validity; the spatial part runs frame by frame, the correlation time one lag at a
    time as dot products (no (F, H, W, C) temporaries: a 250-frame 384 x 384 px window needed ~4 GB
    of them before).
    """
    from scipy import fft as sfft

    r = np.asarray(residuals, dtype=float)
    if pixel_stride > 1:
        r = r[:, ::pixel_stride, ::pixel_stride]
    f, h, w, ch = r.shape
    lag = min(max_lag_px, h - 1, w - 1)
    # zero-padded to at least (h + lag, w + lag): the circular correlation is then the linear one at every lag
    # up to ``lag`` (the only lags used); scipy's FFT at a fast length, not numpy's at (2h, 2w): 0.36 -> 0.19 s on
    # 40 frames of 160 x 160 px x 3 (scratch ess_cmp.py), equal to round-off
    shape = (sfft.next_fast_len(h + lag, real=True), sfft.next_fast_len(w + lag, real=True))
    # power spectra summed over frames and channels; the inverse transform is linear, so one at the end
    num_spec = np.zeros((shape[0], shape[1] // 2 + 1))
    cnt_spec = np.zeros((shape[0], shape[1] // 2 + 1))
    seen = np.zeros((h, w, ch), bool)
    n_res, ss = 0, 0.0
    for k in range(f):
        valid = np.isfinite(r[k])
        z = np.where(valid, r[k], 0.0)
        n_res += int(valid.sum())
        ss += float(np.vdot(z, z))
        seen |= valid
        fz = sfft.rfft2(z, shape, axes=(0, 1))
        fm = sfft.rfft2(valid.astype(float), shape, axes=(0, 1))
        num_spec += np.sum(fz.real**2 + fz.imag**2, axis=-1)
        cnt_spec += np.sum(fm.real**2 + fm.imag**2, axis=-1)
    if n_res == 0:
        return ResidualCorrelation(0, 1.0, 1.0, 0.0)
    var = ss / n_res
    if var <= 0:
        return ResidualCorrelation(n_res, 1.0, 1.0, float(n_res))
    lags = np.ix_(np.arange(-lag, lag + 1) % shape[0], np.arange(-lag, lag + 1) % shape[1])
    num = sfft.irfft2(num_spec, shape)[lags]
    cnt = sfft.irfft2(cnt_spec, shape)[lags]
    enough = cnt > 0.1 * cnt.max()
    rho = np.where(enough, num / np.maximum(cnt, 1e-12) / var, 0.0)
    area = _radial_integral(rho, lag)

    cols = np.flatnonzero(seen.reshape(-1))
    flat = r.reshape(f, -1)
    valid = np.empty((f, cols.size), bool)
    z = np.empty((f, cols.size))
    for k in range(f):
        z[k] = flat[k, cols]
        valid[k] = np.isfinite(z[k])
        z[k, ~valid[k]] = 0.0
    tau = 1.0
    for k in range(1, f // 2 + 1):
        both = int(np.count_nonzero(valid[k:] & valid[:-k]))
        if both == 0:
            break
        c = float(np.vdot(z[k:].reshape(-1), z[:-k].reshape(-1))) / (both * var)
        if c <= 0:
            break
        tau += 2.0 * c
    return ResidualCorrelation(n_res, area, tau, n_res / (area * tau))


@dataclass(frozen=True)
class Posterior:
    """Laplace posterior of the control values.

    covariance : (n, n) :class:`BlockMatrix` Cov(x), (x units)^2.
    kappa : scale of E as a negative log-likelihood.  dof : effective number of fitted parameters.
    correlation : the residual correlation behind kappa.
    """

    covariance: BlockMatrix
    kappa: float
    dof: float
    correlation: ResidualCorrelation


def _inverse(a: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric PSD block; a singular block gets the pseudo-inverse of its range plus
    a huge variance (1e12 x its largest) along its null space, i.e. 'not determined'."""
    w, v = np.linalg.eigh(0.5 * (a + a.T))
    top = max(float(w.max()), 1e-300)
    inv_w = np.where(w > 1e-12 * top, 1.0 / np.maximum(w, 1e-300), 1e12 / top)
    return (v * inv_w) @ v.T


def posterior(model: QuadraticModel, correlation: ResidualCorrelation) -> Posterior:
    """Cov(x) = (kappa H)^-1 with kappa = (n_eff - dof) / (2 E_motion) (module docstring).

    model : Gauss-Newton model at the optimum (ridge included in ``hessian``).
    correlation : from :func:`effective_sample_size` of the motion residuals at the optimum.
    """
    h, hd = model.hessian, model.data_hessian
    inverses = tuple(_inverse(b) for b in h.blocks)
    dof = float(sum(np.sum(inv * bd.T) for inv, bd in zip(inverses, hd.blocks)))
    e_motion = max(float(model.terms.motion), 1e-300)
    kappa = max(correlation.n_eff - dof, 1.0) / (2.0 * e_motion)
    cov = BlockMatrix(h.n, h.indices, tuple(inv / kappa for inv in inverses))
    return Posterior(cov, kappa, dof, correlation)


def displacement_std(covariance: BlockMatrix, linearization: Linearization) -> np.ndarray:
    """Standard deviation of every vertex displacement component at every time.

    Parameters
    ----------
    covariance : (n, n) Cov(x) with ``x = C.ravel()``, C (S, n_time), (x units)^2.
    linearization : the response's dU/dx at the fit and the simulated times
        (``QuadraticModel.linearization``, :meth:`vfcli.model.response.base.Response.linearize`):
        ``dU(t) = sum_j R_j dC B_j(t)``, R_j (N, 3, S) mm per unit control, B_j (T, n_time).

    Returns
    -------
    (T, N, 3) float64, mm: ``sqrt(diag(J_t Cov J_t^T))`` with ``J_t = sum_j R_j (x) B_j(t)``.
    """
    lin = linearization
    n_t, n_v = lin.n_time, lin.n_vertices
    n_times = lin.terms[0].temporal.shape[0]
    var = np.zeros((n_times, n_v, 3))
    for idx, cov in zip(covariance.indices, covariance.blocks):
        order = np.argsort(idx)                                       # the block in x order: spatial-major
        spatial = idx[order].reshape(-1, n_t)[:, 0] // n_t           # the block's spatial indices
        s = len(spatial)
        c4 = cov[np.ix_(order, order)].reshape(s, n_t, s, n_t)
        rb = [np.ascontiguousarray(t.spatial[:, :, spatial]).reshape(n_v * 3, s) for t in lin.terms]
        for f in range(n_times):
            for j, tj in enumerate(lin.terms):
                for k, tk in enumerate(lin.terms):
                    w = np.einsum("itjb,t,b->ij", c4, tj.temporal[f], tk.temporal[f])   # (s, s) Cov(C b_j, C b_k)
                    var[f] += np.sum((rb[j] @ w) * rb[k], axis=1).reshape(n_v, 3)
    return np.sqrt(np.maximum(var, 0.0))


def relative_uncertainty(std: np.ndarray, displacements: np.ndarray, nodes: np.ndarray) -> float:
    """RMS stated standard deviation over ``nodes`` (all times, components) / RMS displacement there.

    std, displacements : (T, N, 3) mm.  nodes : (N,) bool or index array.
    """
    d = np.asarray(displacements)[:, nodes]
    rms = float(np.sqrt(np.mean(d ** 2)))
    return float(np.sqrt(np.mean(np.asarray(std)[:, nodes] ** 2))) / max(rms, 1e-300)


def centred_steps(problem, x: np.ndarray, weights: dict[str, dict], frames: list | None = None,
                  disp: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Control values part of the data imply on their own, near the joint fit.

    Parameters
    ----------
    problem : :class:`vfcli.inverse.problem.Problem` (with the ridge of the fit).
    x : (n,) the joint fit.
    weights : {name: term weights} (:meth:`~vfcli.inverse.problem.Problem.with_weights`'s keywords) that keep
        each part of the data alone.
    frames, disp : frozen rasters and displacements at x (computed when omitted).

    Returns
    -------
    {name: (n,) control values}: one Gauss-Newton step from x on E with those weights, the ridge (the prior
    terms) centred on x: ``x - H_k^-1 (grad E_k(x) - grad prior(x))`` (module docstring).
    """
    x = np.asarray(x, dtype=float)
    disp = problem.displacements(x) if disp is None else disp
    frames = problem.freeze(x, disp) if frames is None else frames
    prior = prior_gradient(problem, x, frames, disp)
    out = {}
    for name, w in weights.items():
        model = gauss_newton_model(problem.with_weights(**w), x, frames, disp)
        out[name] = x - model.hessian.solve(model.grad - prior)
    return out


def instrument_fits(problem, x: np.ndarray, frames: list | None = None,
                    disp: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Control values each instrument's data imply on their own (:data:`INSTRUMENTS`; :func:`centred_steps`
    with the motion term of that instrument's velocity components only, gap and ridge kept)."""
    return centred_steps(problem, x, {k: {"component_weights": w} for k, w in INSTRUMENTS.items()}, frames, disp)


def data_kind_fits(problem, x: np.ndarray, frames: list | None = None,
                   disp: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Control values each kind of data implies on its own (:data:`DATA_KINDS`; :func:`centred_steps`): the
    measured velocities without the gap term, and the gap term without the velocities."""
    return centred_steps(problem, x, DATA_KINDS, frames, disp)


def load_family_fit(richer, embed: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Control values of the fit under the next richer load family, near the joint fit.

    Parameters
    ----------
    richer : :class:`vfcli.inverse.problem.Problem` on the same data with the richer load model
        (:func:`vfcli.inverse.setup.richer_load_problem`).
    embed : (n,) int, the index in ``richer``'s control values of each of the joint fit's.
    x : (n,) the joint fit.

    Returns
    -------
    (richer.n_params,) one Gauss-Newton step on the richer problem from x embedded (the added shapes at 0),
    the ridge centred there: the added shapes take what the data ask of them, the rest moves with them.
    """
    xr = np.zeros(richer.n_params)
    xr[np.asarray(embed)] = np.asarray(x, dtype=float)
    return centred_steps(richer, xr, {"richer": {}})["richer"]


def prior_gradient(problem, x: np.ndarray, frames: list, disp: np.ndarray) -> np.ndarray:
    """(n,) gradient at ``x`` of E's prior terms (those that are a function of x only: the ridge),
    per unit x; frames, disp : frozen at x."""
    ev = Evaluation(problem, np.asarray(x, dtype=float), disp, frames, np.zeros_like(disp), np.zeros(len(x)))
    for term in problem.terms:
        if not term.data:
            term.value(ev)
    return ev.grad_x


def corner_fits(problem, x: np.ndarray, weights: dict[str, float], frames: list | None = None,
                disp: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Control values of the fit at other ridge weights, near the joint fit (the regularisation split).

    Parameters
    ----------
    problem : :class:`vfcli.inverse.problem.Problem` (with the ridge weight of the fit).
    x : (n,) the joint fit.
    weights : {name: ridge weight, 1/Pa^2}, e.g. the L-curve corner's width
        (:meth:`vfcli.inverse.regularization.LCurve.corner_width`).
    frames, disp : frozen rasters and displacements at x (computed when omitted).

    Returns
    -------
    {name: (n,) control values}: one Gauss-Newton step from x on E with that ridge weight, the ridge as it is
    (centred on 0): where the fit would sit had the corner been read at that weight.
    """
    x = np.asarray(x, dtype=float)
    disp = problem.displacements(x) if disp is None else disp
    frames = problem.freeze(x, disp) if frames is None else frames
    out = {}
    for name, w in weights.items():
        model = gauss_newton_model(problem.with_weights(ridge_weight=float(w)), x, frames, disp)
        out[name] = x - model.hessian.solve(model.grad)
    return out


def instrument_std(displacements: dict[str, np.ndarray], independent: bool = True) -> np.ndarray:
    """Systematic standard deviation from two reconstructions (module docstring).

    displacements : {name: (T, N, 3)} the displacements of two fits (:func:`instrument_fits`,
        :func:`data_kind_fits`), mm.
    independent : the two are independent estimates with errors alike (two instruments, two kinds of data):
        each is stated the difference over sqrt(2); False: the second is a nested richer model's fit
        (:func:`load_family_fit`), and the difference itself is what the first hangs on the model.

    Returns
    -------
    (N, 3) ``RMS_t |d_a - d_b| / sqrt(2)`` (``independent``), else ``RMS_t |d_a - d_b|``, mm.
    """
    if len(displacements) != 2:
        raise ValueError(f"two reconstructions are compared, got {len(displacements)}")
    a, b = (np.asarray(d, dtype=float) for d in displacements.values())
    return np.sqrt(np.mean((a - b) ** 2, axis=0) / (2.0 if independent else 1.0))


def instrument_split(displacements: dict[str, np.ndarray], independent: bool = True
                     ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`instrument_std` split into the static and the oscillating part over the window.

    displacements : {name: (T + 1, N, 3)} the two reconstructions at the simulated
        times (the last one, past the window, is left out), mm.
    independent : as :func:`instrument_std` (False: no division by sqrt(2)).

    Returns
    -------
    static : (N, 3) ``|mean_t (d_a - d_b)| / sqrt(2)``, mm.
    oscillating : (N, 3) ``RMS_t of (d_a - d_b) minus its mean, / sqrt(2)``, mm.
    """
    if len(displacements) != 2:
        raise ValueError(f"two reconstructions are compared, got {len(displacements)}")
    a, b = (np.asarray(d, dtype=float)[:-1] for d in displacements.values())
    diff = a - b
    mean = diff.mean(axis=0)
    scale = np.sqrt(2.0) if independent else 1.0
    return np.abs(mean) / scale, np.sqrt(np.mean((diff - mean) ** 2, axis=0)) / scale


def window_mean(linearization: Linearization) -> Linearization:
    """The linearisation of the static part: the mean over the window's T frames of dU
    (the simulated times but the last, which lies past the window); one time row."""
    return Linearization(tuple(SeparableTerm(t.spatial, t.temporal[:-1].mean(axis=0, keepdims=True))
                               for t in linearization.terms))


def window_oscillation(linearization: Linearization) -> Linearization:
    """The linearisation of the oscillating part: dU(t) minus its mean over the window (all
    simulated times, the mean taken over the window's T frames)."""
    return Linearization(tuple(SeparableTerm(t.spatial, t.temporal - t.temporal[:-1].mean(axis=0, keepdims=True))
                               for t in linearization.terms))
