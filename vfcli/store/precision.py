"""Stored precision of large float fields: float32 values rounded to fewer significant bits.

A float32 carries 24 significant bits (23 stored); the velocity fields vfcli computes are
uncertain in their third significant digit, so the low bits are noise that gzip cannot
compress. :func:`round_mantissa` rounds each value to ``bits`` stored mantissa bits (round to
nearest, ties to even), keeping the dtype: every reader (vfcli, h5py, xarray, MATLAB) reads
float32 as before, and the shuffle + gzip filter stores the zeroed low bits almost for free.
"""
from __future__ import annotations

import numpy as np

_STORED_BITS = 23  # float32 mantissa bits


def round_mantissa(values: np.ndarray, bits: int) -> np.ndarray:
    """``values`` (float32, any shape) rounded to ``bits`` stored mantissa bits (1..23), as a new
    float32 array. The relative error of each finite value is at most ``2 ** -(bits + 1)``;
    NaN, infinities and values that would round past the largest float32 are kept as they are.

    Raises
    ------
    ValueError
        Not float32, or ``bits`` outside 1..23.
    """
    a = np.asarray(values)
    if a.dtype != np.float32:
        raise ValueError(f"round_mantissa needs float32 values, got {a.dtype}")
    if not 1 <= bits <= _STORED_BITS:
        raise ValueError(f"bits = {bits}: must be 1..{_STORED_BITS}")
    if bits == _STORED_BITS:
        return a.copy()
    drop = _STORED_BITS - bits
    u = np.ascontiguousarray(a).view(np.uint32)
    half = np.uint32((1 << (drop - 1)) - 1)
    odd = (u >> np.uint32(drop)) & np.uint32(1)  # ties to even
    rounded = ((u + half + odd) & np.uint32((0xFFFFFFFF << drop) & 0xFFFFFFFF)).view(np.float32)
    return np.where(np.isfinite(a) & np.isfinite(rounded), rounded, a).astype(np.float32, copy=False)
