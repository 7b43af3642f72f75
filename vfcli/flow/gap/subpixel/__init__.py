"""Sub-pixel edges of the glottal gap: per-ray blurred-slit fits, smoothing, mask and area.

A binary mask can only be as good as the pixels it is cut from; :func:`segment_stream`
(used by ``vfcli flow`` unless ``flow.subpixel_edges`` is off) keeps the paper's
segmentation (:mod:`vfcli.flow.gap.detect`) as the detector and places the edges to a fraction of a
pixel: on every image line across the glottis (ray) it fits the blurred "tissue - gap -
tissue" profile (:func:`fit_slit_profiles`; gap level and blur measured once per recording,
:func:`estimate_edge_model`), smooths the edges along the glottis and in time
(:func:`smooth_edges`), and takes the pixels whose centres lie between them; the glottal area
is the integral of the edge distance (:func:`area_from_edges`).

Modules, one concern each: :mod:`.profile` (the slit model and its least-squares fit),
:mod:`.ray_edges` (the fit of every open ray of frames: windows, starts, passes, the level-free reading),
:mod:`.edge_model` (gap level and PSF of a recording), :mod:`.smoothing` (edges along the
glottis and in time), :mod:`.area` (mask and area from edges), :mod:`.segment` (frames and
streams), :mod:`.ambiguity` (how far the video pins the edges: readings compared), :mod:`.readings`
(what the sampled frames say of the gap as a whole: the rays' levels, the readings' warnings). The names below
are the package's interface.
"""
from vfcli.flow.gap.subpixel.area import GapSegmentation, area_from_edges, mask_from_edges
from vfcli.flow.gap.subpixel.edge_model import estimate_edge_model
from vfcli.flow.gap.subpixel.profile import EdgeModel, SlitFit, fit_slit_profiles, slit_profile_model
from vfcli.flow.gap.subpixel.ray_edges import fit_ray_edges, ray_windows
from vfcli.flow.gap.subpixel.segment import SubpixelGap, raw_edges, segment_gap, segment_stream
from vfcli.flow.gap.subpixel.smoothing import robustness_weights, smooth_edges

__all__ = ["EdgeModel", "GapSegmentation", "SlitFit", "SubpixelGap", "area_from_edges", "estimate_edge_model",
           "fit_ray_edges", "fit_slit_profiles", "mask_from_edges", "raw_edges", "ray_windows", "robustness_weights",
           "segment_gap", "segment_stream", "slit_profile_model", "smooth_edges"]
