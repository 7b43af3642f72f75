"""Plain words for what Locate found: the lines `vfcli diagnose` prints."""
from __future__ import annotations

import numpy as np

from vfcli.diagnose.cycles import PHASE_NAMES
from vfcli.diagnose.locate import MIN_HARMONIC_CYCLES, Hotspot, Located


def ordinal(k: int) -> str:
    """1st, 2nd, 3rd, 4th ... 11th, 12th, 13th, 21st."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def percent_size(fraction: float) -> str:
    """The size of a relative change in per cent, without sign: whole per cent from 9.5 % up, else two
    significant digits ("72", "1.7", "0.044"; never "0" for a change that is there)."""
    pct = abs(100.0 * float(fraction))
    return f"{pct:.0f}" if pct >= 9.5 else f"{pct:.2g}"


def p_text(p: float) -> str:
    """A p-value as text: two significant digits, '< 1e-6' below."""
    return "p < 1e-6" if p < 1e-6 else f"p = {p:.2g}"


def hotspot_words(located: Located, h: Hotspot) -> str:
    """One hotspot in plain words, e.g. "the residual sits on the left fold, medial edge, posterior third,
    vertical component, 2nd harmonic of f0 (peaking in the closing phase): 4.1x the noise floor, p = 0.001"."""
    d = located.families[h.family]
    what = "the residual" if h.family == "motion" else "the gap silhouette's residual"
    where = d.region_names[h.region]
    comp = d.component_names[h.component]
    comp = f"{comp} component" if h.family == "motion" else comp
    if h.kind == "harmonic":
        when = f"{ordinal(h.index)} harmonic of f0"
        if h.peak_phase >= 0:
            when += f" (peaking in the {PHASE_NAMES[h.peak_phase]} phase)"
        size = f"amplitude {h.size:.3g} {d.units}"
    else:
        when = f"{PHASE_NAMES[h.index]} phase"
        size = f"mean {h.size:.3g} {d.units}"
    return (f"{what} sits on the {where}, {comp}, {when}: {h.ratio:.1f}x the noise floor ({size}), "
            f"{p_text(h.p_value)} ({p_text(h.p_adjusted).replace('p', 'adjusted', 1)} over {len(located.hotspots)} parts)")


def fold_side_words(camera, mesh, pose_source: str, origin_px=(0.0, 0.0)) -> str:
    """Which fold of the video the words call left and which right.

    The diagnosis names places and parameters by the model's folds (fold 0 "left", fold 1 "right": hotspots,
    ``left_softening``, ``offset_y_left_mm``). Which of the video's folds that is follows the run's camera rotation;
    the two folds look alike, so a rotation estimated from the gap is chosen within a half turn of
    ``camera.rotation_deg`` (:func:`vfcli.camera.pose.gap_axis`), and with the mounting angle not in the config the
    model's left fold may be the lab's right one (widened phantom 2111, rotation 95.8 deg unstated: fitted at
    -84.2 deg, its left fold's softening read as the right's). The line says where each fold is in the video.

    camera : the run's :class:`vfcli.camera.camera.Camera` (on the stored frames' grid).  mesh : the run's
    :class:`vfcli.model.mesh.FoldMesh`.  pose_source : the run's ``pose_source`` attribute ("config" or "estimated
    from the glottal gap (...)").  origin_px : (col, row) of the stored frames' first pixel in the video, px.
    """
    at = [np.asarray(camera.project(mesh.nodes[mesh.fold_nodes(f)].mean(axis=0)), float) + np.asarray(origin_px, float)
          for f in (0, 1)]
    (c0, r0), (c1, r1) = at
    line = (f"left and right name the model's folds: in the video's pixels the left fold (fold 0) is the one centred "
            f"at col {c0:.0f}, row {r0:.0f}, the right fold (fold 1) the one centred at col {c1:.0f}, row {r1:.0f} "
            f"(camera rotation {camera.rotation_deg:.1f} deg")
    if pose_source == "config":
        return line + ", from the config)"
    return line + (f", {pose_source}; the folds look alike, so the estimate keeps within a half turn of "
                   "camera.rotation_deg: unless that is the rig's mounting angle, check which fold is which)")


def summary_lines(located: Located, max_lines: int = 5) -> list[str]:
    """The lines the command prints: the significant hotspots (at most ``max_lines``) and what they mean
    (:data:`MEANING`), or that there are none."""
    n = len(located.hotspots)
    head = (f"f0 {located.f0_hz:.1f} Hz; noise floor from {located.n_cycles} whole glottal cycles; "
            f"{n} parts tested, family-wise false-alarm rate {located.alpha:g}")
    spans = [d.window_cycles for d in located.families.values() if np.isfinite(d.window_cycles)]
    if spans and min(spans) < MIN_HARMONIC_CYCLES:
        head += (f"; harmonics of f0 not tested: the window spans {min(spans):.2f} of a glottal cycle (from "
                 f"{MIN_HARMONIC_CYCLES:g} they are told apart; fit a longer window, optimize.n_frames)")
    sig = located.significant
    if not sig:
        best = located.hotspots[0] if located.hotspots else None
        tail = (f" (largest: {best.ratio:.1f}x the noise floor, {p_text(best.p_value)}, "
                f"{p_text(best.p_adjusted).replace('p', 'adjusted', 1)})") if best else ""
        return [head, "no part of the residual stands above the noise floor" + tail]
    lines = [head] + [hotspot_words(located, h) for h in sig[:max_lines]]
    if len(sig) > max_lines:
        lines.append(f"... and {len(sig) - max_lines} more parts above the noise floor")
    return lines + [MEANING]


#: what a part above the noise floor means, said after the hotspots: a place where the fit and the recording
#: differ beyond the recording's own cycle-to-cycle variation, which the fitted model's error (its geometry, its
#: loads) makes as readily as a missing term; whether a candidate term explains it is the decision's to say
MEANING = ("parts above the noise floor are where the fit and the recording differ beyond noise (the model's own "
           "error or missing physics); the candidates below say whether a known term explains them")


#: how the line on a doubtful gap begins (:func:`gap_doubt_words`)
GAP_DOUBT_START = "the gap this run was fitted to is doubtful"


def gap_doubt_words(edge_disagreement: float, level_disagreement: float = float("nan")) -> str:
    """The line on a doubtful gap ("" when the gap is not doubtful).

    ``vfcli flow`` reads the gap's edges two ways and warns when the sampled glottal area moves by more than
    :data:`vfcli.flow.gap.subpixel.ambiguity.AMBIGUOUS_AREA` between them (a medial wall in shade beside one edge:
    that fold's side of the gap read too wide, widened seeds 4112 and 4165 by 55 and 40 %), and again with the gap level
    free where a slit rejects the level the gap shows elsewhere (a channel brighter in one part of the glottis: that
    part read too narrow, widened seed 4279 by 25 % over the glottis).  The run was fitted to
    that gap, so what the gap carries (the closure, for contact; one fold's share of the gap, for a mounting offset
    or a softer fold) may be the gap's error rather than missing physics; the diagnosis says so beside its verdict.

    edge_disagreement, level_disagreement : the ``/flow`` attributes ``edge_disagreement`` and ``level_disagreement``
        (NaN: not measured, e.g. a gap never resolved).
    """
    from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA

    carries = ("what the gap carries (the closure, for contact; one fold's share of the gap, for an offset or an "
               "asymmetry) may be the gap's error rather than missing physics")
    x, y = float(edge_disagreement), float(level_disagreement)
    if np.isfinite(x) and x > AMBIGUOUS_AREA:
        return (f"{GAP_DOUBT_START}: flow's two readings of its edges differ by {percent_size(x)} % of its area (more "
                f"than {percent_size(AMBIGUOUS_AREA)} %; /flow edge_disagreement), as beside a medial wall in shade; "
                f"{carries}")
    if np.isfinite(y) and y > AMBIGUOUS_AREA:
        return (f"{GAP_DOUBT_START}: read with the gap level free where a slit rejects the level the gap shows "
                f"elsewhere, its area differs by {percent_size(y)} % (more than {percent_size(AMBIGUOUS_AREA)} %; "
                "/flow level_disagreement), as where the channel below looks brighter in one part of the glottis; "
                f"{carries}")
    return ""
