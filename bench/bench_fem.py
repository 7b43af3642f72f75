"""Benchmark of the M5 mesh and the FEM solver backends.

For coarse, default and fine element sizes: DOF count, time to mesh, to
assemble the model (stiffness + load operators), to factorise, and to solve
250 load cases as one block, for each installed backend; plus the effect of
factorising the folds separately (and reusing one fold's factor for its
mirror) against one factorisation of the whole block-diagonal system.

Writes the tables into docs/benchmarks.md under ``## Mesh and FEM``.

Reproduce: ``.venv/bin/python bench/bench_fem.py`` (``--quick`` for a smoke run).
"""
from __future__ import annotations

import argparse
import os
import platform
import re
import time
from pathlib import Path

import numpy as np

from vfcli.model.fem import ElasticModel
from vfcli.model.m5 import M5Params
from vfcli.model.mesh import DEFAULT_EDGE_MM, TAG_INFERIOR, TAG_MEDIAL, TAG_SUPERIOR, build_mesh
from vfcli.model.solver import available_backends, factorize

N_CASES = 250
SIZES = {"coarse": 2.0, "default": DEFAULT_EDGE_MM, "fine": 1.25}
DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
HEADING = "## Mesh and FEM"


REPEATS = 2


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _best(make, run, repeats: int = REPEATS) -> float:
    """Smallest wall time of ``run(make())`` over repeats (the machine is shared)."""
    times = []
    for _ in range(repeats):
        obj = make()
        times.append(_timed(lambda: run(obj))[1])
    return min(times)


def _load_cases(model: ElasticModel, n: int, seed: int = 0) -> np.ndarray:
    """n load vectors from random tractions on the free (inferior, medial, superior) facets."""
    mask = model.quadrature_mask(tags=[TAG_INFERIOR, TAG_MEDIAL, TAG_SUPERIOR])
    op = model.traction_operator(mask)
    rng = np.random.default_rng(seed)
    return np.asarray(op @ rng.normal(scale=100.0, size=(op.shape[1], n)))


def bench_size(name: str, h: float, backends: list[str], n_cases: int) -> list[dict]:
    rows = []
    mesh, t_mesh = _timed(lambda: build_mesh(M5Params(), target_edge_mm=h))
    for backend in backends:
        model, t_asm = _timed(lambda: ElasticModel(mesh, backend=backend))
        _, t_ops = _timed(lambda: model.traction_operator())
        loads = _load_cases(model, n_cases)
        t_fac = _best(lambda: ElasticModel(mesh, backend=backend), lambda m: m.factorize())
        model.factorize()
        t_solve = _best(lambda: model, lambda m: m.solve(loads))
        rows.append(dict(size=name, h=h, nodes=mesh.n_nodes, tets=len(mesh.tets), dofs=model.n_dofs,
                         free=len(model.free_dofs), backend=backend, mesh=t_mesh, assemble=t_asm + t_ops,
                         factor=t_fac, solve=t_solve, total=t_mesh + t_asm + t_ops + t_fac + t_solve,
                         min_dihedral=mesh.min_dihedral_deg()))
        print(rows[-1], flush=True)
    return rows


def bench_structure(h: float, backends: list[str], n_cases: int) -> list[dict]:
    """Whole block-diagonal system vs per-fold factorisations vs mirror reuse."""
    mesh = build_mesh(M5Params(), target_edge_mm=h)
    rows = []
    for backend in backends:
        mirrored = ElasticModel(mesh, backend=backend)
        loads = _load_cases(mirrored, n_cases)
        separate = ElasticModel(mesh, backend=backend, reuse_mirror=False)
        k_ff, _ = mirrored.reduced_matrices()
        free = mirrored.free_dofs
        rhs = np.ascontiguousarray(loads[free])
        t_whole = _best(lambda: None, lambda _: factorize(k_ff, backend))
        whole = factorize(k_ff, backend)
        t_whole_solve = _best(lambda: whole, lambda w: w.solve(rhs))
        t_sep = _best(lambda: ElasticModel(mesh, backend=backend, reuse_mirror=False), lambda m: m.factorize())
        separate.factorize()
        t_sep_solve = _best(lambda: separate, lambda m: m.solve(loads))
        t_mir = _best(lambda: ElasticModel(mesh, backend=backend), lambda m: m.factorize())
        mirrored.factorize()
        t_mir_solve = _best(lambda: mirrored, lambda m: m.solve(loads))
        for variant, tf, ts in (("whole system", t_whole, t_whole_solve), ("per fold", t_sep, t_sep_solve),
                                ("per fold + mirror reuse", t_mir, t_mir_solve)):
            rows.append(dict(backend=backend, variant=variant, factor=tf, solve=ts))
            print(rows[-1], flush=True)
    return rows


def markdown(size_rows: list[dict], struct_rows: list[dict], h_struct: float, n_cases: int) -> str:
    lines = [
        HEADING,
        "",
        "Reproduce: `.venv/bin/python bench/bench_fem.py` (writes this section).",
        "",
        f"Machine: {os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}; "
        f"measured {time.strftime('%Y-%m-%d')}. Times in seconds, wall clock, best of {REPEATS} runs for factor and "
        "solves, on a machine shared with other jobs: expect +-50 % between runs.",
        "",
        f"M5 folds (D = 8 mm, L = 15 mm, both folds), P2 tetrahedra, nu = 0.499, fixture clamped. "
        f"'assemble' = stiffness of both folds + facet load operators; 'factor' = one factorisation "
        f"(fold 1, reused for its mirror fold 0); '{n_cases} solves' = one block solve of {n_cases} "
        "load vectors (random tractions on the free surfaces).",
        "",
        "| size | edge (mm) | nodes | tets | DOFs (free) | min dihedral (deg) | backend | mesh | assemble | "
        f"factor | {n_cases} solves | total |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in size_rows:
        lines.append(f"| {r['size']} | {r['h']:g} | {r['nodes']} | {r['tets']} | {r['dofs']} ({r['free']}) | "
                     f"{r['min_dihedral']:.1f} | {r['backend']} | {r['mesh']:.2f} | {r['assemble']:.2f} | "
                     f"{r['factor']:.2f} | {r['solve']:.2f} | {r['total']:.1f} |")
    lines += [
        "",
        f"Structure (edge {h_struct:g} mm): factorising the whole block-diagonal system, each fold "
        "separately, or fold 1 only and reusing it for the mirror fold 0 (`ElasticModel(reuse_mirror=True)`, "
        "the default when no offset/rotation is set).",
        "",
        f"| backend | variant | factor | {n_cases} solves |",
        "|---|---|---|---|",
    ]
    for r in struct_rows:
        lines.append(f"| {r['backend']} | {r['variant']} | {r['factor']:.2f} | {r['solve']:.2f} |")
    default = [r for r in size_rows if r["size"] == "default"]
    if default:
        best = min(default, key=lambda r: r["total"])
        totals = ", ".join(f"{r['backend']} {r['total']:.1f} s" for r in default)
        lines += [
            "",
            "Findings:",
            f"- Default size (edge {default[0]['h']:g} mm, {default[0]['dofs']} DOFs): mesh + assemble + "
            f"factorise + {n_cases} solves took {totals} (target: under 20 s). Fastest: {best['backend']}. "
            "`backend=\"auto\"` picks the first installed of `vfcli.model.solver.AUTO_ORDER`; splu (SuperLU, "
            "always installed) is the fallback.",
            "- Accuracy at the default size (tests/test_fem.py): the six lowest eigenfrequencies of one fold "
            "are 0.4-0.6 % above the converged 48.9, 72.3, 83.7, 85.4, 95.4, 97.9 Hz (bench/fem_mode_reference.py); "
            "the lateral and vertical "
            "displacements under 800 Pa on the inferior and medial surfaces agree with a refined mesh "
            "(edge 1.1 mm) within 2 %.",
            "- Spread between runs: in an earlier run the same day on a less loaded machine the default-size "
            "totals were splu 7.5 s, cholespy 5.8 s, pypardiso 4.6 s; SuperLU's 250-column block solve alone "
            "varied from 4 to 16 s with the load of other jobs. So with splu (always installed) the 20 s target "
            "holds at 1.5 mm on an idle 2-core machine but not under heavy load; cholespy (an 11 MB "
            "self-contained wheel) held it in every run, pypardiso (MKL, about 1 GB) is fastest to factorise.",
            "- Default element: P2 with full quadrature. `ElasticModel(volumetric=\"reduced\")` (one-point "
            "quadrature of the lambda term = condensed P2-P0 u-p element) converges faster at nu = 0.499 "
            "(thick-cylinder L2 rate 3.1 against 2.6) and gives a 1.7 % larger displacement at 1.5 mm, "
            "within 0.1 % of its own refined value, at the same cost.",
        ]
    for backend in sorted({r["backend"] for r in struct_rows}):
        v = {r["variant"]: r for r in struct_rows if r["backend"] == backend}
        lines.append(
            f"- {backend}: factor whole system {v['whole system']['factor']:.2f} s, per fold "
            f"{v['per fold']['factor']:.2f} s, per fold + mirror reuse {v['per fold + mirror reuse']['factor']:.2f} s "
            f"(x{v['whole system']['factor'] / v['per fold + mirror reuse']['factor']:.1f} faster than the whole "
            "system); the block solves do the same triangular work in all variants.")
    return "\n".join(lines) + "\n"


def write_section(text: str, path: Path = DOC) -> None:
    """Replace (or append) the '## Mesh and FEM' section of docs/benchmarks.md."""
    old = path.read_text() if path.exists() else "# Benchmarks\n\n"
    pattern = re.compile(rf"^{re.escape(HEADING)}\n.*?(?=^## |\Z)", re.S | re.M)
    new = pattern.sub(lambda _: text + "\n", old) if pattern.search(old) else old.rstrip("\n") + "\n\n" + text
    path.write_text(new)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarse size only, 20 cases, no doc update")
    args = parser.parse_args()
    backends = available_backends()
    n_cases = 20 if args.quick else N_CASES
    sizes = {"coarse": SIZES["coarse"]} if args.quick else SIZES
    size_rows = [r for name, h in sizes.items() for r in bench_size(name, h, backends, n_cases)]
    h_struct = SIZES["coarse"] if args.quick else DEFAULT_EDGE_MM
    struct_rows = bench_structure(h_struct, backends, n_cases)
    text = markdown(size_rows, struct_rows, h_struct, n_cases)
    print(text)
    if not args.quick:
        write_section(text)
        print(f"written to {DOC}")


if __name__ == "__main__":
    main()
