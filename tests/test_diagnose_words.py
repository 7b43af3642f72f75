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
