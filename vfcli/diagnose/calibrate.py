"""Calibrated screening: the null distribution of every candidate's score statistic by parametric
bootstrap from the fitted baseline, and family-wise p-values over all candidates (Westfall-Young).

The chi2 reference of the score test (:mod:`vfcli.diagnose.candidates.screening`) assumes white
noise of the estimated scale.  The residual of a real fit is not that: it holds noise that is
correlated within a glottal cycle (optics, flow, the vibrometer's phase average) and a periodic
model error (load shape, mesh, optics) that repeats in every cycle.  Here the reference is
rebuilt from the recording itself.

**The statistic.**  For candidate c with efficient score directions ``W_c`` (m, p_c): the candidate's
Jacobian columns with the part the loads can make removed (``A_c = J_c - J_L H_LL^-1 H_Lc``, the
Gauss-Newton blocks of the objective, ridge included) and multiplied by the objective's row weights.
Its score on a residual r is ``U_c = W_c^T r`` and its statistic ``T_c = U_c^T I_c^+ U_c`` with
``I_c = A_c^T Omega A_c``.  Because ``A_c`` is orthogonal to every load column in the objective's
metric, ``U_c(r)`` is the score after refitting the loads to r by one (exact, linear) Gauss-Newton
step: a replicate's "refit" is the projection, and costs one inner product.

**The null replicates** ``r* = e* + m*``:

* ``e*``, the noise: the window's rows are grouped by the whole glottal cycle they fall in; each
  group takes the deviation from the periodic template (the mean over cycles at the same phase)
  of a cycle drawn with replacement from the recording's other whole cycles, with a random sign
  (Rademacher; noise symmetric about the template).  Correlation within a cycle, in space and
  time, is kept; cycles are independent.
* ``m*``, the periodic model error no candidate explains: the window's systematic residual
  ``s = r - e_window`` (the residual minus the window's own deviation from the template: what repeats
  in every cycle) with its least-squares projection on all candidates' directions removed
  (``s_perp``), then moved in time by a random whole number of frames (cyclically over the window)
  and given a random sign.  The shift keeps its size and its correlation in space and time, and
  makes its alignment with the candidates' signatures random: a model error leans on a candidate's
  columns in the null as much as a model error of that size and texture does when it sits anywhere
  in the cycle.  A candidate's own signature is the part of s the candidates explain, which the
  null does not contain: it stays detectable when it stands above the noise and above that lean.

**One-sided terms**: a candidate whose single parameter is physically one-signed (a retardation time, a
contact share: ``one_sided``) counts only evidence for a positive value, the one-sided score test
(Silvapulle and Sen 2005, ch. 4): its statistic is ``T_c`` when the one-step estimate ``I_c^-1 U_c`` is
positive and 0 otherwise, in the observed statistic and in every replicate alike.  A model error
leaning the wrong way is then no lead, and the test keeps its level (the null's atom at 0 gives p = 1).

**Family-wise**: single-step min-p (Westfall and Young 1993).  Per replicate, each candidate's
p-value against its own replicate distribution; the minimum over candidates; a candidate's adjusted
p-value is the share of replicates whose minimum is at most its own p-value.  The replicates keep
the candidates' joint dependence (one residual feeds all of them).

Everything here is numpy in, numpy out; :mod:`vfcli.diagnose.calibrate_run` builds the arrays
from a fitted run and its recording.
"""
from __future__ import annotations

import builtins
from dataclasses import dataclass
from functools import partial
from typing import Callable, Sequence

import numpy as np

#: replicates of the bootstrap when the config does not say
DEFAULT_REPLICATES = 199
#: eigenvalues of I_c below this share of its largest are not information
INFO_RTOL = 1e-10
#: replicates computed per task handed to the injected map
CHUNK = 64


@dataclass(frozen=True)
class ScoreBasis:
    """The candidates' efficient score directions on the rows of a residual.

    weights : per candidate, (m, p_c) ``Omega A_c``: the score on a residual r is ``weights[c].T @ r``.
    information : per candidate, (p_c, p_c) ``I_c = A_c^T Omega A_c`` (per unit parameter^2).
    identifiable : per candidate, False when the loads absorb it (its statistic is then 0, p = 1).
    one_sided : per candidate, True when only a positive parameter is physical (one parameter; module
        docstring); default: none.
    """

    weights: Sequence[np.ndarray]
    information: Sequence[np.ndarray]
    identifiable: Sequence[bool]
    one_sided: Sequence[bool] = ()

    @property
    def sizes(self) -> list[int]:
        """p_c of each candidate."""
        return [w.shape[1] for w in self.weights]

    def scores(self, r: np.ndarray) -> np.ndarray:
        """(sum p_c,) or (sum p_c, B): every candidate's score on r (m,) or (m, B), stacked."""
        return np.concatenate([w.T @ r for w in self.weights], axis=0)

    def statistics(self, u: np.ndarray) -> np.ndarray:
        """(C,) or (C, B) statistics ``U_c^T I_c^+ U_c`` from stacked scores u (sum p_c,) or (sum p_c, B)."""
        return statistics(u, self.information, self.identifiable, self.one_sided)


def pseudo_inverse(info: np.ndarray, rtol: float = INFO_RTOL) -> np.ndarray:
    """(p, p) the pseudo-inverse of a symmetric positive semi-definite matrix (eigenvalues below rtol of the top dropped)."""
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    keep = _kept(w, rtol)
    return (v[:, keep] / w[keep]) @ v[:, keep].T


def _kept(w: np.ndarray, rtol: float = INFO_RTOL) -> np.ndarray:
    """(..., p) bool: the eigenvalues w (..., p) the pseudo-inverse keeps (above rtol of their matrix's largest)."""
    top = np.maximum(w.max(axis=-1, initial=0.0), 1e-300)
    return w > rtol * top[..., None]


def statistics(u: np.ndarray, information: Sequence[np.ndarray], identifiable: Sequence[bool],
               one_sided: Sequence[bool] = ()) -> np.ndarray:
    """(C,) or (C, B) ``U_c^T I_c^+ U_c`` of stacked scores u (sum p_c,) or (sum p_c, B); 0 where not identifiable,
    and for a ``one_sided`` candidate (one parameter) 0 where its score, the sign of its one-step estimate, is <= 0."""
    u = np.asarray(u, dtype=float)
    out = np.zeros((len(information),) + u.shape[1:])
    sided = tuple(one_sided) + (False,) * (len(information) - len(one_sided))
    at = 0
    for c, (info, ok) in enumerate(zip(information, identifiable)):
        p = info.shape[0]
        uc = u[at:at + p]
        at += p
        if ok:
            out[c] = np.einsum("i...,ij,j...->...", uc, pseudo_inverse(info), uc)
            if sided[c]:
                if p != 1:
                    raise ValueError(f"a one-sided candidate has one parameter, candidate {c} has {p}")
                out[c] = np.where(uc[0] > 0, out[c], 0.0)
    return out


def quadrature_scores(s_frames: np.ndarray, w_frames: Sequence[np.ndarray], dc: bool = True) -> np.ndarray:
    """(J, sum p_c) per frequency bin j of the window, the candidates' scores on the quadrature part of s.

    s_frames : (F, R) the systematic residual as frames x rows-of-a-frame (0 where a row is not compared).
    w_frames : per candidate (F, R, p_c) its score weights laid out the same way.
    With X_j, W_j the real FFTs over frames, bin j contributes ``c_j Re(X_j conj W_j)`` to the score of s
    (c_j = 2 / F, 1 / F at 0 and at the Nyquist bin) and ``c_j Im(X_j conj W_j)`` to the score of its
    quadrature (each harmonic turned by a quarter period).  For a model error stationary in time the two
    have the same distribution, and a candidate's own signature has no quadrature part on its own
    columns: the quadrature scores estimate the model error's lean without the candidate's effect.
    The zero-frequency bin has no quadrature: with ``dc`` its in-phase score is used (a constant
    model error and a constant effect cannot be told apart).
    """
    f = s_frames.shape[0]
    x = np.fft.rfft(s_frames, axis=0)                                    # (J, R)
    scale = np.full(x.shape[0], 2.0 / f)
    scale[0] = 1.0 / f
    if f % 2 == 0:
        scale[-1] = 1.0 / f
    out = []
    for w in w_frames:
        wf = np.fft.rfft(w, axis=0)                                      # (J, R, p)
        q = np.einsum("jr,jrp->jp", x, np.conj(wf))
        col = scale[:, None] * q.imag
        col[0] = scale[0] * q[0].real if dc else 0.0
        out.append(col)
    return np.concatenate(out, axis=1)


def project_out_candidates(basis: ScoreBasis, columns: Sequence[np.ndarray], s: np.ndarray) -> np.ndarray:
    """(m,) s minus its weighted least-squares fit by all candidates' efficient columns together.

    columns : per candidate, (m, p_c) the efficient columns ``A_c`` (unweighted); ``basis.weights`` are
    ``Omega A_c``.  The result has zero score on every candidate: the model error no candidate explains.
    """
    a = np.concatenate(list(columns), axis=1)
    wa = np.concatenate(list(basis.weights), axis=1)
    gram = wa.T @ a
    return s - a @ (pseudo_inverse(gram) @ (wa.T @ s))


@dataclass(frozen=True)
class NullParts:
    """The precomputed scores the replicates are built from (module docstring).

    noise : (K, sum p_c) scores of the K pool stretches' deviations from the periodic template
        (each stretch: the window moved by a whole number of cycles); their covariance over the K
        stretches (K - 1 degrees of freedom) is the noise covariance of the window's scores.
    model_error : (J, sum p_c) the quadrature scores of the systematic residual, one row per frequency bin
        of the window (:func:`quadrature_scores`); a replicate's model error is their sum with independent
        standard normal weights.
    """

    noise: np.ndarray
    model_error: np.ndarray

    @property
    def n_pool(self) -> int:
        return int(self.noise.shape[0])


def noise_covariances(u: np.ndarray, sizes: Sequence[int], centred: bool = False) -> list[np.ndarray]:
    """Per candidate, (p_c, p_c) covariance over the rows of u (K, sum p_c), K - 1 degrees of freedom.

    u : deviations from the template (their mean is already removed: ``centred=False``) or draws
    (``centred=True``: their own mean is removed first).
    """
    u = np.asarray(u, dtype=float)
    if centred:
        u = u - u.mean(axis=0)
    k = max(u.shape[0] - 1, 1)
    out, at = [], 0
    for p in sizes:
        out.append(u[:, at:at + p].T @ u[:, at:at + p] / k)
        at += p
    return out


def studentized(u: np.ndarray, covs: Sequence[np.ndarray], identifiable: Sequence[bool],
                one_sided: Sequence[bool] = ()) -> np.ndarray:
    """(C,) ``U_c^T S_c^+ U_c`` of stacked scores u (sum p_c,) with per-candidate covariances S_c; 0 where not
    identifiable or, for a ``one_sided`` candidate, where its score is <= 0."""
    return statistics(u, covs, identifiable, one_sided)


def model_error_covariances(q: np.ndarray, sizes: Sequence[int], weights: np.ndarray | None = None) -> list[np.ndarray]:
    """Per candidate, (p_c, p_c) ``sum_j w_j Q_j Q_j^T`` over the quadrature scores q (J, sum p_c) (w = 1: the
    estimate of the model error's score covariance)."""
    q = np.asarray(q, dtype=float)
    w = np.ones(q.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    out, at = [], 0
    for p in sizes:
        out.append((q[:, at:at + p] * w[:, None]).T @ q[:, at:at + p])
        at += p
    return out


def _batched_statistics(u: np.ndarray, covs: Sequence[np.ndarray], identifiable: Sequence[bool],
                        one_sided: Sequence[bool] = ()) -> np.ndarray:
    """(C, n) ``U_c^T S_c^+ U_c`` of n stacked scores u (n, sum p_c) with per-candidate covariances
    covs[c] (n, p_c, p_c): :func:`statistics` of each row with its own covariances, in one batched
    eigendecomposition per candidate (the pseudo-inverse's eigenvalue cut of :func:`pseudo_inverse`)."""
    sided = tuple(one_sided) + (False,) * (len(covs) - len(one_sided))
    out = np.zeros((len(covs), u.shape[0]))
    at = 0
    for c, (cov, ok) in enumerate(zip(covs, identifiable)):
        p = cov.shape[1]
        uc = u[:, at:at + p]
        at += p
        if not ok:
            continue
        if sided[c] and p != 1:
            raise ValueError(f"a one-sided candidate has one parameter, candidate {c} has {p}")
        w, v = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))                 # (n, p), (n, p, p)
        keep = _kept(w)
        proj = np.einsum("nij,ni->nj", v, uc)                                          # V^T u
        out[c] = np.sum(np.where(keep, proj ** 2 / np.where(keep, w, 1.0), 0.0), axis=1)
        if sided[c]:
            out[c] = np.where(uc[:, 0] > 0, out[c], 0.0)
    return out


def _replicate_chunk(parts: NullParts, sizes: tuple[int, ...], identifiable: tuple[bool, ...], seed: int,
                     n: int, one_sided: tuple[bool, ...] = ()) -> np.ndarray:
    """(C, n) studentized statistics of n replicates drawn with ``seed`` (module docstring).

    The draws are made replicate by replicate (the random stream is the same whatever the chunking
    of the linear algebra); the covariances and statistics of the n replicates are then computed at once.
    """
    rng = np.random.default_rng(seed)
    k = parts.n_pool
    d = parts.noise / np.sqrt(k - 1)                 # rows: d^T d = the pool's covariance
    q = parts.model_error
    u = np.empty((n, d.shape[1]))
    pool = np.empty((n, k, d.shape[1]))
    weights = np.empty((n, len(q)))
    for b in range(n):
        g = rng.standard_normal((k + 1, k))
        draws = g @ d                                # (K + 1, sum p): the window's noise and K pool stretches
        u[b], pool[b] = draws[0], draws[1:]
        if len(q):
            u[b] += rng.standard_normal(len(q)) @ q  # the model error's in-phase lean, bin by bin
            weights[b] = rng.standard_normal(len(q)) ** 2   # its fresh estimate's weights
    pool -= pool.mean(axis=1, keepdims=True)
    covs, at = [], 0
    for p in sizes:
        dc = pool[:, :, at:at + p]
        cov = np.einsum("nki,nkj->nij", dc, dc) / max(k - 1, 1)
        if len(q):
            qc = q[:, at:at + p]
            cov = cov + np.einsum("nj,ji,jk->nik", weights, qc, qc)
        covs.append(cov)
        at += p
    return _batched_statistics(u, covs, identifiable, one_sided)


def _replicate_item(parts: NullParts, sizes: tuple[int, ...], identifiable: tuple[bool, ...],
                    one_sided: tuple[bool, ...], item: tuple[int, int]) -> np.ndarray:
    """:func:`_replicate_chunk` of one ``(seed, n)`` item (the :class:`vfcli.parallel.Mapper` contract:
    one item per call)."""
    return _replicate_chunk(parts, sizes, identifiable, *item, one_sided=one_sided)


def replicate_statistics(parts: NullParts, sizes: Sequence[int], identifiable: Sequence[bool], n_replicates: int,
                         seed: int, map: Callable = builtins.map, one_sided: Sequence[bool] = ()) -> np.ndarray:
    """(C, B) studentized statistics of B null replicates, reproducible for a seed (``one_sided``: as
    :func:`statistics`).

    Each replicate draws the window's noise and K fresh pool stretches from the Gaussian with the
    pool's score covariance (so the replicate's own covariance estimate has the observed one's K - 1
    degrees of freedom), adds a randomly shifted, randomly signed model error, and studentizes.
    The replicates are drawn in chunks of :data:`CHUNK`, each with its own seed spawned from ``seed``
    (:class:`numpy.random.SeedSequence`), handed to ``map`` as ``(seed, n)`` items (a
    :class:`vfcli.parallel.Mapper`: builtin ``map`` by default; any map that applies the function to
    the items gives the same numbers).
    """
    if parts.n_pool < 2:
        raise ValueError(f"the noise needs at least 2 pool stretches, got {parts.n_pool}")
    counts = [min(CHUNK, n_replicates - i) for i in range(0, n_replicates, CHUNK)]
    seeds = [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(len(counts))]
    fn = partial(_replicate_item, parts, tuple(sizes), tuple(bool(i) for i in identifiable),
                 tuple(bool(o) for o in one_sided))
    chunks = list(map(fn, list(zip(seeds, counts))))
    return np.concatenate(chunks, axis=1) if chunks else np.zeros((len(sizes), 0))


@dataclass(frozen=True)
class Calibration:
    """The calibrated screening of all candidates.

    statistic : (C,) observed statistics.  p_value : (C,) bootstrap p-value of each candidate alone.
    p_family : (C,) family-wise (Westfall-Young min-p) adjusted p-values.
    null_statistics : (C, B) the replicates' statistics.  n_replicates : B.  seed : the bootstrap's seed.
    n_pool_cycles : whole cycles the noise was resampled from.  n_shifts : time shifts of the model error.
    covariances : per candidate, (p_c, p_c) the covariance the observed scores are studentized by (noise and
        model error).
    """

    statistic: np.ndarray
    p_value: np.ndarray
    p_family: np.ndarray
    null_statistics: np.ndarray
    n_replicates: int
    seed: int
    n_pool_cycles: int
    n_shifts: int
    covariances: tuple = ()


def bootstrap_p_values(observed: np.ndarray, null: np.ndarray) -> np.ndarray:
    """(C,) ``(1 + #{T*_c >= T_c}) / (B + 1)`` for observed (C,) and null (C, B) statistics."""
    b = null.shape[1]
    return (1.0 + np.sum(null >= observed[:, None], axis=1)) / (b + 1.0)


def westfall_young(observed: np.ndarray, null: np.ndarray) -> np.ndarray:
    """(C,) single-step min-p adjusted p-values (module docstring) for observed (C,) and null (C, B)."""
    b = null.shape[1]
    if b == 0:
        return np.ones(len(observed))
    # each replicate's p-value against its candidate's null distribution: (1 + #{T*_b' >= T*_b}) / (B + 1)
    srt = -np.sort(-null, axis=1)
    ge = np.stack([np.searchsorted(-srt[c], -null[c], side="right") for c in range(len(null))])
    p_null = (1.0 + ge) / (b + 1.0)                  # counts include the replicate itself, as the observed's would
    min_p = p_null.min(axis=0)                       # (B,)
    p_obs = bootstrap_p_values(observed, null)
    return (1.0 + np.sum(min_p[None, :] <= p_obs[:, None], axis=1)) / (b + 1.0)


def detection_thresholds(null: np.ndarray, alpha: float) -> np.ndarray:
    """(C,) per candidate the statistic its family-wise p-value (:func:`westfall_young` against ``null`` (C, B))
    falls to ``alpha`` above (an observed statistic larger than it is a lead); inf where no statistic does.

    The adjusted p-value of a statistic T is ``(1 + #{b: min_p_b <= p_c(T)}) / (B + 1)`` with
    ``p_c(T) = (1 + k) / (B + 1)``, k the replicates of c at or above T: it is at most alpha for the largest
    k whose p_c still lets at most ``alpha (B + 1) - 1`` replicates' min-p below it, and T must then exceed
    the (k + 1)-th largest replicate of c."""
    null = np.asarray(null, dtype=float)
    c_n, b = null.shape
    out = np.full(c_n, np.inf)
    if b == 0:
        return out
    srt = -np.sort(-null, axis=1)
    ge = np.stack([np.searchsorted(-srt[c], -null[c], side="right") for c in range(c_n)])
    min_p = np.sort(((1.0 + ge) / (b + 1.0)).min(axis=0))
    k = np.arange(b)
    family = (1.0 + np.searchsorted(min_p, (1.0 + k) / (b + 1.0), side="right")) / (b + 1.0)   # (B,) at k
    ok = np.flatnonzero(family <= alpha + 1e-12)
    if ok.size:
        out[:] = srt[:, int(ok.max())]
    return out


def smallest_detectable(cal: Calibration, information: Sequence[np.ndarray], alpha: float) -> np.ndarray:
    """(C,) the smallest size of each one-parameter candidate the calibrated screening names at family-wise
    ``alpha`` about half the time, in the candidate's units; NaN for a candidate of several parameters or
    without information, inf where no statistic is a lead.

    In the linearised model a candidate present at theta adds ``I_c theta`` to its score (``A_c`` is the
    effect's column after the loads' refit), so its studentized statistic gains ``I_c^2 theta^2 / S_c``
    (S_c: :attr:`Calibration.covariances`): it crosses the threshold T* (:func:`detection_thresholds`) at
    ``theta = sqrt(T* S_c) / I_c``, the one-step estimate's calibrated sd times sqrt(T*)."""
    t = detection_thresholds(cal.null_statistics, alpha)
    out = np.full(len(information), np.nan)
    for c, info in enumerate(information):
        info = np.asarray(info, float)
        if info.shape != (1, 1) or not info[0, 0] > 0 or c >= len(cal.covariances):
            continue
        out[c] = np.sqrt(t[c] * float(np.asarray(cal.covariances[c])[0, 0])) / info[0, 0]
    return out


def calibrate(basis: ScoreBasis, residual: np.ndarray, parts: NullParts, n_replicates: int = DEFAULT_REPLICATES,
              seed: int = 0, map: Callable = builtins.map) -> Calibration:
    """Calibrated p-values of every candidate on ``residual`` (m,) against the null replicates (module docstring).

    The observed statistic is studentized by the pool's score covariance (:func:`noise_covariances`).
    """
    if n_replicates < 1:
        raise ValueError(f"n_replicates must be >= 1, got {n_replicates}")
    u = basis.scores(np.asarray(residual, dtype=float))
    covs = noise_covariances(parts.noise, basis.sizes)
    if len(parts.model_error):
        covs = [a + e for a, e in zip(covs, model_error_covariances(parts.model_error, basis.sizes))]
    observed = studentized(u, covs, basis.identifiable, basis.one_sided)
    null = replicate_statistics(parts, basis.sizes, basis.identifiable, n_replicates, seed, map, basis.one_sided)
    return Calibration(observed, bootstrap_p_values(observed, null), westfall_young(observed, null), null,
                       int(n_replicates), int(seed), parts.n_pool, int(len(parts.model_error)), tuple(covs))
