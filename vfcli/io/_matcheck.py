"""Structural check of a MATLAB v5/v7 .mat file before scipy reads it.

scipy.io.loadmat (1.17) can crash the interpreter (segmentation fault) on
corrupt files, e.g. a data element tag with an unknown type, so vfcli walks the
tag structure first: every data element must have a known type and lie within
its parent; compressed elements are inflated and walked too, within a budget of
inflated bytes for the whole file (:func:`inflate_budget`: 100 times the file's size,
at least 64 MiB, at most 2 GiB), counted while inflating: a small file that inflates
past the budget (a "zip bomb") is refused before it takes the memory.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

from vfcli.errors import InputDataError

_VALID_TYPES = {1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MAX_INFLATE = 2**31
_MIN_INFLATE = 64 * 2**20
_INFLATE_RATIO = 100
_MAX_DEPTH = 32
_STEP = 16 * 2**20


def inflate_budget(file_size: int) -> int:
    """Inflated bytes a .mat file of ``file_size`` bytes may hold in all (bytes).

    Measured data (velocities, coordinates in float64) deflate by a factor of 1-10;
    100 leaves room for zero-padded arrays without letting 2 MB become 2 GiB.
    """
    return int(min(_MAX_INFLATE, max(_MIN_INFLATE, _INFLATE_RATIO * file_size)))


def check_mat5(path: str | Path) -> None:
    """Raise InputDataError unless ``path`` is a structurally sound MAT v5/v7 file."""
    p = Path(path)
    buf = p.read_bytes()
    if len(buf) < 128:
        raise InputDataError("not a MATLAB .mat file (shorter than the 128-byte header)", p)
    endian = buf[126:128]
    if endian == b"IM":
        fmt = "<"
    elif endian == b"MI":
        fmt = ">"
    else:
        raise InputDataError("not a MATLAB v5/v7 .mat file (no endian indicator)", p)
    (version,) = struct.unpack(fmt + "H", buf[124:126])
    if version == 0x0200:
        raise InputDataError("MATLAB v7.3 (HDF5) .mat files are not supported: save with -v7",
                             p)
    if version != 0x0100:
        raise InputDataError(f"unknown .mat version 0x{version:04x}", p)
    _walk(buf, 128, len(buf), fmt, 0, p, top=True, budget=[inflate_budget(len(buf))])


def _inflate(data: bytes, budget: list[int], p: Path) -> bytes:
    """Inflate ``data`` in steps, refusing as soon as the file's budget is spent."""
    d = zlib.decompressobj()
    out = bytearray()
    chunk = d.decompress(data, _STEP)
    while True:
        out += chunk
        if len(out) > budget[0]:
            raise InputDataError(f"compressed element inflates past {budget[0] // 2**20} MiB (the limit "
                                 "for a file of this size): corrupt or not measurement data", p)
        if not d.unconsumed_tail:
            break
        chunk = d.decompress(d.unconsumed_tail, _STEP)
    budget[0] -= len(out)
    return bytes(out)


def _walk(buf: bytes, pos: int, end: int, fmt: str, depth: int, p: Path, top: bool,
          budget: list[int]) -> None:
    if depth > _MAX_DEPTH:
        raise InputDataError("corrupt .mat file: nesting too deep", p)
    while pos < end:
        if end - pos < 8:
            if top or any(buf[pos:end]):
                raise InputDataError(f"corrupt .mat file: truncated data element at byte {pos}",
                                     p)
            return
        w0, w1 = struct.unpack(fmt + "II", buf[pos:pos + 8])
        if w0 >> 16:  # small data element: type and size packed in one word
            typ, n = w0 & 0xFFFF, w0 >> 16
            if n > 4 or typ not in _VALID_TYPES or typ in (_MI_MATRIX, _MI_COMPRESSED):
                raise InputDataError(f"corrupt .mat file: bad small element at byte {pos}", p)
            pos += 8
            continue
        typ, n = w0, w1
        if typ not in _VALID_TYPES:
            raise InputDataError(f"corrupt .mat file: unknown data type {typ} at byte {pos}", p)
        start, stop = pos + 8, pos + 8 + n
        if stop > end:
            raise InputDataError(f"corrupt .mat file: element at byte {pos} runs past its end "
                                 "(truncated file?)", p)
        if typ == _MI_MATRIX:
            _walk(buf, start, stop, fmt, depth + 1, p, top=False, budget=budget)
        elif typ == _MI_COMPRESSED:
            try:
                inner = _inflate(buf[start:stop], budget, p)
            except zlib.error as exc:
                raise InputDataError(f"corrupt .mat file: bad compressed element ({exc})",
                                     p) from None
            _walk(inner, 0, len(inner), fmt, depth + 1, p, top=False, budget=budget)
            del inner
        pos = stop if typ == _MI_COMPRESSED else stop + (-n) % 8
