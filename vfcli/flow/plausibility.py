"""Is a product plausible? Pure checks of what the LDV and field stages produce (issue 15).

* :func:`points_on_image`: the vibrometer points' screen positions lie on the video's frames
  (a scan read in the wrong length unit lands thousands of px away, and the thin-plate
  spline then extrapolates a "valid" field from nothing).
* :func:`pressure_velocity_bound`: the largest surface velocity a pressure swing can drive,
  ``max |p| / (rho c)`` (the momentum flux of a wave of speed ``c`` in tissue of density
  ``rho``), with the slowest documented mucosal wave (0.5 m/s) and a tissue density of
  1000 kg/m^3: 2 m/s per kPa, above the in-vivo closing velocities (0.3-1.6 m/s at about
  1 kPa; docs/physical-setup).
"""
from __future__ import annotations

import numpy as np

#: Tissue (or silicone) density used by the velocity bound, kg/m^3.
TISSUE_DENSITY_KG_M3 = 1000.0
#: Slowest mucosal wave speed, m/s (excised larynges: 0.5-2 m/s).
SLOWEST_WAVE_M_S = 0.5
#: "Far beyond": speeds over this multiple of :func:`pressure_velocity_bound` are flagged (a widened
#: phantom's flow reached 1.06 x the bound at its 99th percentile, a mis-scaled vibrometer 10-1000 x).
FAR_BEYOND = 2.0


def points_on_image(points_px: np.ndarray, shape: tuple[int, int], margin_px: float = 0.5) -> np.ndarray:
    """Which screen points (P, 2) (col, row) px lie on an (H, W) frame (pixel edges +- ``margin_px``).

    Returns
    -------
    (P,) bool
    """
    p = np.asarray(points_px, float).reshape(-1, 2)
    h, w = shape
    return (np.isfinite(p).all(axis=1) & (p[:, 0] >= -margin_px) & (p[:, 0] <= w - 1 + margin_px)
            & (p[:, 1] >= -margin_px) & (p[:, 1] <= h - 1 + margin_px))


def pressure_velocity_bound(pressure_pa: np.ndarray) -> float:
    """The largest surface velocity the pressure can drive, mm/s: ``max |p| / (rho c)`` (module doc).

    Parameters
    ----------
    pressure_pa : (S,) float, Pa (subglottal, as recorded: mean included)

    Returns
    -------
    float
        mm/s; NaN when no finite sample.
    """
    p = np.asarray(pressure_pa, float)
    p = p[np.isfinite(p)]
    if p.size == 0:
        return float("nan")
    return float(np.max(np.abs(p)) / (TISSUE_DENSITY_KG_M3 * SLOWEST_WAVE_M_S) * 1e3)
