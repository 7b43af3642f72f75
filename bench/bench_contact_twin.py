"""## What the synth's contact changes in the glottal closure: a contact phantom against its no-contact twin (issue 16)

Truth-side physics, no recording: for a contact phantom of the panel (its ``raw/phantom.json``, as
``vfcli synth`` wrote it), the true motion is solved again as the synth solves it
(:func:`vfcli.synth.phantom.true_motion`, the widened draw and pressure waveform of its seed), once with
contact and once without (``effect = "none"``: the same aerodynamic loads; the quasi-static response does not
depend on the adduction), both on the contact phantom's adducted rest mesh.  The glottis seen from above is
the narrowest lateral distance between the folds through their depth: per slice along the length (40
slices), twice the smallest distance of fold 1's medial and superior surface nodes (off the fixture) from
the midplane (the folds are mirror images), negative where they overlap; the area is the positive part
summed over the slices, mm^2.  Figures, per phantom:

* the largest change of the area by contact over the cycle, relative to the largest area, and the same
  in the phases where the twin's glottis is open;
* the closed share of the cycle of each (area at most 2 % of the largest, as ``Contact`` and
  bench_contact_closure.py count closed);
* the clipping index of bench_contact_closure.py on each area sampled at the recording's frame rate over
  100 cycles (f0 and fps of the phantom's config): mean, and the one-sided p against the smooth -0.5.

Reproduce (a kept panel, ``bench_diagnose.py --keep DIR``)::

    .venv/bin/python bench/bench_contact_twin.py DIR/seed2004_contact DIR/seed2009_contact DIR/seed2014_contact
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

_spec = importlib.util.spec_from_file_location("bench_contact_closure", ROOT / "bench" / "bench_contact_closure.py")
closure = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(closure)

#: slices along the length
N_SLICES = 40
#: cycles sampled at the frame rate for the clipping index
N_CYCLES = 100


def motions(phantom_json: Path):
    """(rest mesh, contact motion, no-contact motion, SynthConfig) of the phantom ``phantom_json`` describes."""
    from vfcli.config import MeshConfig, SynthConfig
    from vfcli.synth.phantom import PressureWaveform, resolve_effect, true_motion
    from vfcli.synth.widened import draw_widened

    j = json.loads(phantom_json.read_text())
    cfg, mesh_cfg = SynthConfig(**j["synth"]), MeshConfig(**j["mesh"])
    rng = np.random.default_rng(cfg.seed)                         # as make_recording draws them
    wide = draw_widened(cfg.seed, cfg.width_px, cfg.height_px, mesh_cfg) if cfg.panel == "widened" else None
    if wide is not None:
        mesh_cfg = wide.true_mesh(mesh_cfg)
    effect, strength = resolve_effect(cfg, rng)
    if effect != "contact":
        raise SystemExit(f"{phantom_json}: effect {effect}, not contact")
    waveform = PressureWaveform(mean_pa=cfg.mean_pressure_pa, amplitude_rel=cfg.pressure_amplitude_rel,
                                phases_rad=tuple(np.round(rng.uniform(-np.pi, np.pi, 4), 3)))
    load = None if wide is None else wide.load
    with_contact = true_motion(cfg, mesh_cfg, waveform, "contact", strength, load)
    without = true_motion(cfg, mesh_cfg, waveform, "none", 0.0, load)
    return with_contact.mesh, with_contact.motion, without.motion, cfg


def aperture_area(mesh, disp: np.ndarray) -> np.ndarray:
    """(T,) area of the glottis seen from above, mm^2 (module docstring), for displacements ``disp`` (T, N, 3)."""
    from vfcli.model.mesh import TAG_FIXTURE, TAG_MEDIAL, TAG_SUPERIOR

    fixture = np.unique(mesh.faces[mesh.face_tag == TAG_FIXTURE])
    near = (mesh.face_fold == 1) & np.isin(mesh.face_tag, [TAG_MEDIAL, TAG_SUPERIOR])
    nodes = np.setdiff1d(np.unique(mesh.faces[near]), fixture)
    x = mesh.nodes[nodes, 0]
    edges = np.linspace(x.min(), x.max(), N_SLICES + 1)
    slot = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, N_SLICES - 1)
    dist = mesh.nodes[nodes, 1][None] + disp[:, nodes, 1]          # (T, n) fold 1's distance from y = 0
    width = np.full((len(disp), N_SLICES), np.inf)
    for s in range(N_SLICES):
        if np.any(slot == s):
            width[:, s] = 2.0 * dist[:, slot == s].min(axis=1)
    width[~np.isfinite(width)] = 0.0
    return np.maximum(width, 0.0).sum(axis=1) * (edges[1] - edges[0])


def compare(panel_dir: Path) -> dict:
    t0 = time.perf_counter()
    mesh, contact, free, cfg = motions(panel_dir / "raw" / "phantom.json")
    phase = np.arange(512) / 512
    a_c, a_f = aperture_area(mesh, contact.displacement(phase)), aperture_area(mesh, free.displacement(phase))
    big = float(a_f.max())
    open_f = a_f > closure.CLOSED_SHARE * big
    frames = np.arange(int(N_CYCLES * cfg.fps_hz / cfg.f0_hz)) * cfg.f0_hz / cfg.fps_hz   # phases at the frames
    out = {"phantom": panel_dir.name, "strength": float(cfg.strength),
           "change_max_rel": float(np.abs(a_c - a_f).max() / big),
           "change_open_rel": float(np.abs(a_c - a_f)[open_f].max() / big),
           "closed_contact": float(np.mean(a_c <= closure.CLOSED_SHARE * a_c.max())),
           "closed_free": float(np.mean(~open_f))}
    for name, motion in (("contact", contact), ("free", free)):
        area = np.concatenate([aperture_area(mesh, motion.displacement(frames[i:i + 500]))
                               for i in range(0, len(frames), 500)])
        q = np.array([v for _, v in closure.clipping_index(area)])
        mean, se, p = closure.clipping_test(q)
        out.update({f"q_{name}": mean, f"q_se_{name}": se, f"p_{name}": p, f"edges_{name}": int(q.size)})
    out["seconds"] = time.perf_counter() - t0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("phantoms", type=Path, nargs="+", help="panel folders of contact phantoms (with raw/phantom.json)")
    args = ap.parse_args()
    print("| phantom (adduction factor) | largest change of the area by contact / largest area: all phases, "
          "the twin open | closed share, contact / twin | clipping index at the frame rate, contact / twin "
          "(edges) | p (q > -0.5), contact / twin |")
    print("|---|---|---|---|---|")
    for d in args.phantoms:
        r = compare(d)
        print(f"| {r['phantom']} ({r['strength']:g}) | {r['change_max_rel']:.3f} / {r['change_open_rel']:.3f} | "
              f"{r['closed_contact']:.3f} / {r['closed_free']:.3f} | {r['q_contact']:+.3f} / {r['q_free']:+.3f} "
              f"({r['edges_contact']}, {r['edges_free']}) | {r['p_contact']:.2g} / {r['p_free']:.2g} |", flush=True)
        print(f"{r['phantom']}: {r['seconds']:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
