"""Photron MRAW + CIHX/CIH: a streaming reader and an SA-X2 style writer.

Format
------
``.mraw`` holds raw frames, no header, frame after frame, row-major:

* 8 bit: one byte per pixel;
* 16 bit: little-endian uint16 per pixel (the SA-X2 saves 12 significant bits,
  "EffectiveBit Depth : 12", in the lower bits; with "EffectiveBit Side : Higher"
  (CIHX ``<effectiveBit><side>``) in the higher bits: read shifted down by
  16 - 12 bits, so the values are 0..4095 either way; the same for 8 bit);
* 12 bit packed: two pixels in three bytes, big-endian:
  ``p0 = b0 << 4 | b1 >> 4``, ``p1 = (b1 & 0x0F) << 8 | b2``.

The metadata lies beside it in ``<stem>.cihx`` (PFV 4: a short binary block,
then UTF-8 XML ``<cih> ... </cih>``) or ``<stem>.cih`` (older PFV: ``key : value``
text lines). :mod:`vfcli.io.video.photron_cih` parses both without pyMRAW (whose numba
import costs about a second) and checks them; the reader here checks them against the
MRAW size.

pyMRAW decodes a 12-bit file whole; :class:`MrawSource` instead seeks to
``frame_index * W * H * 12 / 8`` and decodes frame ranges with vectorised
numpy (:func:`unpack_12bit`), so a 4 GB recording streams in bounded memory.
"""
from __future__ import annotations

import datetime as _dt
import logging
import struct
from pathlib import Path
from typing import Iterable, Iterator
from xml.sax.saxutils import escape

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import require_file
from vfcli.io.video.photron_cih import SUPPORTED_BITS, read_cih
from vfcli.io.video.base import FrameBatch, VideoMeta, VideoSource, register_reader

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- 12-bit codec

#: Pixel pairs decoded per step: small enough to stay in the CPU cache (about 2x
#: faster than one pass over a whole batch).
_UNPACK_CHUNK = 1 << 16


def unpack_12bit(raw: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Decode packed big-endian 12-bit pixels.

    Parameters
    ----------
    raw : (3 n,) uint8
        Packed bytes, two pixels per three bytes.
    out : (2 n,) uint16, optional
        Where to write the result.

    Returns
    -------
    (2 n,) uint16
        Pixel values 0..4095.
    """
    g = np.asarray(raw, dtype=np.uint8).reshape(-1, 3)
    n = g.shape[0]
    if out is None:
        out = np.empty(2 * n, np.uint16)
    pairs = out.reshape(-1, 2)
    word = np.empty((min(_UNPACK_CHUNK, max(n, 1)), 4), np.uint8)  # little-endian b2 b1 b0 0
    word[:, 3] = 0
    for a in range(0, n, _UNPACK_CHUNK):
        b = min(n, a + _UNPACK_CHUNK)
        w = word[: b - a]
        w[:, 0] = g[a:b, 2]
        w[:, 1] = g[a:b, 1]
        w[:, 2] = g[a:b, 0]
        v = w.view("<u4").reshape(-1)
        np.right_shift(v, 12, out=pairs[a:b, 0], casting="unsafe")
        np.bitwise_and(v, 0xFFF, out=pairs[a:b, 1], casting="unsafe")
    return out


def pack_12bit(values: np.ndarray) -> np.ndarray:
    """Encode uint values 0..4095 as packed big-endian 12-bit bytes.

    Parameters
    ----------
    values : (2 n,) integer array
        Even number of pixel values, each < 4096.

    Returns
    -------
    (3 n,) uint8
    """
    pairs = np.asarray(values).reshape(-1, 2)
    n = pairs.shape[0]
    out = np.empty((n, 3), np.uint8)
    v = np.empty(min(_UNPACK_CHUNK, max(n, 1)), "<u4")
    for a in range(0, n, _UNPACK_CHUNK):
        b = min(n, a + _UNPACK_CHUNK)
        w = v[: b - a]
        w[...] = pairs[a:b, 0]
        w <<= 12
        w |= pairs[a:b, 1].astype("<u4", copy=False)
        by = w.view(np.uint8).reshape(-1, 4)
        out[a:b, 0] = by[:, 2]
        out[a:b, 1] = by[:, 1]
        out[a:b, 2] = by[:, 0]
    return out.reshape(-1)


def high_bits_down(frames: np.ndarray, shift: int, first: int, path: Path) -> np.ndarray:
    """``frames`` (k, H, W) whose effective bits are the high ones (EffectiveBit Side Higher), shifted
    down by ``shift`` bits in place: counts from 0. ``first``: index of frames[0] in the file.

    Raises
    ------
    InputDataError
        A pixel with any of the ``shift`` low bits set: the stated side does not fit the data.
    """
    low = (frames & np.asarray((1 << shift) - 1, frames.dtype)).reshape(len(frames), -1).any(axis=1)
    if low.any():
        i = int(np.argmax(low))
        raise InputDataError(f"frame {first + i} has pixels with some of their {shift} low bits set, but the "
                             "metadata says the effective bits are the high ones (EffectiveBit Side Higher): "
                             "wrong side or bit depth in the .cih/.cihx", path)
    frames >>= shift
    return frames


# --------------------------------------------------------------------------- metadata

def find_mraw_pair(path: str | Path) -> tuple[Path, Path]:
    """``(mraw, cih)`` paths for an ``.mraw``, ``.cihx`` or ``.cih`` file.

    Raises
    ------
    InputDataError
        When the partner file is missing.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".mraw":
        for suffix in (".cihx", ".cih", ".CIHX", ".CIH"):
            cand = p.with_suffix(suffix)
            if cand.is_file():
                return p, cand
        raise InputDataError(
            f"no {p.stem}.cihx or {p.stem}.cih metadata file next to the MRAW "
            "(the frame size and rate are stored there)", p)
    if ext in (".cihx", ".cih"):
        for suffix in (".mraw", ".MRAW"):
            cand = p.with_suffix(suffix)
            if cand.is_file():
                return cand, p
        raise InputDataError(f"no {p.stem}.mraw next to the {ext} metadata file", p)
    raise InputDataError(f"not a Photron file (expected .mraw, .cihx or .cih), got {p.suffix!r}", p)


# --------------------------------------------------------------------------- reader

#: Default batch of :meth:`MrawSource.iter_lazy_frames`, bytes of decoded frames: reading
#: is cheap there (decoding happens on indexing), so batches can be small.
LAZY_BATCH_BYTES = 8 * 2**20


class MrawSource(VideoSource):
    """Streaming reader of an MRAW + CIHX/CIH pair (8, 12 packed or 16 bit).

    Frames are read by seeking to ``index * frame_bytes``: memory use is one
    batch, whatever the file size. Yields uint8 (8 bit) or uint16 (12/16 bit).
    """

    def __init__(self, path: str | Path) -> None:
        mraw, cih_path = find_mraw_pair(path)
        info = read_cih(cih_path)
        mraw = require_file(mraw, "MRAW file")
        w, h, bits = info["width"], info["height"], info["bit_depth"]
        self.frame_bytes = w * h * bits // 8
        size = mraw.stat().st_size
        if size % self.frame_bytes:
            raise InputDataError(
                f"size {size} bytes is not a whole number of {w} x {h} x {bits}-bit frames "
                f"({self.frame_bytes} bytes each): truncated file or wrong {cih_path.name}",
                mraw)
        n_file = size // self.frame_bytes
        if n_file < info["n_frames"]:
            raise InputDataError(
                f"truncated: holds {n_file} frames but {cih_path.name} says "
                f"{info['n_frames']}", mraw)
        if n_file > info["n_frames"]:
            raise InputDataError(
                f"holds {n_file} frames but {cih_path.name} says {info['n_frames']}: "
                "the metadata does not belong to this MRAW", mraw)
        sf = info["start_frame"]
        n = info["n_frames"]
        self.mraw_path = mraw
        self.cih = info
        self.meta = VideoMeta(
            path=str(mraw), kind="photron", n_frames=n, height=h, width=w,
            dtype=np.dtype(np.uint8 if bits == 8 else np.uint16),
            bit_depth=info["effective_bits"], fps=info["fps"], start_frame=sf,
            trigger_index=(-sf if 0 <= -sf < n else None),
            description=(f"Photron MRAW {bits}-bit ({info['effective_bits']} effective"
                         f"{', in the high bits' if info['effective_side'] == 'higher' else ''}), "
                         f"{info['camera']}, {cih_path.name}; {info['comment']}").strip("; "),
            packed_bits=12 if bits == 12 else None,
        )
        self.stored_bits = bits
        #: bits the effective bits lie above the low bit (EffectiveBit Side Higher), shifted out on reading
        self.shift = bits - info["effective_bits"] if info["effective_side"] == "higher" and bits != 12 else 0
        self._raw = np.empty(0, np.uint8)
        self._fh = open(mraw, "rb")

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def _read_raw(self, start: int, stop: int, into: np.ndarray | None = None) -> np.ndarray:
        """The stored bytes of frames ``start..stop-1``, ``(k * frame_bytes,)`` uint8.

        Read into ``into`` when given (large enough), else into a new array.
        """
        nbytes = (stop - start) * self.frame_bytes
        raw = np.empty(nbytes, np.uint8) if into is None else into[:nbytes]
        self._fh.seek(start * self.frame_bytes)
        got = self._fh.readinto(memoryview(raw))
        if got != nbytes:
            raise InputDataError(
                f"file shrank while reading: frames {start}..{stop} incomplete", self.mraw_path)
        return raw

    def _read_range(self, start: int, stop: int) -> np.ndarray:
        k = stop - start
        h, w = self.meta.height, self.meta.width
        if self.stored_bits == 12:
            if self._raw.size < k * self.frame_bytes:           # reused read buffer
                self._raw = np.empty(k * self.frame_bytes, np.uint8)
            return unpack_12bit(self._read_raw(start, stop, self._raw)).reshape(k, h, w)
        raw = self._read_raw(start, stop).view("<u2" if self.stored_bits == 16 else np.uint8)
        frames = raw.astype(self.meta.dtype, copy=False).reshape(k, h, w)
        return frames if not self.shift else high_bits_down(frames, self.shift, start, self.mraw_path)

    def iter_lazy_frames(self, start: int = 0, stop: int | None = None,
                         roi: tuple[int, int, int, int] | None = None,
                         batch: int | None = None) -> Iterator[FrameBatch]:
        """As :meth:`VideoSource.iter_lazy_frames`: 12-bit batches are read here and
        decoded frame by frame on indexing (:class:`Packed12Frames`)."""
        if self.stored_bits != 12:
            yield from self.iter_frames(start, stop, roi, batch)
            return
        if batch is None:  # small reads: the decoding threads start sooner
            batch = max(1, LAZY_BATCH_BYTES // self.meta.frame_nbytes)
        start, stop, batch = self._check_range(start, stop, batch)
        rows, cols = self._roi_slices(roi)
        for b0 in range(start, stop, batch):
            b1 = min(b0 + batch, stop)
            yield Packed12Frames(self._read_raw(b0, b1), self.meta.height, self.meta.width, rows, cols)


class Packed12Frames:
    """A batch of 12-bit packed frames, decoded one by one on indexing (a FrameBatch).

    Parameters
    ----------
    raw : (k * H * W * 3 / 2,) uint8
        The frames' packed bytes (kept, not copied).
    height, width : int
        Stored frame size, pixels.
    rows, cols : slice
        Window kept of each frame.
    """

    dtype = np.dtype(np.uint16)

    def __init__(self, raw: np.ndarray, height: int, width: int, rows: slice, cols: slice) -> None:
        self._raw = raw
        self._hw = (height, width)
        self._frame_bytes = height * width * 3 // 2
        self._window = (rows, cols)
        k = raw.size // self._frame_bytes
        self.shape = (k, *(len(range(*s.indices(n))) for s, n in zip(self._window, self._hw)))

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def whole_frames(self) -> bool:
        """True when the window keeps the whole stored frame (no crop)."""
        return self.shape[1:] == self._hw

    def _check_index(self, i: int) -> None:
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} of a batch of {len(self)}")

    def packed(self, i: int) -> np.ndarray | None:
        """Frame ``i`` as stored: ``(H * W * 3 / 2,)`` uint8 packed big-endian 12-bit pixels
        (a view of the batch's bytes, not decoded), or None when the batch crops a window.
        """
        self._check_index(i)
        if not self.whole_frames:
            return None
        fb = self._frame_bytes
        return self._raw[i * fb:(i + 1) * fb]

    def __getitem__(self, i: int) -> np.ndarray:
        """Frame ``i``, (H', W') uint16 counts (a new array)."""
        self._check_index(i)
        fb = self._frame_bytes
        frame = unpack_12bit(self._raw[i * fb:(i + 1) * fb]).reshape(self._hw)
        if self.whole_frames:
            return frame
        rows, cols = self._window
        return np.ascontiguousarray(frame[rows, cols])


register_reader("photron", MrawSource, (".mraw", ".cihx", ".cih"))


# --------------------------------------------------------------------------- writer

#: Stand-in for the binary block PFV writes before the CIHX XML. Readers (pyMRAW,
#: vfcli) skip everything before ``<cih>``; the content is not interpreted.
CIHX_PREFIX_LEN = 16


def _cihx_text(meta: dict) -> str:
    e = {k: escape(str(v)) for k, v in meta.items()}
    return f"""<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>
<cih>
  <fileInfo>
    <date>{e['date']}</date>
    <time>{e['time']}</time>
  </fileInfo>
  <deviceInfo>
    <deviceName>{e['camera']}</deviceName>
  </deviceInfo>
  <recordInfo>
    <recordRate>{e['fps']}</recordRate>
    <shutterSpeed>{e['shutter_s']}</shutterSpeed>
  </recordInfo>
  <frameInfo>
    <totalFrame>{e['n_frames']}</totalFrame>
    <recordedFrame>{e['n_frames']}</recordedFrame>
    <startFrame>{e['start_frame']}</startFrame>
  </frameInfo>
  <imageDataInfo>
    <resolution>
      <width>{e['width']}</width>
      <height>{e['height']}</height>
    </resolution>
    <colorInfo>
      <type>Mono</type>
      <bit>{e['bit_depth']}</bit>
    </colorInfo>
    <effectiveBit>
      <depth>{e['effective_bits']}</depth>
      <side>Lower</side>
    </effectiveBit>
  </imageDataInfo>
  <imageFileInfo>
    <fileFormat>MRaw</fileFormat>
  </imageFileInfo>
  <basicInfo>
    <comment>{e['comment']}</comment>
  </basicInfo>
</cih>
"""


def _cih_text(meta: dict) -> str:
    lines = [
        "#Camera Information Header",
        f"Date : {meta['date']}", f"Time : {meta['time']}",
        f"Camera Type : {meta['camera']}",
        f"Record Rate(fps) : {meta['fps']}",
        f"Shutter Speed(s) : {meta['shutter_s']}",
        f"Total Frame : {meta['n_frames']}",
        f"Original Total Frame : {meta['n_frames']}",
        f"Start Frame : {meta['start_frame']}",
        f"Image Width : {meta['width']}", f"Image Height : {meta['height']}",
        "Color Type : Mono", f"Color Bit : {meta['bit_depth']}", "File Format : MRaw",
        f"EffectiveBit Depth : {meta['effective_bits']}", "EffectiveBit Side : Lower",
        f"Comment Text : {meta['comment']}",
    ]
    return "\n".join(lines) + "\n\nEND\n"


def write_mraw(
    path: str | Path,
    frames: Iterable[np.ndarray],
    fps: float,
    bit_depth: int = 12,
    start_frame: int = 0,
    camera: str = "FASTCAM SA-X2 (vfcli phantom)",
    comment: str = "",
    shutter_s: float | None = None,
    metadata: str = "cihx",
) -> tuple[Path, Path]:
    """Write frames as a Photron MRAW plus CIHX (default) or CIH, streaming.

    Parameters
    ----------
    path : str or Path
        Output path; its stem names ``<stem>.mraw`` and ``<stem>.cihx``/``.cih``.
    frames : iterable of (H, W) or (k, H, W) integer arrays
        Pixel counts, each < 2**min(bit_depth, 12) for 12/16 bit (16-bit files
        carry 12 effective bits, like the SA-X2) and < 256 for 8 bit.
    fps : float
        Record rate, frames/s.
    bit_depth : {12, 8, 16}
        Stored bits per pixel; 12 is packed (the SA-X2 format).
    start_frame : int
        Frame number of the first frame relative to the trigger.
    metadata : {'cihx', 'cih'}
        Metadata format written next to the MRAW.

    Returns
    -------
    (mraw_path, cih_path)

    Raises
    ------
    ConfigError
        Unsupported bit depth, bad fps, out-of-range or misshaped frames.
    """
    if bit_depth not in SUPPORTED_BITS:
        raise ConfigError(f"bit_depth must be one of {SUPPORTED_BITS}, got {bit_depth}")
    if not fps > 0:
        raise ConfigError(f"fps must be > 0, got {fps}")
    if metadata not in ("cihx", "cih"):
        raise ConfigError(f"metadata must be 'cihx' or 'cih', got {metadata!r}")
    effective = 8 if bit_depth == 8 else 12
    p = Path(path)
    mraw_path = p.with_suffix(".mraw")
    cih_path = p.with_suffix("." + metadata)
    mraw_path.parent.mkdir(parents=True, exist_ok=True)
    shape = None
    n = 0
    with open(mraw_path, "wb") as fh:
        for block in frames:
            block = np.asarray(block)
            if block.ndim == 2:
                block = block[None]
            if block.ndim != 3:
                raise ConfigError(f"frames must be (H, W) or (k, H, W), got shape {block.shape}")
            if block.shape[0] == 0:
                continue
            if shape is None:
                shape = block.shape[1:]
                if bit_depth == 12 and (shape[0] * shape[1]) % 2:
                    raise ConfigError(f"12-bit packing needs an even pixel count, got {shape}")
            elif block.shape[1:] != shape:
                raise ConfigError(f"frame shape changed from {shape} to {block.shape[1:]}")
            if not np.issubdtype(block.dtype, np.integer):
                raise ConfigError(f"frames must be integer counts, got {block.dtype}")
            if block.min() < 0 or block.max() >= 2**effective:
                raise ConfigError(
                    f"pixel values must lie in 0..{2**effective - 1} for {bit_depth}-bit MRAW, "
                    f"got {block.min()}..{block.max()}")
            if bit_depth == 12:
                pack_12bit(block.reshape(-1)).tofile(fh)
            elif bit_depth == 16:
                block.astype("<u2").tofile(fh)
            else:
                block.astype(np.uint8).tofile(fh)
            n += block.shape[0]
    if n == 0:
        mraw_path.unlink()
        raise ConfigError("no frames to write")
    now = _dt.datetime.now()
    meta = dict(date=now.strftime("%Y/%m/%d"), time=now.strftime("%H:%M"), camera=camera,
                fps=f"{fps:g}", shutter_s=f"{(shutter_s or 1.0 / fps):.9g}", n_frames=n,
                start_frame=int(start_frame), width=shape[1], height=shape[0],
                bit_depth=bit_depth, effective_bits=effective, comment=comment)
    if metadata == "cihx":
        body = _cihx_text(meta).encode("utf-8")
        prefix = struct.pack("<4sI8x", b"\xff\xfe\x00\x00", len(body))
        assert len(prefix) == CIHX_PREFIX_LEN
        cih_path.write_bytes(prefix + body)
    else:
        cih_path.write_text(_cih_text(meta), encoding="utf-8")
    logger.info("wrote %d frames (%d x %d, %d bit) to %s", n, shape[1], shape[0], bit_depth,
                mraw_path)
    return mraw_path, cih_path
