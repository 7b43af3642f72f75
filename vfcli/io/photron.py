"""Photron MRAW + CIHX/CIH: a streaming reader and an SA-X2 style writer.

Format
------
``.mraw`` holds raw frames, no header, frame after frame, row-major:

* 8 bit: one byte per pixel;
* 16 bit: little-endian uint16 per pixel (the SA-X2 saves 12 significant bits,
  "EffectiveBit Depth : 12", in the lower bits);
* 12 bit packed: two pixels in three bytes, big-endian:
  ``p0 = b0 << 4 | b1 >> 4``, ``p1 = (b1 & 0x0F) << 8 | b2``.

The metadata lies beside it in ``<stem>.cihx`` (PFV 4: a short binary block,
then UTF-8 XML ``<cih> ... </cih>``) or ``<stem>.cih`` (older PFV: ``key : value``
text lines). pyMRAW parses both (:func:`pyMRAW.get_cih`); this module adds the
start/trigger frame and checks the metadata against the MRAW size.

pyMRAW decodes a 12-bit file whole; :class:`MrawSource` instead seeks to
``frame_index * W * H * 12 / 8`` and decodes frame ranges with vectorised
numpy (:func:`unpack_12bit`), so a 4 GB recording streams in bounded memory.
"""
from __future__ import annotations

import datetime as _dt
import logging
import struct
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Iterable
from xml.sax.saxutils import escape

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import require_file
from vfcli.io.video import VideoMeta, VideoSource, register_reader

logger = logging.getLogger(__name__)

SUPPORTED_BITS = (8, 12, 16)


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


def _cihx_xml(raw: bytes, path: Path) -> ET.Element:
    i0 = raw.find(b"<cih>")
    i1 = raw.rfind(b"</cih>")
    if i0 < 0 or i1 < i0:
        raise InputDataError("not a CIHX file: no <cih> ... </cih> XML block", path)
    try:
        return ET.fromstring(raw[i0:i1 + len(b"</cih>")].decode("utf-8", errors="replace"))
    except ET.ParseError as exc:
        raise InputDataError(f"corrupt CIHX XML: {exc}", path) from None


def read_cih(path: str | Path) -> dict:
    """Parse a ``.cihx`` or ``.cih`` file into vfcli's metadata fields.

    Returns
    -------
    dict
        ``fps`` (frames/s), ``n_frames``, ``width``, ``height``, ``bit_depth``
        (stored bits: 8, 12 or 16), ``effective_bits``, ``start_frame``,
        ``camera``, ``comment``, ``file_format`` and ``raw`` (pyMRAW's dict).

    Raises
    ------
    InputDataError
        Unreadable, corrupt or incomplete metadata, or an unsupported layout.
    """
    import pyMRAW  # heavy (numba): import only here

    p = require_file(path, "Photron metadata file")
    ext = p.suffix.lower()
    start_frame = 0
    if ext == ".cihx":
        root = _cihx_xml(p.read_bytes(), p)
        sf = root.findtext("frameInfo/startFrame")
    elif ext == ".cih":
        head = p.read_bytes()[:4096]
        if b"\x00" in head or b" : " not in head:
            raise InputDataError("not a CIH text header (no 'key : value' lines)", p)
        sf = None
    else:
        raise InputDataError(f"not a CIH/CIHX file: {p.suffix!r}", p)
    try:
        cih = pyMRAW.get_cih(str(p))
        if ext == ".cih":
            sf = cih.get("Start Frame", 0)
        info = dict(
            fps=float(cih["Record Rate(fps)"]),
            n_frames=int(cih["Total Frame"]),
            width=int(cih["Image Width"]),
            height=int(cih["Image Height"]),
            bit_depth=int(cih["Color Bit"]),
            effective_bits=int(cih.get("EffectiveBit Depth", cih["Color Bit"])),
            file_format=str(cih["File Format"]),
            camera=str(cih.get("Camera Type", "") or ""),
            comment=str(cih.get("Comment Text", "") or ""),
            color_type=str(cih.get("Color Type", "Mono") or "Mono"),
        )
        start_frame = int(float(sf)) if sf not in (None, "") else 0
    except InputDataError:
        raise
    except KeyError as exc:
        raise InputDataError(f"metadata field {exc} missing", p) from None
    except Exception as exc:  # pyMRAW/xmltodict raise bare exceptions on bad files
        raise InputDataError(f"cannot parse Photron metadata: {type(exc).__name__}: {exc}",
                             p) from None
    info["start_frame"] = start_frame
    info["raw"] = cih
    _check_cih(info, p)
    return info


def _check_cih(info: dict, p: Path) -> None:
    if info["file_format"].lower() != "mraw":
        raise InputDataError(f"File Format is {info['file_format']!r}; only MRaw is supported", p)
    if info["bit_depth"] not in SUPPORTED_BITS:
        raise InputDataError(
            f"unsupported bit depth {info['bit_depth']} (supported: 8, 12, 16)", p)
    if not 1 <= info["effective_bits"] <= info["bit_depth"]:
        raise InputDataError(
            f"effective bit depth {info['effective_bits']} not in 1..{info['bit_depth']}", p)
    if info["color_type"].lower() not in ("mono", ""):
        raise InputDataError(f"Color Type {info['color_type']!r}: only monochrome is supported", p)
    for key in ("width", "height", "n_frames"):
        if info[key] < 1:
            raise InputDataError(f"{key} is {info[key]}; must be >= 1", p)
    if not np.isfinite(info["fps"]) or info["fps"] <= 0:
        raise InputDataError(f"record rate {info['fps']} fps is not positive", p)
    if (info["width"] * info["height"] * info["bit_depth"]) % 8:
        raise InputDataError(
            f"{info['width']} x {info['height']} pixels at {info['bit_depth']} bit is not a "
            "whole number of bytes per frame: unsupported", p)


# --------------------------------------------------------------------------- reader

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
            description=(f"Photron MRAW {bits}-bit ({info['effective_bits']} effective), "
                         f"{info['camera']}, {cih_path.name}; {info['comment']}").strip("; "),
        )
        self.stored_bits = bits
        self._raw = np.empty(0, np.uint8)
        self._fh = open(mraw, "rb")

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def _read_range(self, start: int, stop: int) -> np.ndarray:
        k = stop - start
        h, w = self.meta.height, self.meta.width
        self._fh.seek(start * self.frame_bytes)
        nbytes = k * self.frame_bytes
        if self.stored_bits == 12:
            if self._raw.size < nbytes:           # reused read buffer
                self._raw = np.empty(nbytes, np.uint8)
            raw = self._raw[:nbytes]
            got = self._fh.readinto(memoryview(raw))
        else:
            raw = np.empty(k * h * w, "<u2" if self.stored_bits == 16 else np.uint8)
            got = self._fh.readinto(memoryview(raw).cast("B"))
        if got != nbytes:
            raise InputDataError(
                f"file shrank while reading: frames {start}..{stop} incomplete", self.mraw_path)
        if self.stored_bits == 12:
            return unpack_12bit(raw).reshape(k, h, w)
        return raw.astype(self.meta.dtype, copy=False).reshape(k, h, w)


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
