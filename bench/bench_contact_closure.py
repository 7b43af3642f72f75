"""## Contact from the closure: does the recorded glottal closure tell contact from no contact? (issue 16)

The contact score test and the rigid-contact refit read the superior-surface velocity, which contact moves by
about 0.2 % (the reference note); the evidence is to come from the gap silhouette's closure.  This measures,
per recording of a kept blind panel (``bench_diagnose.py --keep DIR``, the store's run ``default``), two
kinds of closure figures, reading only the store (no truth.h5; the hidden effect and strength are printed
from the panel's ``prepared.json`` after the figures are computed):

* **the recording alone, its cycles (and their closure edges) as replicates** (the whole recording's
  glottal area ``/flow/glottal_area``):

  - the closed quotient per whole cycle (frames whose area is at most 2 % of the recording's largest, the
    share ``Contact`` calls closed), mean and sd over cycles;
  - the **clipping index** of every closure edge (:func:`clipping_index`): the area of the last two open
    frames before a closed stretch (first two after it), extrapolated linearly to the first closed frame
    (last closed frame), above the closed level, in units of the area's change per frame there.  A
    glottis whose area passes smoothly through the closed level (the folds meet with a finite speed, the
    frames at a uniformly random phase of that passage) gives ``q = u - 1`` with ``u`` uniform in [0, 1):
    mean -0.5, never above 0 (a decelerating closure gives less).  A clipped closure (the area falling
    from a finite value to closed within a frame: folds stopped by contact, or a slit the gap masks do
    not resolve) gives ``q = J - (1 - u)``, J the jump in units of the slope.  The test: the edges' mean q against -0.5,
    one-sided Student t over the edges (each edge one replicate; the edges of different cycles are
    independent realisations of the same closure);

* **the no-contact fit against the recording** (the fitted window only; descriptive, no null distribution):
  the fit's signed aperture per ray (lateral distance of the two folds' simulated silhouettes on the
  baseline's rays, negative where the folds overlap) and its area (the positive part summed over rays);
  the window's measured and simulated closed quotients; the share of the measured closed frames in which
  the fit's glottis is open; the fit's mean overlap (-mean signed aperture over the rays) at its deepest
  during the measured closed frames, mm.

Reproduce (on a kept panel; ``--only`` seeds prepared with ``bench_diagnose.py ... --prepare``)::

    .venv/bin/python bench/bench_diagnose.py --seeds 2001 --duration 0.04 --run-set optimize.uncertainty=false \\
        --keep /tmp/contact_panel --prepare --jobs 1 --only 2001 2004 2006 2009 2011 2014
    .venv/bin/python bench/bench_contact_closure.py /tmp/contact_panel/seed20*/recording.h5
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: a frame is closed when its area is at most this share of the recording's largest (as ``Contact``)
CLOSED_SHARE = 0.02
#: the clipping index's mean under a smooth passage through zero sampled at a uniform phase
SMOOTH_MEAN = -0.5


def closed_runs(area: np.ndarray, share: float = CLOSED_SHARE) -> list[tuple[int, int]]:
    """(first, last) frame of every closed stretch of ``area`` (F,), any unit; a frame is closed when its
    area is at most ``share`` of the largest."""
    closed = np.asarray(area, float) <= share * max(float(np.max(area)), 1e-300)
    edges = np.diff(np.concatenate([[0], closed.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), (np.flatnonzero(edges == -1) - 1).tolist()))


def clipping_index(area: np.ndarray, share: float = CLOSED_SHARE) -> list[tuple[str, float]]:
    """("closing" | "opening", q) for every closure edge with two open frames on its open side and a
    falling (rising) area there (module docstring): ``q = (2 a1 - a2 - L) / (a2 - a1)``, a1 the open frame
    next to the closed stretch, a2 the one before it (after it), L the closed level (``share`` of the
    largest area: the extrapolation is to the level that counts as closed, so that level is no clip);
    dimensionless (frames of the local slope)."""
    a = np.asarray(area, float)
    level = share * float(a.max())
    out = []
    for first, last in closed_runs(a, share):
        for kind, a1i, a2i in (("closing", first - 1, first - 2), ("opening", last + 1, last + 2)):
            if a2i < 0 or a2i >= len(a):
                continue
            a1, a2 = a[a1i], a[a2i]
            if a1 <= level or a2 <= a1:                 # not two open frames, or not moving towards closure
                continue
            out.append((kind, float((2 * a1 - a2 - level) / (a2 - a1))))
    return out


def clipping_test(q: np.ndarray) -> tuple[float, float, float]:
    """(mean, standard error, one-sided p) of the edges' clipping indices against :data:`SMOOTH_MEAN`."""
    q = np.asarray(q, float)
    if q.size < 2:
        return float(q.mean()) if q.size else float("nan"), float("nan"), float("nan")
    se = float(q.std(ddof=1) / np.sqrt(q.size))
    t = (q.mean() - SMOOTH_MEAN) / se if se > 0 else np.inf
    return float(q.mean()), se, float(stats.t.sf(t, q.size - 1))


def cycle_closed_quotients(area: np.ndarray, cycle: np.ndarray, share: float = CLOSED_SHARE) -> np.ndarray:
    """(K,) share of each whole cycle's frames (``cycle`` (F,) index, -1 outside) whose area is closed."""
    closed = np.asarray(area, float) <= share * float(np.max(area))
    return np.array([closed[cycle == k].mean() for k in range(int(cycle.max()) + 1)]) if cycle.max() >= 0 \
        else np.zeros(0)


def fit_apertures(problem, displacements: np.ndarray) -> np.ndarray:
    """(F, n_rays) signed aperture of the fit on the problem's rays, mm: the high fold's simulated silhouette
    minus the low fold's (negative where they overlap); NaN on rays a fold does not cross."""
    rays = np.asarray(problem.rays)
    out = np.full((problem.n_frames, len(rays)), np.nan)
    for f in range(problem.n_frames):
        (r0, _, s0), (r1, _, s1) = problem.silhouettes(problem.mesh.nodes + displacements[f])
        lo = np.full(int(rays.max()) + 1, np.nan)
        hi = lo.copy()
        lo[r0], hi[r1] = s0, s1
        out[f] = (hi[rays] - lo[rays]) / problem.camera.px_per_mm
    return out


def measure(store: Path) -> dict:
    """Every figure of one store (module docstring) from its run ``default``; reads no truth."""
    from vfcli.config import load_config
    from vfcli.diagnose.cycles import glottal_cycles
    from vfcli.stages.diagnose import read_inputs
    from vfcli.store import Store

    t0 = time.perf_counter()
    with Store(store).read() as r:
        _, cfg = load_config(stored_json=r.recording_config_json())
        inp = read_inputs(r, cfg, "default")
        b, rec = inp.baseline, inp.recording
        p = b.problem
        area = np.asarray(rec.glottal_area, float)
        window = slice(rec.window_start, rec.window_start + p.n_frames)
        window_area = area[window]
    cyc = glottal_cycles(area, p.dt, rec.pressure_f0_hz)
    cq = cycle_closed_quotients(area, cyc.cycle)
    edges = clipping_index(area)
    q = np.array([v for _, v in edges])
    mean, se, pval = clipping_test(q)
    w = fit_apertures(p, b.displacements)
    ppm = p.camera.px_per_mm
    fit_area = np.nansum(np.maximum(w, 0.0), axis=1) / ppm            # mm^2 (ray spacing 1 px)
    meas_closed = window_area <= CLOSED_SHARE * max(float(area.max()), 1e-300)
    fit_closed = fit_area <= CLOSED_SHARE * max(float(fit_area.max()), 1e-300)
    overlap = -np.nanmean(w, axis=1)
    return {"store": str(store), "f0_hz": cyc.f0_hz, "cycles": int(cq.size),
            "cq_mean": float(cq.mean()) if cq.size else float("nan"),
            "cq_sd": float(cq.std(ddof=1)) if cq.size > 1 else float("nan"),
            "edges": len(edges), "q": [round(v, 3) for v in q.tolist()],
            "q_kinds": [k for k, _ in edges], "q_mean": mean, "q_se": se, "p_clipping": pval,
            "window_cq_measured": float(meas_closed.mean()), "window_cq_fit": float(fit_closed.mean()),
            "fit_open_while_closed": float((~fit_closed[meas_closed]).mean()) if meas_closed.any() else float("nan"),
            "fit_overlap_closed_mm": float(overlap[meas_closed].max()) if meas_closed.any() else float("nan"),
            "fit_max_aperture_mm": float(np.nanmax(np.nanmean(w, axis=1))),
            "seconds": time.perf_counter() - t0}


def hidden(store: Path) -> tuple[str, float]:
    """The panel's hidden effect and strength (its prepared.json, written by bench_diagnose; not truth.h5)."""
    for name in ("prepared.json", "case.json"):
        f = store.parent / name
        if f.exists():
            case = json.loads(f.read_text())["case"]
            return case["effect"], float(case["strength"])
    return "?", float("nan")


def seam_speed_ratio(gap: np.ndarray, visible: np.ndarray, velocity: np.ndarray, closed: np.ndarray,
                     inner_px: float = 3.0, outer_px: float = 8.0) -> float:
    """Scoring only: the true surface's lateral speed next to the seam against a little further out, while
    the glottis is closed (does the tissue at the contact stop?).  Per ray (image line across the glottis)
    the seam is the ray's mean gap centre over the open frames; the RMS lateral screen velocity of the
    visible pixels within ``inner_px`` of it, divided by that from ``inner_px`` to ``outer_px``, per closed
    frame, mean over the closed frames.

    gap, visible : (F, H, W) bool.  velocity : (F, H, W, 3) screen velocity (x along columns, y along rows),
    mm/s.  closed : (F,) bool."""
    ii, jj = np.nonzero(gap.any(axis=0))
    lateral = 0 if np.ptp(ii) < np.ptp(jj) else 1                  # rows lateral when the gap is wide in x
    g = gap if lateral == 0 else gap.transpose(0, 2, 1)              # (F, lateral, rays)
    vis = visible if lateral == 0 else visible.transpose(0, 2, 1)
    comp = 1 if lateral == 0 else 0
    n = g.shape[1]
    pos = np.arange(n, dtype=float)
    count = g.sum(axis=1)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # rays never open: no centre (NaN)
        centre = np.nanmean(np.where(count > 0, np.einsum("flr,l->fr", g, pos) / np.maximum(count, 1), np.nan), 0)
    rays = np.flatnonzero(np.isfinite(centre))
    dist = np.abs(pos[:, None] - centre[None, rays])                 # (lateral, rays)
    ratios = []
    for f in np.flatnonzero(closed):
        v = (velocity[f] if lateral == 0 else velocity[f].transpose(1, 0, 2))[:, rays, comp]
        ok = vis[f][:, rays] & np.isfinite(v)
        inner, outer = ok & (dist < inner_px), ok & (dist >= inner_px) & (dist < outer_px)
        if inner.any() and outer.any():
            ratios.append(np.sqrt(np.mean(v[inner] ** 2) / np.mean(v[outer] ** 2)))
    return float(np.mean(ratios)) if ratios else float("nan")


def truth_figures(store: Path) -> dict:
    """Scoring only, after every figure is computed: the phantom's true glottal area's clipping index (the
    area at the pixel centres, without the camera's blur and the gap masks' threshold) and how far the
    phantom's own medial and superior surfaces (not the fixture) cross
    the midplane while its glottis is closed (a null phantom's folds interpenetrate there; contact's do not).
    Reads the panel's sealed ``truth/truth.h5``."""
    import h5py

    f = store.parent / "truth" / "truth.h5"
    if not f.exists():
        return {}
    with h5py.File(f, "r") as h:
        area = np.asarray(h["screen/glottal_area"], float)
        nodes = np.asarray(h["mesh/nodes"], float)
        disp = np.asarray(h["frames/displacement"], float)
        faces, tag, fold = (np.asarray(h[f"mesh/{k}"]) for k in ("faces", "face_tag", "face_fold"))
        gap, visible = np.asarray(h["screen/gap"], bool), np.asarray(h["screen/visible"], bool)
        velocity = np.asarray(h["screen/velocity"], np.float32)
    fixture = np.unique(faces[tag == 4])                 # the fixture's nodes keep their adducted rest place
    depth = np.zeros(len(area))
    for k, sign in ((0, -1.0), (1, 1.0)):
        idx = np.setdiff1d(np.unique(faces[np.isin(tag, (2, 3)) & (fold == k)]), fixture)
        depth = np.maximum(depth, np.max(-sign * (nodes[idx, 1][None] + disp[:, idx, 1]), axis=1))
    closed = area <= CLOSED_SHARE * area.max()
    q = np.array([v for _, v in clipping_index(area)])
    mean, se, pval = clipping_test(q)
    return {"true_q_mean": mean, "true_q_se": se, "true_p_clipping": pval,
            "true_overlap_closed_mm": float(depth[closed].max()) if closed.any() else 0.0,
            "true_cq": float(closed.mean()), "true_seam_ratio": seam_speed_ratio(gap, visible, velocity, closed)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stores", type=Path, nargs="+")
    ap.add_argument("--json", type=Path, help="write every figure here")
    args = ap.parse_args()
    rows = [measure(s) for s in args.stores]
    for row, s in zip(rows, args.stores):                 # the hidden truth only after every figure
        row["effect"], row["strength"] = hidden(s)
        row.update(truth_figures(s))
    print("| recording | hidden (strength) | cycles | closed quotient, mean (sd) | edges | clipping index q, "
          "mean +- se | p (q > -0.5) | window closed quotient, recording / fit | fit open while closed | "
          "fit overlap while closed, mm (max aperture) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {Path(r['store']).parent.name} | {r['effect']} ({r['strength']:g}) | {r['cycles']} | "
              f"{r['cq_mean']:.3f} ({r['cq_sd']:.3f}) | {r['edges']} | {r['q_mean']:+.2f} +- {r['q_se']:.2f} | "
              f"{r['p_clipping']:.2g} | {r['window_cq_measured']:.2f} / {r['window_cq_fit']:.2f} | "
              f"{r['fit_open_while_closed']:.2f} | {r['fit_overlap_closed_mm']:.3f} ({r['fit_max_aperture_mm']:.3f}) |")
    print("\nScoring against the phantoms' truth (read after the figures above):\n")
    print("| recording | true closed share | true area's clipping index q, mean +- se | p (q > -0.5) | "
          "phantom's own folds cross the midplane while closed, mm | true lateral speed at the seam / 3-8 px out, "
          "closed |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        if "true_q_mean" in r:
            print(f"| {Path(r['store']).parent.name} | {r['true_cq']:.2f} | {r['true_q_mean']:+.2f} +- "
                  f"{r['true_q_se']:.2f} | {r['true_p_clipping']:.2g} | {r['true_overlap_closed_mm']:.3f} | "
                  f"{r['true_seam_ratio']:.2f} |")
    for r in rows:
        print(f"{Path(r['store']).parent.name}: q per edge {list(zip(r['q_kinds'], r['q']))}; {r['seconds']:.0f} s",
              file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
