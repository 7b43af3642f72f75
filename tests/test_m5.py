"""M5 profile: published heights, analytic area, placement of the two folds."""
import math

import numpy as np
import pytest

from vfcli.model.m5 import M5Params


@pytest.mark.parametrize("depth, height", [(5.0, 7.895), (8.0, 10.41)])
def test_height_matches_published_formula_values(depth, height):
    p = M5Params(depth_mm=depth)
    assert p.height_mm == pytest.approx(height, abs=1e-3 if depth == 5.0 else 5e-3)
    contour, _ = p.contour(0.1)
    assert contour[:, 1].min() == pytest.approx(-p.height_mm, abs=1e-12)


def test_contour_is_closed_tangent_continuous_and_round():
    p = M5Params()
    ends = []
    for _, kind, data in p.segments():
        if kind == "line":
            ends.append((np.array(data[0]), np.array(data[1])))
        else:
            (cs, cz), r, a0, a1 = data
            ends.append((np.array([cs + r * math.cos(a0), cz + r * math.sin(a0)]),
                         np.array([cs + r * math.cos(a1), cz + r * math.sin(a1)])))
    for (_, end), (start, _) in zip(ends, ends[1:] + ends[:1]):
        np.testing.assert_allclose(end, start, atol=1e-12)
    # medial straight has length T - R_O = 2.013 mm, entrance arc ends on the 40 degree slope
    assert ends[2][0][1] - ends[2][1][1] == pytest.approx(2.013, abs=1e-12)
    slope = ends[4][1] - ends[4][0]
    assert math.degrees(math.atan2(-slope[1], slope[0])) == pytest.approx(40.0)


def test_analytic_area_equals_fine_polygon_area():
    p = M5Params()
    contour, _ = p.contour(0.002)
    s, z = contour[:, 0], contour[:, 1]
    poly = 0.5 * np.sum(s * np.roll(z, -1) - np.roll(s, -1) * z)
    assert poly > 0  # counter-clockwise
    assert p.area_mm2() == pytest.approx(poly, rel=1e-6)
    # independent bound: the profile lies inside the D x H box minus the triangle under the slope
    assert p.area_mm2() < p.depth_mm * p.height_mm
    assert p.volume_mm3() == pytest.approx(p.area_mm2() * 15.0)


def test_split_point_is_a_contour_vertex_in_the_middle_of_the_medial_surface():
    p = M5Params()
    contour, seg = p.contour(1.5)
    hit = np.flatnonzero((np.abs(contour[:, 0]) < 1e-12) & (np.abs(contour[:, 1] - p.split_z_mm) < 1e-12))
    assert len(hit) == 1
    assert p.split_z_mm == pytest.approx(-(0.987 + 3.0) / 2)


def test_folds_are_mirror_images_then_offset_and_rotated():
    pts = np.array([[1.0, 0.0, 0.0], [2.0, 3.0, -4.0]])
    p = M5Params(gap_mm=0.2)
    left, right = p.place(pts, 0), p.place(pts, 1)
    np.testing.assert_allclose(left, right * [1, -1, 1])
    assert right[0, 1] == pytest.approx(0.1)
    q = M5Params(gap_mm=0.2, offset_y_mm=(0.0, 0.5), offset_z_mm=(-0.3, 0.0), rotation_deg=(0.0, 90.0))
    moved = q.place(pts, 1)
    # rotation by +90 deg about x around the pivot (0.1, 0): (dy, dz) = (3, -4) -> (4, 3)
    np.testing.assert_allclose(moved[1], [2.0, 0.1 + 4.0 + 0.5, 3.0])
    np.testing.assert_allclose(q.place(pts, 0), left + [0, 0, -0.3])


@pytest.mark.parametrize("kwargs", [
    {"exit_radius_mm": 3.0}, {"depth_mm": -1.0}, {"gap_mm": -0.1}, {"entrance_sweep_deg": 120.0},
    {"offset_y_mm": (1.0, 2.0, 3.0)}, {"depth_mm": 0.5},
])
def test_invalid_shapes_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        M5Params(**kwargs)


@pytest.mark.parametrize("override, field", [
    ("mesh.exit_radius_mm=3.5", "exit_radius_mm"), ("mesh.depth_mm=2.5", "depth_mm"),
])
def test_the_config_refuses_shapes_the_model_would_reject(override, field):
    """A [mesh] section the M5 model rejects is a user error (ConfigError naming the field), caught by the config."""
    from vfcli.config import load_config
    from vfcli.errors import ConfigError

    extra = ["mesh.entrance_radius_mm=5", "mesh.entrance_sweep_deg=90"] if field == "depth_mm" else []
    with pytest.raises(ConfigError, match=field):
        load_config(overrides=[override, *extra])


def test_every_mesh_config_the_config_accepts_builds_an_m5_profile():
    """Random [mesh] values inside the config's bounds: the config refuses them, or M5Params accepts them and
    the mesher triangulates their profile."""
    from vfcli.config import MeshConfig
    from vfcli.model.m5 import m5_params_from
    from vfcli.model.mesh import _cap_triangulation

    rng = np.random.default_rng(0)
    bounds = {"thickness_mm": (0.5, 10), "exit_radius_mm": (0.05, 5), "entrance_radius_mm": (0.05, 5),
              "entrance_sweep_deg": (0, 90), "inferior_angle_deg": (0, 89.9), "depth_mm": (2, 20),
              "length_mm": (2, 40), "gap_mm": (0, 2)}
    accepted = refused = 0
    for _ in range(400):
        values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in bounds.items()}
        try:
            cfg = MeshConfig(**values)
        except ValueError:  # pydantic's ValidationError
            refused += 1
            continue
        params = m5_params_from(cfg)
        _cap_triangulation(params.contour(1.5)[0], 1.5)  # raises on a non-convex profile
        accepted += 1
    assert accepted > 50 and refused > 50


def _shape(**changes):
    """The M5 fields with their defaults, some changed, as any settings object (no validation)."""
    from dataclasses import fields
    from types import SimpleNamespace

    return SimpleNamespace(**{**{f.name: f.default for f in fields(M5Params)}, **changes})


def _height_limited_angle(sweep_deg, **changes):
    """The inferior angle (degrees) at which the profile is exactly MAX_HEIGHT_MM tall."""
    from vfcli.model.m5 import MAX_HEIGHT_MM

    s = _shape(entrance_sweep_deg=sweep_deg, **changes)
    a = math.radians(sweep_deg)
    rise = MAX_HEIGHT_MM - s.thickness_mm - s.entrance_radius_mm * math.sin(a)
    return math.degrees(math.atan(rise / (s.depth_mm - s.entrance_radius_mm * (1 - math.cos(a)))))


@pytest.mark.parametrize("changes", [
    {},                                                          # Scherer's M5: sweep + angle = 90, tangent
    {"entrance_sweep_deg": 30.0, "inferior_angle_deg": 60.0},    # tangent too
    {"entrance_sweep_deg": 30.0, "inferior_angle_deg": 59.999},  # convex corner
    {"entrance_sweep_deg": 90.0, "inferior_angle_deg": 0.0},
    {"entrance_sweep_deg": 1.0, "inferior_angle_deg": _height_limited_angle(1.0) - 0.01},
    {"entrance_sweep_deg": 5.0, "inferior_angle_deg": _height_limited_angle(5.0, depth_mm=20.0, thickness_mm=10.0) - 0.01,
     "depth_mm": 20.0, "thickness_mm": 10.0, "entrance_radius_mm": 1.5},
])
def test_m5_shape_problem_accepts_convex_profiles_of_sensible_height(changes):
    from vfcli.model.m5 import MAX_HEIGHT_MM, m5_shape_problem

    assert m5_shape_problem(_shape(**changes)) is None
    p = M5Params(**changes)
    assert p.height_mm <= MAX_HEIGHT_MM
    contour, _ = p.contour(0.5)
    e_in, e_out = contour - np.roll(contour, 1, axis=0), np.roll(contour, -1, axis=0) - contour
    turn = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    assert np.all(turn >= -1e-12)  # convex: the counter-clockwise contour never turns right


@pytest.mark.parametrize("changes, names, limit", [
    ({"inferior_angle_deg": 40.001}, ("mesh.entrance_sweep_deg 50", "mesh.inferior_angle_deg 40.001"), "at most 40 deg"),
    ({"inferior_angle_deg": 60.0}, ("mesh.inferior_angle_deg 60",), "at most 40 deg"),
    ({"inferior_angle_deg": 89.99}, ("mesh.inferior_angle_deg 89.99",), "at most 40 deg"),
    ({"entrance_sweep_deg": 70.0}, ("mesh.entrance_sweep_deg 70",), "at most 20 deg"),
    ({"entrance_sweep_deg": 30.0, "inferior_angle_deg": 60.001}, ("mesh.inferior_angle_deg 60.001",), "at most 60 deg"),
    ({"entrance_sweep_deg": 1.0, "inferior_angle_deg": _height_limited_angle(1.0) + 0.01},
     ("mesh.inferior_angle_deg", "mm tall"), f"at most {math.floor(_height_limited_angle(1.0) * 10) / 10:g} deg"),
    ({"entrance_sweep_deg": 0.01, "inferior_angle_deg": 89.99}, ("mesh.inferior_angle_deg 89.99", "mm tall"), "at most"),
])
def test_m5_shape_problem_names_the_fields_and_the_largest_angle(changes, names, limit):
    """A concave corner where the entrance arc meets the inferior surface (sweep + angle > 90 deg), or a
    profile taller than MAX_HEIGHT_MM (tan of an inferior angle near 90 deg), is refused with the
    largest inferior angle that would do."""
    from vfcli.model.m5 import m5_shape_problem

    msg = m5_shape_problem(_shape(**changes), prefix="mesh.")
    assert msg is not None and "\n" not in msg
    for name in names:
        assert name in msg
    assert limit in msg
    with pytest.raises(ValueError, match="inferior_angle_deg"):
        M5Params(**changes)
