"""Which fold of the video the diagnosis calls left and right (:func:`vfcli.diagnose.words.fold_side_words`)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from vfcli.camera.camera import Camera
from vfcli.diagnose.words import fold_side_words
from vfcli.model.mesh import build_mesh


@pytest.fixture(scope="module")
def mesh():
    return build_mesh(None, 2.5)


def _centres(line: str) -> list[np.ndarray]:
    found = [np.array([float(c), float(r)]) for c, r in re.findall(r"centred at col (-?\d+), row (-?\d+)", line)]
    assert len(found) == 2, line
    return found


def test_a_half_turn_of_the_camera_swaps_the_folds_it_names(mesh):
    """The ambiguity the line warns of: the camera turned by 180 deg about the glottis's centre (widened phantom
    2111: fitted at -84.2 deg for a true 95.8) puts the left fold where the right one was, so an estimated rotation
    says so and a configured one does not."""
    centre = mesh.nodes.mean(axis=0)
    cam = Camera(18.0, 95.8, (128.0, 128.0), 256, 256)
    c = np.asarray(cam.project(centre))
    turned = Camera(18.0, 95.8 - 180.0, tuple(2 * c - np.asarray(cam.offset_px)), 256, 256)   # R(t - 180) = -R(t)
    np.testing.assert_allclose(turned.project(centre), c, atol=1e-9)     # the same glottis centre in the image
    a = _centres(fold_side_words(cam, mesh, "config"))
    estimated = fold_side_words(turned, mesh, "estimated from the glottal gap (mid-length: symmetry of the motion)")
    b = _centres(estimated)
    assert np.linalg.norm(a[0] - a[1]) > 50
    np.testing.assert_allclose(a[0], b[1], atol=1.0)
    np.testing.assert_allclose(a[1], b[0], atol=1.0)
    assert "from the config)" in fold_side_words(cam, mesh, "config")
    assert "within a half turn of camera.rotation_deg" in estimated and "check which fold is which" in estimated


def test_the_stated_pixels_are_the_videos_not_the_cropped_frames(mesh):
    cam = Camera(18.0, 10.0, (100.0, 90.0), 200, 200)
    a = _centres(fold_side_words(cam, mesh, "config"))
    b = _centres(fold_side_words(cam, mesh, "config", (30.0, 12.0)))
    np.testing.assert_allclose(b[0] - a[0], [30.0, 12.0], atol=1.0)
    np.testing.assert_allclose(b[1] - a[1], [30.0, 12.0], atol=1.0)


def test_a_doubtful_gap_is_said_with_its_figure_and_what_it_may_carry():
    """flow's edge readings (/flow edge_disagreement) above its 5 % line: the diagnosis says the gap is doubtful and
    which evidence rests on it; at or below the line, or not measured, it says nothing."""
    from vfcli.diagnose.words import GAP_DOUBT_START, gap_doubt_words
    from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA

    line = gap_doubt_words(0.175)
    assert line.startswith(GAP_DOUBT_START) and "differ by 18 % of its area" in line and "more than 5 %" in line
    assert "contact" in line and "offset" in line and "asymmetry" in line
    assert gap_doubt_words(AMBIGUOUS_AREA) == "" and gap_doubt_words(0.039) == "" and gap_doubt_words(float("nan")) == ""
    # the reading with the gap level free (/flow level_disagreement): said when it alone is above the line
    level = gap_doubt_words(0.02, 0.13)
    assert level.startswith(GAP_DOUBT_START) and "level_disagreement" in level and "differs by 13 %" in level
    assert "contact" in level and gap_doubt_words(0.175, 0.13) == line
    assert gap_doubt_words(0.02, AMBIGUOUS_AREA) == "" and gap_doubt_words(float("nan"), float("nan")) == ""


def _rest_glottis(params) -> tuple[float, float]:
    """(width, midline) of the glottis at rest, mm: the folds' least lateral distance and the y half-way between
    them, from the M5 profile each fold is placed with (:meth:`vfcli.model.m5.M5Params.place`)."""
    pts, _ = params.contour(0.05)
    prism = np.column_stack([np.zeros(len(pts)), pts])          # (x, s, z) at x = 0: the profile is a prism
    left, right = (params.place(prism, fold)[:, 1] for fold in (0, 1))
    return float(right.min() - left.max()), 0.5 * float(right.min() + left.max())


@pytest.mark.parametrize("left, right", [(0.18, -0.179), (-0.05, 0.07), (0.1, 0.1), (0.3, -0.1)])
def test_the_mounting_offsets_are_read_as_the_mount_the_mesh_would_need(left, right):
    """The mounting offset's two parameters (each fold along +y) said as the folds' mounting: the glottis at rest
    narrower or wider, and the pair shifted toward one fold's side, by what the M5 geometry placed with those offsets
    gives against the same geometry without them (widened phantom 4215's one-step estimate was +0.18 and -0.179 mm
    for folds 0.32 mm nearer than the config said, docs/benchmarks.md "Session 63: frames that are not square ...")."""
    from vfcli.diagnose.candidates import MountingOffset
    from vfcli.model.m5 import M5Params

    line = MountingOffset().reading(np.array([left, right]))
    w0, m0 = _rest_glottis(M5Params(gap_mm=0.4))
    w1, m1 = _rest_glottis(M5Params(gap_mm=0.4, offset_y_mm=(left, right)))
    narrower = re.search(r"the glottis (\d+\.\d+) mm (narrower|wider) at rest", line)
    said = float(narrower.group(1)) * (1 if narrower.group(2) == "narrower" else -1)
    assert said == pytest.approx(w0 - w1, abs=0.006)
    shift = re.search(r"the pair (\d+\.\d+) mm toward the (left|right) fold's side", line)
    toward_right = float(shift.group(1)) * (1 if shift.group(2) == "right" else -1)
    right_side = np.sign(_rest_glottis(M5Params(gap_mm=0.4, offset_y_mm=(0.0, 1.0)))[1] - m0)   # where fold 1 lies
    assert toward_right == pytest.approx(right_side * (m1 - m0), abs=0.006)
    each = re.search(r"each fold (\d+\.\d+) mm (nearer|further from) the midplane", line)
    assert float(each.group(1)) == pytest.approx(abs(w0 - w1) / 2, abs=0.006)
    assert "mesh.offset_y_mm" in line and "camera.offset_px" in line


def test_a_refit_of_the_offset_says_its_estimate_as_the_mounting_too():
    """The refit's line (:func:`vfcli.diagnose.confirm.words`) carries the offset's reading after its estimate when
    it is given the refitted term, and only the estimate without it."""
    from vfcli.diagnose.candidates import MountingOffset
    from vfcli.diagnose.confirm import words
    from vfcli.diagnose.confirmation import Confirmation

    term = MountingOffset()
    conf = Confirmation("offset", term.parameter_names, np.array([0.12, -0.1]), np.array([0.02, 0.02]), run="r+offset")
    line = words(conf, term)[0]
    assert line.startswith("refit with offset (run r+offset): offset_y_left_mm = 0.12")
    assert line.endswith(term.reading(conf.estimate)) and "each fold 0.11 mm nearer the midplane" in line
    assert "read as the folds' mounting" not in words(conf)[0]
