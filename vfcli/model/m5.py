"""The M5 vocal-fold profile (Scherer et al. 2001, uniform glottis psi = 0).

The coronal (y-z) profile of one fold is built in a *profile frame*
``(s, z)``: ``s`` is the lateral distance from the most medial point of the fold
(``s = 0`` on the medial surface, ``s = depth_mm`` on the lateral wall) and ``z``
is the vertical coordinate of docs/conventions.md (flat superior surface at
``z = 0``, body below).  Going round the free contour from the superior-lateral
corner (see the project reference note "The physical set-up: numbers to build with"):

1. superior surface, flat, ``z = 0``, from ``s = D`` to ``s = R_O``;
2. exit arc, radius ``R_O``, centre ``(R_O, -R_O)``, turning 90 degrees;
3. medial surface, straight, ``s = 0``, from ``z = -R_O`` to ``z = -T``;
4. entrance arc, radius ``R_L``, centre ``(R_L, -T)``, sweeping
   ``entrance_sweep_deg``;
5. inferior surface, straight, at ``inferior_angle_deg`` below the horizontal,
   out to the lateral wall at ``s = D``;
6. lateral wall ``s = D`` (glued to the fixture), back up to ``z = 0``.

Total height ``H = T + R_L sin(a) + (D - R_L (1 - cos a)) tan(b)`` with ``a``
the entrance sweep and ``b`` the inferior angle.

In the model frame the right fold (fold 1) occupies ``y = gap/2 + s``; the left
fold (fold 0) is its mirror image ``y = -(gap/2 + s)``.  Each fold may then be
rotated about the x axis (right-handed, degrees) about its own pivot
``(y, z) = (+-gap/2, 0)`` (the nominal medial-superior edge) and shifted by
``(offset_y_mm, offset_z_mm)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


#: Names of the contour segments, in contour order (superior-lateral corner first).
#: largest angle (degrees) spanned by one chord of a discretised arc
_MAX_ARC_STEP_DEG = 30.0

SEGMENTS = ("superior", "exit_arc", "medial", "entrance_arc", "inferior", "lateral")

#: tallest profile (mm) the model builds: the tan() of an inferior angle near 90 degrees makes the
#: height H unbounded (and the mesher's memory with it); Scherer's M5 is 10.4 mm tall, the widened
#: synth draws reach 16 mm, and 40 mm is the config's largest length_mm
MAX_HEIGHT_MM = 40.0


def m5_shape_problem(shape: object, prefix: str = "") -> str | None:
    """What makes an M5 profile unbuildable, as one line naming the fields; None if it is fine.

    Parameters
    ----------
    shape : any object with the shape fields of :class:`M5Params` (``thickness_mm``,
        ``exit_radius_mm``, ``entrance_radius_mm``, ``depth_mm`` in mm; ``entrance_sweep_deg``,
        ``inferior_angle_deg`` in degrees), each already in its own range.
    prefix : put before each field name (``"mesh."`` for the config).

    The arcs must fit (R_O < T, R_O < D, the entrance arc ends medial of the lateral wall); the
    entrance arc may not turn past the inferior surface's direction (sweep + inferior angle
    <= 90 degrees; above that the contour has a concave corner there, which the mesher's cap
    triangulation cannot follow; Scherer's M5 is tangent, sum 90); and the height H may not exceed
    :data:`MAX_HEIGHT_MM` (H grows as tan(inferior angle)).
    """
    t, r_o, r_l, d = shape.thickness_mm, shape.exit_radius_mm, shape.entrance_radius_mm, shape.depth_mm
    sweep, angle = shape.entrance_sweep_deg, shape.inferior_angle_deg
    if r_o >= t:
        return f"{prefix}exit_radius_mm ({r_o}) must be smaller than {prefix}thickness_mm ({t})"
    a = math.radians(sweep)
    run = d - r_l * (1 - math.cos(a))  # lateral extent of the inferior surface, mm
    if r_o >= d or run <= 0:
        return f"{prefix}depth_mm ({d}) is too small for the exit and entrance arcs"
    if sweep + angle > 90.0 + 1e-9:
        return (f"{prefix}entrance_sweep_deg {sweep:g} + {prefix}inferior_angle_deg {angle:g} = {sweep + angle:g} deg "
                f"turns the entrance arc past the inferior surface (a concave corner in the M5 profile; "
                f"Scherer's M5 is tangent there, sum 90): {prefix}inferior_angle_deg at most {90 - sweep:g} deg "
                f"with this sweep")
    rise = t + r_l * math.sin(a)  # height at the end of the entrance arc, mm
    height = rise + run * math.tan(math.radians(angle))
    if height > MAX_HEIGHT_MM:
        largest = math.degrees(math.atan(max(MAX_HEIGHT_MM - rise, 0.0) / run))
        return (f"{prefix}inferior_angle_deg {angle:g} with {prefix}depth_mm {d:g} makes the M5 profile "
                f"{height:.4g} mm tall, more than {MAX_HEIGHT_MM:g} mm: {prefix}inferior_angle_deg at most "
                f"{math.floor(largest * 10) / 10:g} deg here")
    return None


def _pair(value: object, name: str) -> tuple[float, float]:
    arr = np.asarray(value, dtype=float).ravel()
    if arr.size == 1:
        arr = np.repeat(arr, 2)
    if arr.size != 2 or not np.all(np.isfinite(arr)):
        raise ValueError(f"M5 {name} must be one finite number or two (fold 0, fold 1), got {value!r}")
    return float(arr[0]), float(arr[1])


@dataclass(frozen=True)
class M5Params:
    """Shape and placement of the two M5 folds (all lengths mm, angles degrees).

    Parameters
    ----------
    thickness_mm : T, vertical extent from the end of the entrance arc to the
        superior surface (3.0).
    exit_radius_mm : R_O, radius of the exit (superior-medial) arc (0.987).
    entrance_radius_mm : R_L, radius of the entrance arc (1.5 = T/2).
    entrance_sweep_deg : angle swept by the entrance arc (50).
    inferior_angle_deg : angle of the inferior surface to the medial-lateral
        plane (40; 90 - sweep keeps the contour tangent-continuous).
    depth_mm : D, medial-lateral depth from the medial surface to the lateral
        wall (8.0).
    length_mm : L, anterior-posterior length of the prism along x (15.0).
    gap_mm : total pre-phonatory gap between the two medial surfaces (0.1).
    offset_y_mm, offset_z_mm : per-fold translation (fold 0, fold 1), mm.
    rotation_deg : per-fold rotation about the x axis (fold 0, fold 1), degrees,
        right-handed, about the fold's pivot (y, z) = (-+gap/2, 0).
    """

    thickness_mm: float = 3.0
    exit_radius_mm: float = 0.987
    entrance_radius_mm: float = 1.5
    entrance_sweep_deg: float = 50.0
    inferior_angle_deg: float = 40.0
    depth_mm: float = 8.0
    length_mm: float = 15.0
    gap_mm: float = 0.1
    offset_y_mm: tuple[float, float] = (0.0, 0.0)
    offset_z_mm: tuple[float, float] = (0.0, 0.0)
    rotation_deg: tuple[float, float] = field(default=(0.0, 0.0))

    def __post_init__(self) -> None:
        for name in ("offset_y_mm", "offset_z_mm", "rotation_deg"):
            object.__setattr__(self, name, _pair(getattr(self, name), name))
        for name in ("thickness_mm", "exit_radius_mm", "entrance_radius_mm", "depth_mm", "length_mm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"M5 {name} must be a positive number of mm, got {v!r}")
        if not (math.isfinite(self.gap_mm) and self.gap_mm >= 0):
            raise ValueError(f"M5 gap_mm must be >= 0, got {self.gap_mm!r}")
        if not 0 < self.entrance_sweep_deg <= 90:
            raise ValueError(f"M5 entrance_sweep_deg must be in (0, 90], got {self.entrance_sweep_deg!r}")
        if not 0 <= self.inferior_angle_deg < 90:
            raise ValueError(f"M5 inferior_angle_deg must be in [0, 90), got {self.inferior_angle_deg!r}")
        problem = m5_shape_problem(self)
        if problem is not None:
            raise ValueError(f"M5 {problem}")

    # ----------------------------------------------------------------- geometry
    @property
    def height_mm(self) -> float:
        """Total height H of the profile (mm)."""
        a = math.radians(self.entrance_sweep_deg)
        b = math.radians(self.inferior_angle_deg)
        r_l = self.entrance_radius_mm
        return self.thickness_mm + r_l * math.sin(a) + (self.depth_mm - r_l * (1 - math.cos(a))) * math.tan(b)

    @property
    def split_z_mm(self) -> float:
        """z of the superior/inferior side split: middle of the medial straight (mm)."""
        return -0.5 * (self.exit_radius_mm + self.thickness_mm)

    def segments(self) -> list[tuple[str, str, tuple]]:
        """Contour segments in profile coordinates (s, z), in contour order.

        Returns
        -------
        list of (name, kind, data): kind ``"line"`` with data ``(p0, p1)``, or
        ``"arc"`` with data ``(centre, radius, angle0, angle1)`` (radians, the
        point is ``centre + radius * (cos, sin)``).
        """
        d, t, r_o, r_l = self.depth_mm, self.thickness_mm, self.exit_radius_mm, self.entrance_radius_mm
        a = math.radians(self.entrance_sweep_deg)
        h = self.height_mm
        end_arc = (r_l * (1 - math.cos(a)), -t - r_l * math.sin(a))
        return [
            ("superior", "line", ((d, 0.0), (r_o, 0.0))),
            ("exit_arc", "arc", ((r_o, -r_o), r_o, math.pi / 2, math.pi)),
            ("medial", "line", ((0.0, -r_o), (0.0, -t))),
            ("entrance_arc", "arc", ((r_l, -t), r_l, math.pi, math.pi + a)),
            ("inferior", "line", (end_arc, (d, -h))),
            ("lateral", "line", ((d, -h), (d, 0.0))),
        ]

    def area_mm2(self) -> float:
        """Analytic cross-section area of one fold (mm^2), by Green's theorem.

        The contour runs counter-clockwise in (s, z) (s to the right, z up); the
        enclosed area is ``1/2 * closed-integral (s dz - z ds)``, exact for lines
        and arcs.
        """
        total = 0.0
        for _, kind, data in self.segments():
            if kind == "line":
                (s0, z0), (s1, z1) = data
                total += 0.5 * (s0 * z1 - s1 * z0)
            else:
                (cs, cz), r, a0, a1 = data
                total += 0.5 * (r * r * (a1 - a0) + r * (cs * (math.sin(a1) - math.sin(a0))
                                                       - cz * (math.cos(a1) - math.cos(a0))))
        return abs(total)

    def volume_mm3(self) -> float:
        """Analytic volume of one fold: area * length (mm^3)."""
        return self.area_mm2() * self.length_mm

    def contour(self, target_edge_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Closed polyline of the profile, edges no longer than ``target_edge_mm``.

        The medial straight is cut at its middle so that the side split
        (:attr:`split_z_mm`) is a contour vertex.

        Returns
        -------
        points : (P, 2) float64, (s, z) mm, counter-clockwise, superior-lateral corner
            first, not repeated at the end.
        segment : (P,) int, index into :data:`SEGMENTS` of the edge that starts
            at each point.
        """
        pts: list[np.ndarray] = []
        seg: list[np.ndarray] = []
        for k, (name, kind, data) in enumerate(self.segments()):
            if kind == "line":
                p0, p1 = np.asarray(data[0]), np.asarray(data[1])
                pieces = [(p0, p1)]
                if name == "medial":
                    mid = 0.5 * (p0 + p1)
                    pieces = [(p0, mid), (mid, p1)]
                for q0, q1 in pieces:
                    n = max(1, math.ceil(float(np.hypot(*(q1 - q0))) / target_edge_mm - 1e-9))
                    f = np.arange(n)[:, None] / n
                    pts.append(q0 + f * (q1 - q0))
                    seg.append(np.full(n, k))
            else:
                (cs, cz), r, a0, a1 = data
                n = max(math.ceil(r * abs(a1 - a0) / target_edge_mm - 1e-9),
                        math.ceil(abs(a1 - a0) / math.radians(_MAX_ARC_STEP_DEG) - 1e-9))
                ang = a0 + (a1 - a0) * np.arange(n) / n
                pts.append(np.column_stack([cs + r * np.cos(ang), cz + r * np.sin(ang)]))
                seg.append(np.full(n, k))
        return np.concatenate(pts), np.concatenate(seg)

    def place(self, profile_points: np.ndarray, fold: int) -> np.ndarray:
        """Map points from the profile frame to the model frame.

        Parameters
        ----------
        profile_points : (N, 3) float64, (x, s, z) mm.
        fold : 0 (left, y < 0) or 1 (right, y > 0).

        Returns
        -------
        (N, 3) float64 model-frame (x, y, z) mm, mirrored, rotated and shifted.
        """
        p = np.asarray(profile_points, dtype=float)
        sign = -1.0 if fold == 0 else 1.0
        y = sign * (0.5 * self.gap_mm + p[:, 1])
        z = p[:, 2].copy()
        pivot_y = sign * 0.5 * self.gap_mm
        th = math.radians(self.rotation_deg[fold])
        c, s = math.cos(th), math.sin(th)
        dy, dz = y - pivot_y, z
        y_r = pivot_y + c * dy - s * dz + self.offset_y_mm[fold]
        z_r = s * dy + c * dz + self.offset_z_mm[fold]
        return np.column_stack([p[:, 0], y_r, z_r])


def m5_params_from(settings: object) -> M5Params:
    """M5Params from any settings object (e.g. the [mesh] config) with the same field names."""
    from dataclasses import fields

    return M5Params(**{f.name: getattr(settings, f.name) for f in fields(M5Params)})
