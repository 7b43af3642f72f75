"""## The steady state's transfers: one product for every harmonic against two per harmonic (session 73).

:func:`vfcli.model.response.steady_state.change_transfers` forms ``[H(rho, tau, eta) - H(0, 0, eta)] L`` at every
harmonic of f0 from a modal reduction in one product with its vertex modes; the baseline, in the same run, is
the form it replaced: per harmonic, one product for the real and one for the imaginary part.  The reduction has the
size of the complete expansion of a run's 2.5 mm mesh (6960 modes, 438 surface vertices, 7 load patterns; random
modes: the product's cost does not depend on their values).  Prints the time of each (best of ``--repeats``), their
ratio and the largest difference (0: the same numbers).

Reproduce::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_steady_state.py [--repeats 5]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from vfcli.model.response.modal import ModalReduction
from vfcli.model.response.steady_state import change_transfers


def reduction_of_size(n_modes: int, n_vertices: int, n_loads: int, seed: int = 0) -> ModalReduction:
    """A ModalReduction with random modes, positive eigenvalues and modal loads of the given sizes."""
    rng = np.random.default_rng(seed)
    red = ModalReduction.__new__(ModalReduction)
    red.eigenvalues_ = np.sort(rng.uniform(1e5, 1e10, n_modes))
    red.vertex_modes_ = rng.normal(size=(n_modes, n_vertices, 3))
    red.modal_loads_ = rng.normal(size=(n_modes, n_loads))
    return red


def per_harmonic(red: ModalReduction, omegas: np.ndarray, density: float, tau: float, loss: float) -> np.ndarray:
    """The baseline: per frequency, the real and the imaginary part each in a product of their own."""
    flat = red.vertex_modes_.reshape(len(red.vertex_modes_), -1).T
    out = []
    for w in omegas:
        d = red.modal_factors(w, density, tau, loss) - red.modal_factors(w, 0.0, 0.0, loss)
        wl = d[:, None] * red.modal_loads_
        out.append((flat @ wl.real + 1j * (flat @ wl.imag)).reshape(red.vertex_modes_.shape[1], 3, -1))
    return np.stack(out)


def best(f, repeats: int) -> tuple[float, np.ndarray]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    red = reduction_of_size(6960, 438, 7)
    omegas = 2 * np.pi * 120.0 * np.arange(7)
    t_old, old = best(lambda: per_harmonic(red, omegas, 1.3, 2e-4, 0.05), args.repeats)
    t_new, new = best(lambda: change_transfers(red, omegas, 1.3, 2e-4, 0.05), args.repeats)
    print("| form | s (best of %d) |\n| --- | ---: |" % args.repeats)
    print(f"| two products per harmonic (baseline) | {t_old:.4f} |\n| one product (change_transfers) | {t_new:.4f} |")
    print(f"\nratio {t_old / t_new:.2f}; largest difference {np.abs(new - old).max():.3g} "
          f"(of {np.abs(old).max():.3g})")


if __name__ == "__main__":
    main()
