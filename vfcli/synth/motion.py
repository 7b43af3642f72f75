"""Periodic motion as a truncated Fourier series over one cycle, evaluated at any time."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PeriodicMotion:
    """Vertex displacements periodic in the cycle phase.

    Attributes
    ----------
    coeffs : (K + 1, N, 3) complex, mm: ``u(phi) = Re sum_k coeffs[k] exp(2 pi i k phi)``
        (``coeffs[0]`` real mean; harmonics carry the factor 2 of the one-sided series).
    """

    coeffs: np.ndarray

    @classmethod
    def from_samples(cls, samples: np.ndarray, n_harmonics: int) -> "PeriodicMotion":
        """Fit from ``samples`` (P, N, 3) at phases ``arange(P) / P`` (band-limited to n_harmonics)."""
        p = samples.shape[0]
        if n_harmonics > p // 2 - 1:
            raise ValueError(f"{p} phase samples resolve at most {p // 2 - 1} harmonics, asked {n_harmonics}")
        spec = np.fft.rfft(samples, axis=0) / p
        spec[1:] *= 2.0
        return cls(spec[: n_harmonics + 1])

    @property
    def n_harmonics(self) -> int:
        return self.coeffs.shape[0] - 1

    def _basis(self, phase: np.ndarray, derivative: int) -> np.ndarray:
        k = np.arange(self.n_harmonics + 1)
        e = np.exp(2j * np.pi * np.outer(np.asarray(phase, float), k))
        return e * (2j * np.pi * k) ** derivative

    def displacement(self, phase: np.ndarray) -> np.ndarray:
        """(T, N, 3) mm at cycle phases ``phase`` (T,) (in cycles)."""
        return np.real(np.tensordot(self._basis(phase, 0), self.coeffs, axes=(1, 0)))

    def velocity(self, phase: np.ndarray, f0_hz: float) -> np.ndarray:
        """(T, N, 3) mm/s at phases ``phase`` for a cycle frequency ``f0_hz``."""
        return f0_hz * np.real(np.tensordot(self._basis(phase, 1), self.coeffs, axes=(1, 0)))
