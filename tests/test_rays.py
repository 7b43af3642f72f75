"""The one outermost-silhouette-per-ray implementation against a loop over pixels, and its users."""
import numpy as np
import pytest

from vfcli.flow.gap.opening import gap_centers, measured_silhouettes
from vfcli.flow.gap.rays import as_rays, outermost_silhouette


def _by_hand(mask: np.ndarray, lateral_axis: int, border_is_edge: bool):
    """Per ray, walk the pixels: every change of state is a silhouette point (the border too, if asked)."""
    m = mask if lateral_axis == 0 else mask.T
    n, n_rays = m.shape
    lo, hi = np.full(n_rays, np.nan), np.full(n_rays, np.nan)
    for j in range(n_rays):
        ray = [False, *m[:, j], False] if border_is_edge else list(m[:, j])
        offset = -1 if border_is_edge else 0
        points = [i + offset + 0.5 for i in range(len(ray) - 1) if ray[i] != ray[i + 1]]
        if points:
            lo[j], hi[j] = points[0], points[-1]
    return lo, hi


@pytest.mark.parametrize("lateral_axis", [0, 1])
@pytest.mark.parametrize("border_is_edge", [False, True])
def test_outermost_silhouette_matches_a_walk_along_each_ray(lateral_axis, border_is_edge):
    rng = np.random.default_rng(3)
    for density in (0.05, 0.3, 0.9):
        mask = rng.random((13, 9)) < density
        mask[:, 0] = False            # a closed ray
        mask[:, 1] = True             # all gap: no silhouette unless the border counts
        mask[0, 2], mask[-1, 2] = True, True  # gap touching both borders
        lo, hi = outermost_silhouette(mask if lateral_axis == 0 else mask.T, lateral_axis, border_is_edge)
        want = _by_hand(mask if lateral_axis == 0 else mask.T, lateral_axis, border_is_edge)
        np.testing.assert_array_equal(lo, want[0])
        np.testing.assert_array_equal(hi, want[1])


def test_the_border_counts_only_when_asked():
    mask = np.zeros((6, 3), bool)
    mask[:3, 0] = True   # touches the top border: one silhouette point inside, at 2.5
    mask[:, 1] = True    # all gap
    lo, hi = outermost_silhouette(mask)
    np.testing.assert_array_equal(lo, [2.5, np.nan, np.nan])
    np.testing.assert_array_equal(hi, [2.5, np.nan, np.nan])
    lo, hi = outermost_silhouette(mask, border_is_edge=True)
    np.testing.assert_array_equal(lo, [-0.5, -0.5, np.nan])
    np.testing.assert_array_equal(hi, [2.5, 5.5, np.nan])


def test_the_opening_function_and_the_gap_term_use_the_same_silhouette():
    rng = np.random.default_rng(5)
    masks = rng.random((4, 10, 7)) < 0.2
    masks[2, :, 3] = False
    lo, hi = measured_silhouettes(masks)
    for f, mask in enumerate(masks):
        a, b = outermost_silhouette(mask)
        open_ = np.isfinite(a)
        np.testing.assert_array_equal(lo[f][open_], a[open_])
        np.testing.assert_array_equal(hi[f][open_], b[open_])
        np.testing.assert_array_equal(gap_centers(mask), 0.5 * (a + b))


def test_rays_refuse_a_bad_axis_or_shape():
    with pytest.raises(ValueError):
        as_rays(np.zeros((3, 3)), 2)
    with pytest.raises(ValueError):
        as_rays(np.zeros((2, 3, 3)), 0)
