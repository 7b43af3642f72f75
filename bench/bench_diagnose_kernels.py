"""## The kernels session 15 rewrote, each against the code it replaced, timed in the same run on the same data.

1. **Region means** (:func:`vfcli.diagnose.residual.region_means`, diagnose's locate step): one sparse
   (R, P) region indicator times the pixel columns, against the stacked dense ``(F, C, P) @ (P, R)``
   it replaced; 100 frames of 160 x 160 px, 3 components, 18 regions, 30 % NaN.
2. **Gauss-Newton motion blocks** (:func:`vfcli.inverse.terms.motion.motion_blocks`): every (j, k) block
   of J linearisation terms from one product of the terms' columns side by side, against the former
   per-pair ``motion_block`` (J^2 sparse-dense products); 1500 seen vertices, S = 20, J = 14 (inertia's
   steady-state response) and J = 1 (the quasi-static response of optimize).
3. **Shifted LU** (:func:`vfcli.model.response.modal.shifted_ritz_vectors`): SuperLU of
   ``K - (2 pi 240 Hz)^2 M`` of one fold of the 1.5 mm mesh with a symmetric ordering
   (MMD_AT_PLUS_A, diagonal pivots preferred down to a tenth) against SciPy's default (COLAMD).

Session 34's, the same way:

4. **Calibration replicates** (``vfcli.diagnose.calibrate._replicate_chunk``): the covariances and
   studentized statistics of a chunk of 64 replicates in one batched eigendecomposition per candidate,
   against the former replicate-by-replicate loop (:func:`replicate_chunk_loop`, one ``eigh`` per
   candidate and replicate); five candidates (p = 3, 1, 2, 1, 1), a pool of 10 stretches, 40 model-error bins.
5. **Shifted Ritz vectors of both folds** (:func:`vfcli.model.response.modal.shifted_ritz_vectors`):
   fold 0 solved with fold 1's factors when it is fold 1's mirror image, against the same function on
   the same model built with ``reuse_mirror=False`` (one factorisation per fold); 1.5 mm mesh, 7 loads.

Each pair is checked to agree before it is timed. BLAS threads matter on a busy machine: run it both
ways, e.g. ``OPENBLAS_NUM_THREADS=1`` (what ``make test`` sets) and unset.

Reproduce::

    .venv/bin/python bench/bench_diagnose_kernels.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

from _forward_case import elastic_model  # noqa: E402
from _runner import best  # noqa: E402
from vfcli.diagnose import calibrate  # noqa: E402
from vfcli.diagnose.residual import region_means  # noqa: E402
from vfcli.model.fem import ElasticModel  # noqa: E402
from vfcli.model.response.modal import shifted_ritz_vectors  # noqa: E402
from vfcli.inverse.terms.motion import motion_blocks, seen_vertex_gram  # noqa: E402


def region_means_dense(values: np.ndarray, labels: np.ndarray, n_regions: int) -> np.ndarray:
    """The former region means (session 14): a stacked dense product with a one-hot matrix."""
    v = np.asarray(values, dtype=float)
    f, c = v.shape[0], v.shape[-1]
    flat = v.reshape(f, -1, c)
    lab = np.asarray(labels).reshape(-1)
    keep = lab >= 0
    flat, lab = flat[:, keep], lab[keep]
    ok = np.isfinite(flat)
    onehot = np.zeros((lab.size, n_regions))
    onehot[np.arange(lab.size), lab] = 1.0
    sums = np.moveaxis(np.moveaxis(np.where(ok, flat, 0.0), 2, 1) @ onehot, 1, 2)
    counts = np.moveaxis(np.moveaxis(ok.astype(float), 2, 1) @ onehot, 1, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / counts, np.nan)


def motion_block_pairwise(seen, gram, bases, weights=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The former per-pair blocks (session 14): ``sum_c w_c R_j,c^T K R_k,c`` one pair at a time."""
    n_terms, n_s = len(bases), bases[0].shape[2]
    out = np.zeros((n_terms, n_terms, n_s, n_s))
    for j in range(n_terms):
        for k in range(n_terms):
            for c in range(3):
                r, q = bases[j][seen, c, :], bases[k][seen, c, :]
                out[j, k] += weights[c] * (r.T @ (gram @ q))
    return out


def replicate_chunk_loop(parts, sizes, identifiable, seed, n, one_sided=()) -> np.ndarray:
    """The former replicate chunk (sessions 19-33): covariances and statistics one replicate at a time."""
    rng = np.random.default_rng(seed)
    k = parts.n_pool
    d = parts.noise / np.sqrt(k - 1)
    q = parts.model_error
    out = np.zeros((len(sizes), n))
    for b in range(n):
        g = rng.standard_normal((k + 1, k))
        draws = g @ d
        u = draws[0]
        covs = calibrate.noise_covariances(draws[1:], sizes, centred=True)
        if len(q):
            u = u + rng.standard_normal(len(q)) @ q
            est = calibrate.model_error_covariances(q, sizes, rng.standard_normal(len(q)) ** 2)
            covs = [a + e for a, e in zip(covs, est)]
        out[:, b] = calibrate.studentized(u, covs, identifiable, one_sided)
    return out


def bench_replicates() -> tuple[float, float]:
    rng = np.random.default_rng(3)
    sizes, sided = (3, 1, 2, 1, 1), (False, True, False, True, True)
    parts = calibrate.NullParts(rng.normal(size=(10, 8)), 0.3 * rng.normal(size=(40, 8)))
    args = (parts, sizes, (True,) * 5, 11, calibrate.CHUNK, sided)
    a, b = replicate_chunk_loop(*args), calibrate._replicate_chunk(*args)
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()
    return best(lambda: replicate_chunk_loop(*args), 3), best(lambda: calibrate._replicate_chunk(*args), 3)


def bench_mirrored_ritz(edge_mm: float = 1.5) -> tuple[float, float]:
    mirrored = elastic_model(edge_mm)
    both = ElasticModel(mirrored.mesh, reuse_mirror=False)
    assert mirrored.is_mirrored and not both.is_mirrored
    loads = np.random.default_rng(4).normal(size=(mirrored.n_dofs, 7))
    loads[mirrored.fixed_dofs] = 0.0
    a, b = shifted_ritz_vectors(both, loads, 240.0), shifted_ritz_vectors(mirrored, loads, 240.0)
    assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()
    return best(lambda: shifted_ritz_vectors(both, loads, 240.0), 2), \
        best(lambda: shifted_ritz_vectors(mirrored, loads, 240.0), 2)


def bench_region_means() -> tuple[float, float]:
    rng = np.random.default_rng(0)
    v = rng.normal(size=(100, 160, 160, 3))
    v[rng.random(v.shape) < 0.3] = np.nan
    lab = rng.integers(-1, 18, size=(160, 160))
    a, b = region_means_dense(v, lab, 18), region_means(v, lab, 18)
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.nanmax(np.abs(a - b)) < 1e-12
    return best(lambda: region_means_dense(v, lab, 18), 3), best(lambda: region_means(v, lab, 18), 3)


def bench_motion_blocks(n_terms: int, n_s: int = 20) -> tuple[float, float]:
    rng = np.random.default_rng(1)
    n_vert, n_pix = 6000, 4000
    rows = np.repeat(np.arange(n_pix), 3)
    m = sp.csr_matrix((rng.random(rows.size), (rows, rng.integers(0, 1500, rows.size))), shape=(n_pix, n_vert))
    bases = [rng.normal(size=(n_vert, 3, n_s)) for _ in range(n_terms)]
    seen, gram = seen_vertex_gram(m)
    a, b = motion_block_pairwise(seen, gram, bases), motion_blocks(seen, gram, bases)
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()
    return best(lambda: motion_block_pairwise(seen, gram, bases), 3), best(lambda: motion_blocks(seen, gram, bases), 3)


def bench_shifted_lu(edge_mm: float = 1.5) -> tuple[float, float, int]:
    model = elastic_model(edge_mm)
    fold = model.folds[1]
    idx = model.offsets[1] + fold.free
    a = (fold.stiffness[fold.free][:, fold.free] - (2 * np.pi * 240.0) ** 2 * model.mass[idx][:, idx]).tocsc()
    b = np.random.default_rng(2).normal(size=(a.shape[0], 7))
    sym = dict(permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1, options={"SymmetricMode": True})
    for kw in ({}, sym):
        x = splu(a, **kw).solve(b)
        assert np.abs(a @ x - b).max() < 1e-8 * np.abs(b).max()
    return best(lambda: splu(a), 2), best(lambda: splu(a, **sym), 2), a.shape[0]


def main() -> None:
    old, new = bench_region_means()
    print(f"region means, 100 frames of 160 x 160 px: dense {old:.3f} s, sparse {new:.3f} s: {old / new:.1f}x")
    for n_terms in (14, 1):
        old, new = bench_motion_blocks(n_terms)
        print(f"motion blocks, J = {n_terms:2d}, S = 20, 1500 seen vertices: per pair {1e3 * old:.1f} ms, "
              f"side by side {1e3 * new:.1f} ms: {old / new:.1f}x")
    old, new, n = bench_shifted_lu()
    print(f"shifted LU, one fold of the 1.5 mm mesh ({n} free DOFs): COLAMD {old:.2f} s, symmetric {new:.2f} s: "
          f"{old / new:.1f}x")
    old, new = bench_replicates()
    print(f"calibration replicates, a chunk of {calibrate.CHUNK}: one by one {1e3 * old:.1f} ms, batched "
          f"{1e3 * new:.1f} ms: {old / new:.1f}x")
    old, new = bench_mirrored_ritz()
    print(f"shifted Ritz vectors of both folds (1.5 mm mesh): a factorisation per fold {old:.2f} s, fold 1's "
          f"mirrored for fold 0 {new:.2f} s: {old / new:.1f}x")


if __name__ == "__main__":
    main()
