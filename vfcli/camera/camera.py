"""Orthographic superior-view camera: the projection between model mm and image px.

The camera looks down the -z axis (docs/conventions.md)::

    [col, row] = px_per_mm * R(rotation_deg) @ [x, y] + offset_px

with ``R(theta) = [[cos, -sin], [sin, cos]]`` and pixel centres at integer
``(col, row)``.  ``z`` is depth: where several surfaces cover one pixel, the
one with the LARGEST z (closest to the camera) is visible.

The rasteriser that finds what each pixel sees is :mod:`vfcli.camera.raster`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Orthographic camera looking down -z.

    Parameters
    ----------
    px_per_mm : scale, pixels per mm (> 0).
    rotation_deg : rotation of the model (x, y) axes in the image, degrees
        (counter-clockwise from the column axis towards the row axis).
    offset_px : (2,) pixel coordinates ``(col, row)`` of the model origin.
    width, height : image size, pixels (columns, rows).
    """

    px_per_mm: float
    rotation_deg: float
    offset_px: tuple[float, float]
    width: int
    height: int

    def __post_init__(self) -> None:
        off = tuple(float(v) for v in np.asarray(self.offset_px, dtype=float).ravel())
        if len(off) != 2 or not all(np.isfinite(off)):
            raise ValueError(f"camera offset_px must be two finite numbers, got {self.offset_px!r}")
        object.__setattr__(self, "offset_px", off)
        if not (np.isfinite(self.px_per_mm) and self.px_per_mm > 0):
            raise ValueError(f"camera px_per_mm must be > 0, got {self.px_per_mm!r}")
        if not np.isfinite(self.rotation_deg):
            raise ValueError(f"camera rotation_deg must be finite, got {self.rotation_deg!r}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"camera size must be at least 1 x 1 px, got {self.width} x {self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)`` (rows, columns)."""
        return (self.height, self.width)

    @property
    def rotation(self) -> np.ndarray:
        """(2, 2) rotation matrix R(rotation_deg)."""
        th = np.deg2rad(self.rotation_deg)
        c, s = np.cos(th), np.sin(th)
        return np.array([[c, -s], [s, c]])

    @property
    def matrix(self) -> np.ndarray:
        """(2, 2) linear part ``px_per_mm * R``: mm (x, y) -> px (col, row)."""
        return self.px_per_mm * self.rotation

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates of points.

        Parameters
        ----------
        points : (..., 3) or (..., 2) model-frame positions, mm (z is ignored).

        Returns
        -------
        (..., 2) float64 ``(col, row)``, px.
        """
        p = np.asarray(points, dtype=float)
        return p[..., :2] @ self.matrix.T + np.asarray(self.offset_px)

    def project_vector(self, vectors: np.ndarray) -> np.ndarray:
        """Screen-space components of vectors (velocities, displacements).

        vectors : (..., 3) or (..., 2) model-frame (x, y[, z]) components, e.g. mm/s.
        Returns (..., 2) ``(d col, d row)`` in px (per the same time unit).
        """
        v = np.asarray(vectors, dtype=float)
        return v[..., :2] @ self.matrix.T

    def unproject_xy(self, px: np.ndarray) -> np.ndarray:
        """Model-frame ``(x, y)`` in mm of pixel coordinates ``(..., 2)`` ``(col, row)``."""
        q = np.asarray(px, dtype=float) - np.asarray(self.offset_px)
        return q @ np.linalg.inv(self.matrix).T

    def pixel_centres_xy(self) -> np.ndarray:
        """(H, W, 2) model-frame ``(x, y)`` (mm) of every pixel centre (read-only, cached)."""
        return _pixel_centres_xy(self)

    def supersampled(self, factor: int) -> "Camera":
        """The camera whose pixels split each of this camera's pixels into factor x factor.

        Fine pixel ``(j_col, j_row)`` covers coarse pixel ``(j_col // factor, j_row // factor)``:
        averaging factor x factor blocks of a fine image gives a box-filtered coarse image.
        """
        f = int(factor)
        if f < 1:
            raise ValueError(f"supersampling factor must be >= 1, got {factor!r}")
        shift = (f - 1) / 2.0
        off = (f * self.offset_px[0] + shift, f * self.offset_px[1] + shift)
        return Camera(self.px_per_mm * f, self.rotation_deg, off, self.width * f, self.height * f)


@lru_cache(maxsize=8)
def _pixel_centres_xy(camera: Camera) -> np.ndarray:
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    xy = camera.unproject_xy(np.stack([cols, rows], axis=-1).astype(float))
    xy.flags.writeable = False
    return xy
