"""## Why a refit's Gauss-Newton steps fail: the surface sliding under the pixels (issue 16, session 50).

On a fitted store (a run diagnose has located, so that its f0 is stored in ``/diagnose/<run>``), the inertia
candidate's response at one density factor (``--density``, 1.5 by default) is given Gauss-Newton steps of the
loads from the run's loads (``vfcli.diagnose.refit._load_steps``, as the refit's start does) under the closed rays'
rule ``overlap-allowed`` and under the run's own rule; then, at the point the first reached, taken under the run's
rule:

* the overlap of the simulated folds on the rays the camera sees closed (median / max px, and the widest opening);
* E along the next load step at several lengths, with the raster frozen at the start (what the Gauss-Newton model
  predicts) and re-rasterised at the trial (what the line search measures), each split into motion and gap;
* the re-rasterised motion change at 1/32 of the step by pixel class: compared before and after on the same visible
  triangle (only the barycentric coordinates moved: the surface slid under the pixel), on a new visible triangle,
  and switching between compared and not compared.

With ``--slide`` the frozen model follows the surface under the pixels (``optimize.motion_slide``): its dE should
then track the re-rasterised one at small steps, and the load step lower E.

Reproduce (about 5 min on the kept store of panel recording 2012, made by ``bench/bench_diagnose.py --only 2012
--keep DIR --prepare``, its run ``bounded`` by ``vfcli optimize DIR/seed2012_inertia/recording.h5 --run bounded
--set optimize.gap_closed_rays=overlap-bounded`` and ``vfcli diagnose ... --run bounded``)::

    .venv/bin/python bench/bench_raster_slide.py DIR/seed2012_inertia/recording.h5 bounded [--density 1.5] [--slide]
"""
from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vfcli.diagnose.refit as R  # noqa: E402
from vfcli.config import RecordingConfig  # noqa: E402
from vfcli.diagnose.candidates.inertia import Inertia  # noqa: E402
from vfcli.stages.diagnose import read_inputs  # noqa: E402
from vfcli.store import Store  # noqa: E402


def closed_overlap(problem, disp: np.ndarray) -> np.ndarray:
    """The simulated folds' overlap (px) on every ray the camera sees closed, over the frames; disp (F + 1, N, 3)."""
    out = []
    for f in range(problem.n_frames):
        (r0, _, s0), (r1, _, s1) = problem.silhouettes(problem.mesh.nodes + disp[f])
        common, i0, i1 = np.intersect1d(r0, r1, return_indices=True)
        closed = problem.meas.gap_lo[f][common] == problem.meas.gap_hi[f][common]
        out.append((s0[i0] - s1[i1])[closed])
    return np.concatenate(out) if out else np.zeros(0)


def pixel_costs(problem, st) -> list[tuple[dict, dict, dict]]:
    """Per frame: {pixel: weighted motion cost} of the compared pixels and of those only the recording sees, and
    {pixel: its visible triangle's vertices} (the columns of its interpolation row)."""
    cw = np.asarray(problem.settings.component_weights, float)
    out = []
    for f, fr in enumerate(st.frames):
        vb = fr.m_both @ problem.frame_velocity(st.disp, f)
        both = ((vb - fr.v_both) ** 2) @ cw / fr.n_norm
        vo = problem.meas.velocity[f].reshape(-1, 3)[fr.pix_only].astype(float)
        only = (vo ** 2) @ cw / fr.n_norm
        m = fr.m_both.tocsr()
        tri = {pix: tuple(sorted(m.indices[m.indptr[i]:m.indptr[i + 1]].tolist()))
               for i, pix in enumerate(fr.pix_both.tolist())}
        out.append((dict(zip(fr.pix_both.tolist(), both.tolist())), dict(zip(fr.pix_only.tolist(), only.tolist())), tri))
    return out


def by_class(problem, before, after) -> dict[str, tuple[float, int]]:
    """The motion term's change between two states' :func:`pixel_costs`, by pixel class: (weighted change, pixels)."""
    tot: dict[str, list] = {k: [0.0, 0] for k in ("same triangle", "new triangle", "compared -> not", "not -> compared")}
    for (b0, o0, t0), (b1, o1, t1) in zip(before, after):
        for pix in set(b0) | set(o0) | set(b1) | set(o1):
            v0, v1 = b0.get(pix, o0.get(pix, 0.0)), b1.get(pix, o1.get(pix, 0.0))
            if pix in b0 and pix in b1:
                k = "same triangle" if t0[pix] == t1[pix] else "new triangle"
            elif pix in b0:
                k = "compared -> not"
            elif pix in b1:
                k = "not -> compared"
            else:
                continue
            tot[k][0] += v1 - v0
            tot[k][1] += 1
    scale = problem.settings.motion_weight / problem.n_frames
    return {k: (scale * v, n) for k, (v, n) in tot.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", type=Path)
    ap.add_argument("run")
    ap.add_argument("--density", type=float, default=1.5, help="inertia's density factor (1: the model's own)")
    ap.add_argument("--slide", action="store_true", help="the frozen model with the surface sliding under the pixels "
                    "(optimize.motion_slide = true; the run's own setting otherwise)")
    args = ap.parse_args()
    with Store(args.store).read() as r:
        base = read_inputs(r, RecordingConfig(), args.run).baseline
        base.f0_hz = float(r.attrs("diagnose", args.run)["f0_hz"])
    p = base.problem
    if args.slide:
        p = copy.copy(p)
        p.settings = replace(p.settings, motion_slide=True)
    allowed = copy.copy(p)
    allowed.settings = replace(p.settings, closed_rays="overlap-allowed")
    theta = np.array([args.density])
    ext = {name: R._Extended(prob, Inertia(base.model), base.f0_hz, base.model, None)
           for name, prob in (("overlap-allowed", allowed), (p.settings.closed_rays, p))}
    starts = {name: R._load_steps(e, e.state(np.asarray(base.x, float), theta), R.START_STEPS, R.START_RTOL)
              for name, e in ext.items()}
    print(f"run {args.run} (rule {p.settings.closed_rays}, motion_slide {p.settings.motion_slide}), density factor {args.density}: E after at most "
          f"{R.START_STEPS} load steps from the run's loads: "
          + ", ".join(f"{k} {s.terms.total:.4g} (motion {s.terms.motion:.4g})" for k, s in starts.items()))
    e = ext[p.settings.closed_rays]
    st = e.state(starts["overlap-allowed"].x, theta)
    o = closed_overlap(p, st.disp)
    print(f"at overlap-allowed's point under {p.settings.closed_rays}: E {st.terms.total:.4g}; closed-ray overlap "
          f"median {np.median(o):.2f} px, max {o.max():.2f} (widest opening {p.widest_opening_px:.1f} px)")
    g_l, qm, *_ = R._blocks(e, st, loads_only=True)
    dx = -qm.hessian.solve(g_l)
    print(f"load step: predicted dE {g_l @ dx:+.4g}")
    for a in (1.0, 0.5, 0.125, 2 ** -5, 2 ** -8):
        e.frames = st.frames
        frozen = e.state(st.x + a * dx, theta).terms
        e.frames = None
        fresh = e.state(st.x + a * dx, theta).terms
        print(f"  step x {a:g}: frozen dE {frozen.total - st.terms.total:+.4g} (motion "
              f"{frozen.motion - st.terms.motion:+.3g}, gap {frozen.gap - st.terms.gap:+.3g}); re-rasterised dE "
              f"{fresh.total - st.terms.total:+.4g} (motion {fresh.motion - st.terms.motion:+.3g}, gap "
              f"{fresh.gap - st.terms.gap:+.3g})", flush=True)
    trial = e.state(st.x + 2 ** -5 * dx, theta)
    parts = by_class(p, pixel_costs(p, st), pixel_costs(p, trial))
    print(f"re-rasterised motion change at 1/32 of the step {trial.terms.motion - st.terms.motion:+.4g}, by pixel: "
          + "; ".join(f"{k} {v:+.3g} ({n} pixel-frames)" for k, (v, n) in parts.items()))


if __name__ == "__main__":
    main()
