"""Streaming readers for multi-page TIFF, image folders and AVI; a TIFF writer.

* Multi-page TIFF (tifffile): one greyscale page per frame, uint8 or uint16; uncompressed,
  zlib/deflate or PackBits, and with the optional imagecodecs (``pip install 'vfcli[tiff]'``)
  LZW, JPEG, ZStandard ... (without it: one line naming the compression and the install).
  The frame rate is read from the first of: a JSON ImageDescription of the first page
  (``{"fps": ...}``, written by :func:`write_tiff`), tifffile's "shaped" metadata, ImageJ's
  ``finterval`` in its ``tunit`` (s when absent; s, ms, us/µs, min) or else ImageJ's ``fps``, an
  OME-TIFF's ``TimeIncrement`` in its ``TimeIncrementUnit`` (s when absent); else None. In another
  time unit: None, and ``fps_note`` names it (ingest then needs ``camera.fps_hz``).
* Folder: every ``.png``, ``.tif``, ``.tiff``, ``.bmp`` file directly in the
  folder, sorted naturally (``img2`` before ``img10``); all frames must have the
  same size and dtype. No frame rate (None).
* AVI: decoded by OpenCV/FFmpeg: 8-bit grey and 16-bit grey (``gray16le``, uint16 at bit depth 16)
  as decoded, 8-bit colour converted to grey; any other pixel format (10/12-bit or big-endian grey,
  more than 8 bits per colour component) refused, as OpenCV would return only 8 of its bits. fps from
  the container; when the main header (``avih``) and the stream header (``strh``) disagree, None
  with ``fps_note`` naming both (ingest then needs ``camera.fps_hz``). An uncompressed stream whose first frame
  does not hold the bytes its header's size and depth need is refused before FFmpeg sees it (FFmpeg
  corrupts memory on it and the process aborts or segfaults, which Python cannot catch).

Colour frames (folder images, AVI) are converted to grey with OpenCV's
BGR->grey weights; colour TIFF pages are rejected (ambiguous for a mono camera).

``bit_depth`` is the dtype's (8 or 16) for TIFF, folders and AVI: the files written in the wild
(tifffile, ImageJ, OME, Pillow, OpenCV's PNG) do not state fewer significant bits, so 12-bit counts
in uint16 are stored with bit depth 16; it is never guessed from the values.
"""
from __future__ import annotations

import json
import logging
import struct
from pathlib import Path
from typing import Iterable

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io._common import library_output, natural_key, require_file
from vfcli.io.units import seconds_per, time_units_text
from vfcli.io.video.base import VideoMeta, VideoSource, register_reader

logger = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".png", ".tif", ".tiff", ".bmp")
_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def _bits_of(dtype: np.dtype) -> int:
    return 8 * np.dtype(dtype).itemsize


def _check_dtype(dtype: np.dtype, path: Path) -> np.dtype:
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.uint8), np.dtype(np.uint16)):
        raise InputDataError(f"unsupported pixel type {dtype} (need 8- or 16-bit unsigned)", path)
    return dtype


# --------------------------------------------------------------------------- TIFF

class UnknownTimeUnit(ValueError):
    """A frame interval in a time unit vfcli does not know; the message names the field and the unit."""


def interval_fps(interval: float, unit: str, field: str) -> float | None:
    """Frames/s of a frame ``interval`` given in ``unit`` (:mod:`vfcli.io.units`); None for an interval of 0
    (not set). ``field`` names the metadata for the error.

    Raises
    ------
    UnknownTimeUnit
        An unknown time unit.
    """
    scale = seconds_per(str(unit))
    if scale is None:
        raise UnknownTimeUnit(f"{field} is {unit!r}, not a time unit vfcli knows ({time_units_text()})")
    interval = float(interval)
    return None if interval == 0 else 1.0 / (interval * scale)


def imagej_fps(ij: dict) -> float | None:
    """Frames/s from ImageJ metadata: ``finterval`` in ``tunit`` (ImageJ's default unit: s), else ImageJ's
    ``fps`` key (its animation rate); None when neither is set."""
    if ij.get("finterval"):
        return interval_fps(ij["finterval"], ij.get("tunit") or "s", "the ImageJ time unit (tunit)")
    if ij.get("fps"):
        return float(ij["fps"])
    return None


def ome_fps(xml: str) -> float | None:
    """Frames/s from an OME-XML ``Pixels`` element's ``TimeIncrement`` in ``TimeIncrementUnit`` (OME's
    default: s); None without a TimeIncrement or with unreadable XML."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return None
    pixels = next((e for e in root.iter() if e.tag.rsplit("}", 1)[-1] == "Pixels"), None)
    if pixels is None or not pixels.get("TimeIncrement"):
        return None
    return interval_fps(pixels.get("TimeIncrement"), pixels.get("TimeIncrementUnit") or "s",
                        "the OME TimeIncrementUnit")


#: The extra that installs the optional codecs of compressed TIFF pages (imagecodecs).
TIFF_CODECS_INSTALL = "pip install 'vfcli[tiff]' (or pip install imagecodecs)"


def missing_codec(compression: int, predictor: int = 1) -> str | None:
    """The name of a TIFF page's compression or predictor that tifffile decodes only with the optional
    package imagecodecs (LZW, JPEG, ...), when it is not installed; None when tifffile can decode both."""
    from tifffile import COMPRESSION, PREDICTOR, TIFF

    for codecs, key, name in ((TIFF.DECOMPRESSORS, compression, lambda k: COMPRESSION(k).name),
                              (TIFF.UNPREDICTORS, predictor, lambda k: f"predictor {PREDICTOR(k).name}")):
        try:
            codecs[key]
        except KeyError as exc:
            if "imagecodecs" in str(exc):
                return name(key)
    return None


def check_codec(page, index: int, path: Path) -> None:
    """ConfigError (exit 2, as for `vfcli batch` without dask) naming the page's compression and the install
    command when decoding it needs imagecodecs and it is not installed (:func:`missing_codec`): a missing optional
    dependency, not bad data."""
    try:
        codes = int(page.compression), int(page.predictor)
    except (TypeError, ValueError):  # a damaged tag: left to decoding, which reports it
        return
    name = missing_codec(*codes)
    if name is not None:
        raise ConfigError(f"page {index} is compressed with {name}, which needs the optional package imagecodecs "
                          f"(not installed): {TIFF_CODECS_INSTALL}", path)


class TiffSource(VideoSource):
    """Multi-page greyscale TIFF, read page by page."""

    def __init__(self, path: str | Path) -> None:
        import tifffile

        p = require_file(path, "TIFF file")
        with open(p, "rb") as fh:
            if fh.read(4) not in _TIFF_MAGIC:
                raise InputDataError("not a TIFF file (bad magic bytes)", p)
        with library_output(p, "tifffile") as said:
            try:
                self._tif = tifffile.TiffFile(p)
                pages = self._tif.pages
                first = pages.first
                n = len(pages)
                shape, dtype = tuple(int(s) for s in first.shape), first.dtype
                try:
                    fps, fps_note = self._fps_from_metadata(), None
                except UnknownTimeUnit as exc:
                    fps, fps_note = None, str(exc)
            except InputDataError:
                raise
            except Exception as exc:  # tifffile raises many types on corrupt files
                raise InputDataError(f"unreadable TIFF: {type(exc).__name__}: {exc}", p) from None
            broken = said.errors("<tifffile.TiffPages")
            if broken:  # tifffile stops counting pages where the chain breaks, and logs an error
                self.close()
                raise InputDataError(f"truncated or damaged TIFF: its chain of pages breaks after {n} page(s) "
                                     f"(tifffile: {broken[0].split('> ', 1)[-1][:120]}; the file holds {p.stat().st_size} bytes)", p)
        if len(shape) != 2:
            self.close()
            raise InputDataError(
                f"TIFF pages have shape {shape}; need greyscale (H, W) pages", p)
        dtype = _check_dtype(dtype, p)
        try:
            check_codec(first, 0, p)
        except ConfigError:
            self.close()
            raise
        if min(shape) < 1 or shape[0] * shape[1] * dtype.itemsize > 1000 * p.stat().st_size:
            self.close()
            raise InputDataError(f"TIFF page size {shape} is implausible for a "
                                 f"{p.stat().st_size}-byte file (corrupt header)", p)
        self.path = p
        try:
            self.meta = VideoMeta(
                path=str(p), kind="tiff", n_frames=n, height=shape[0], width=shape[1], dtype=dtype,
                bit_depth=_bits_of(dtype), fps=fps, fps_note=fps_note, description=f"multi-page TIFF, {n} pages")
        except InputDataError:
            self.close()
            raise

    def _fps_from_metadata(self) -> float | None:
        """Frame rate, frames/s, from the first metadata that states one (see the module docstring).

        Raises
        ------
        UnknownTimeUnit
            A frame interval in a time unit vfcli does not know.
        """
        tif = self._tif
        try:
            desc = tif.pages.first.description
            if desc.startswith("{"):
                fps = json.loads(desc).get("fps")
                if fps is not None:
                    return float(fps)  # VideoMeta refuses an impossible rate
            meta = tif.shaped_metadata
            if meta and "fps" in meta[0]:
                return float(meta[0]["fps"])
            ij = tif.imagej_metadata
            if ij:
                return imagej_fps(ij)
            if tif.is_ome:
                return ome_fps(tif.ome_metadata)
        except UnknownTimeUnit:
            raise
        except (TypeError, ValueError, KeyError, ZeroDivisionError, AttributeError):
            return None
        return None

    def close(self) -> None:
        if getattr(self, "_tif", None) is not None:
            self._tif.close()

    def _read_range(self, start: int, stop: int) -> np.ndarray:
        m = self.meta
        out = np.empty((stop - start, m.height, m.width), m.dtype)
        with library_output(self.path, "tifffile"):
            for j, i in enumerate(range(start, stop)):
                try:
                    page = self._tif.pages[i]
                    img = page.asarray()
                except Exception as exc:
                    if "imagecodecs" in str(exc):
                        check_codec(page, i, self.path)
                    raise InputDataError(f"page {i} unreadable: {type(exc).__name__}: {exc}",
                                         self.path) from None
                if img.shape != out.shape[1:] or img.dtype != m.dtype:
                    raise InputDataError(
                        f"page {i} is {img.shape} {img.dtype}, page 0 is "
                        f"{out.shape[1:]} {m.dtype}", self.path)
                out[j] = img
        return out


register_reader("tiff", TiffSource, (".tif", ".tiff"))


def write_tiff(path: str | Path, frames: Iterable[np.ndarray], fps: float | None = None,
               compression: str | None = None) -> Path:
    """Write frames as a multi-page greyscale TIFF (one page per frame), streaming.

    Parameters
    ----------
    path : str or Path
        Output ``.tif`` file.
    frames : iterable of (H, W) or (k, H, W) uint8/uint16 arrays
    fps : float or None
        Stored in tifffile's JSON description and read back by :class:`TiffSource`.
    compression : str or None
        tifffile compression name (e.g. ``'zlib'``); default none.

    Returns
    -------
    Path
    """
    import tifffile

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    shape = dtype = None
    desc = json.dumps({"fps": None if fps is None else float(fps), "generator": "vfcli"})
    with tifffile.TiffWriter(p) as tw:
        for block in frames:
            block = np.asarray(block)
            if block.ndim == 2:
                block = block[None]
            if block.ndim != 3:
                raise ConfigError(f"frames must be (H, W) or (k, H, W), got {block.shape}")
            if block.dtype not in (np.uint8, np.uint16):
                raise ConfigError(f"frames must be uint8 or uint16, got {block.dtype}")
            if shape is None:
                shape, dtype = block.shape[1:], block.dtype
            elif block.shape[1:] != shape or block.dtype != dtype:
                raise ConfigError("all frames must have the same shape and dtype")
            for img in block:
                # the first page's description carries {"fps": ...} as JSON
                tw.write(img, photometric="minisblack", compression=compression,
                         metadata=None, description=desc if n == 0 else None)
                n += 1
    if n == 0:
        p.unlink(missing_ok=True)
        raise ConfigError("no frames to write")
    return p


# --------------------------------------------------------------------------- folder

def _imread(path: Path) -> np.ndarray:
    import cv2

    if path.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        try:
            with library_output(path, "tifffile"):
                img = tifffile.imread(path, key=0)
        except Exception as exc:
            if "imagecodecs" in str(exc):
                with tifffile.TiffFile(path) as tif:
                    check_codec(tif.pages.first, 0, path)
            raise InputDataError(f"unreadable image: {type(exc).__name__}: {exc}", path) from None
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputDataError("unreadable image (not a PNG/BMP or corrupt)", path)
    if img.ndim == 3:
        _check_dtype(img.dtype, path)  # OpenCV converts 8/16-bit unsigned colour only
        if img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
        elif img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        else:
            img = img[..., 0]
    return img


class FolderSource(VideoSource):
    """A folder of numbered image files, one frame each, in natural order."""

    def __init__(self, path: str | Path) -> None:
        p = Path(path)
        if not p.is_dir():
            raise InputDataError("not a folder", p)
        files = sorted((f for f in p.iterdir()
                        if f.is_file() and f.suffix.lower() in IMAGE_EXTENSIONS),
                       key=lambda f: natural_key(f.name))
        if not files:
            raise InputDataError(
                f"no image files ({', '.join(IMAGE_EXTENSIONS)}) in the folder", p)
        exts = {f.suffix.lower().replace(".tiff", ".tif") for f in files}
        if len(exts) > 1:
            raise InputDataError(f"mixed image types in the folder: {sorted(exts)}", p)
        first = _imread(require_file(files[0], "image"))
        dtype = _check_dtype(first.dtype, files[0])
        self.files = files
        self.meta = VideoMeta(
            path=str(p), kind="folder", n_frames=len(files), height=first.shape[0],
            width=first.shape[1], dtype=dtype, bit_depth=_bits_of(dtype), fps=None,
            description=f"{len(files)} {files[0].suffix} images ({files[0].name} .. "
                        f"{files[-1].name})")

    def _read_range(self, start: int, stop: int) -> np.ndarray:
        m = self.meta
        out = np.empty((stop - start, m.height, m.width), m.dtype)
        for j, f in enumerate(self.files[start:stop]):
            img = _imread(f)
            if img.shape != out.shape[1:] or img.dtype != m.dtype:
                raise InputDataError(
                    f"image is {img.shape} {img.dtype}, the first image is "
                    f"{out.shape[1:]} {m.dtype}", f)
            out[j] = img
        return out


register_reader("folder", FolderSource, ())


# --------------------------------------------------------------------------- AVI

#: bytes of an AVI read for its stream header and its first frame's chunk header
AVI_HEAD_BYTES = 1 << 20


def _riff_chunks(buf: bytes, start: int):
    """(fourcc, data offset, data size) of the RIFF chunks in ``buf`` from ``start`` in file order, LIST and RIFF
    chunks entered where they start (their list type yielded first, as a chunk of size 0; no recursion, so a
    hostile nesting costs nothing); stops at the first chunk header past the buffer's end."""
    at = start
    while at + 8 <= len(buf):
        tag, size = buf[at:at + 4], struct.unpack_from("<I", buf, at + 4)[0]
        if tag in (b"LIST", b"RIFF"):
            yield buf[at + 8:at + 12], at + 12, 0
            at += 12
        else:
            yield tag, at + 8, size
            at += 8 + size + (size & 1)


def check_uncompressed_frames(head: bytes, path: Path) -> None:
    """InputDataError when the AVI's video stream is stated uncompressed (BITMAPINFOHEADER compression 0)
    and its first non-empty frame chunk does not hold ``|height|`` rows of ``width x bit count`` bits (each
    padded to 4 bytes): OpenCV's FFmpeg backend corrupts memory decoding such a frame. ``head``: the file's
    first bytes (:data:`AVI_HEAD_BYTES`); nothing is checked where they end before the first frame."""
    strf = frame = None
    video = False
    for tag, at, size in _riff_chunks(head, 12):
        if tag == b"strh" and size >= 4:
            video = head[at:at + 4] == b"vids"
        elif tag == b"strf" and video and strf is None and size >= 20:
            strf = struct.unpack_from("<iiHHI", head, at + 4)        # width, height, planes, bit count, compression
        elif tag[2:] in (b"db", b"dc") and size > 0:
            frame = size
            break
    if strf is None or frame is None:
        return
    width, height, _, bits, compression = strf
    if compression != 0 or bits not in (8, 16, 24, 32):
        return
    need = ((abs(width) * bits + 31) // 32) * 4 * abs(height)
    if frame != need:
        raise InputDataError(f"the header states uncompressed {abs(width)} x {abs(height)} frames of {bits} bits "
                             f"({need} bytes each), its first frame holds {frame} bytes: the header does not "
                             "match the frames (corrupt file?)", path)


#: FFmpeg codec tags of the decoded pixel format (OpenCV's ``CAP_PROP_CODEC_PIXEL_FORMAT``) read as decoded,
#: without OpenCV's conversion to 8-bit BGR: 8-bit grey (``gray``) and 16-bit little-endian grey (``gray16le``).
AVI_GREY_FORMATS: dict[bytes, np.dtype] = {b"Y800": np.dtype(np.uint8), b"Y1\x00\x10": np.dtype(np.uint16)}
#: Tags of colour or YUV formats of 8 bits per component: OpenCV's 8-bit BGR conversion keeps every bit,
#: then the frames are converted to grey.
AVI_COLOUR_8BIT_FORMATS = frozenset({
    b"I420", b"YV12", b"Y42B", b"444P", b"Y41B", b"YUV9", b"YVU9", b"YUY2", b"UYVY", b"YVYU", b"NV12", b"NV21",
    b"BGR\x18", b"RGB\x18", b"BGRA", b"RGBA", b"ARGB", b"ABGR", b"BGR\x00", b"RGB\x00", b"\x00BGR", b"\x00RGB",
    b"PAL\x08", b"Y2\x00\x08"})


def avi_grey_dtype(tag: bytes, path: Path) -> np.dtype | None:
    """How an AVI whose decoder gives pixel format ``tag`` (FFmpeg codec tag, 4 bytes) is read: the dtype of
    a grey format read at its real depth (:data:`AVI_GREY_FORMATS`), or None for an 8-bit colour format
    (:data:`AVI_COLOUR_8BIT_FORMATS`, converted to grey).

    Raises
    ------
    InputDataError
        Any other format (10-, 12-bit or big-endian grey, more than 8 bits per colour component, RGB 5:5:5,
        unknown): OpenCV would return it as 8 bits and drop the rest.
    """
    if tag in AVI_GREY_FORMATS:
        return AVI_GREY_FORMATS[tag]
    if tag in AVI_COLOUR_8BIT_FORMATS:
        return None
    raise InputDataError(f"the decoded pixel format (FFmpeg tag {tag!r}) cannot be read at its real depth: vfcli "
                         "reads AVIs of 8-bit grey, 16-bit grey (gray16le) or 8-bit colour; convert it, e.g. "
                         "ffmpeg -i IN.avi -c:v ffv1 -pix_fmt gray16le OUT.avi", path)


def avi_header_rates(head: bytes) -> tuple[int | None, float | None]:
    """The frame rate an AVI's headers state: ``(avih dwMicroSecPerFrame, us; video strh dwRate/dwScale,
    frames/s)``, each None when absent or 0. ``head``: the file's first bytes (:data:`AVI_HEAD_BYTES`)."""
    us = rate = None
    for tag, at, size in _riff_chunks(head, 12):
        if tag == b"avih" and size >= 4 and us is None:
            us = struct.unpack_from("<I", head, at)[0] or None
        elif tag == b"strh" and size >= 28 and head[at:at + 4] == b"vids":
            scale, rate_num = struct.unpack_from("<II", head, at + 20)
            rate = rate_num / scale if scale and rate_num else None
            break
        elif tag in (b"movi", b"idx1"):
            break
    return us, rate


def avi_rate_conflict(us: int | None, rate: float | None) -> str | None:
    """The disagreement of an AVI's two stated rates (:func:`avi_header_rates`), or None when one is absent
    or they agree to avih's round-off (a whole number of microseconds: within 1 us per frame)."""
    if us is None or rate is None or abs(us - 1e6 / rate) < 1.0:
        return None
    return (f"the AVI's main header (avih) states {us} us per frame ({1e6 / us:g} frames/s), its video stream "
            f"header (strh) {rate:g} frames/s")


class AviSource(VideoSource):
    """AVI decoded by OpenCV (FFmpeg backend): 8- and 16-bit grey read as decoded (uint8, uint16 of
    bit depth 8, 16), 8-bit colour converted to grey uint8; other pixel formats refused
    (:func:`avi_grey_dtype`).

    An uncompressed stream whose first frame contradicts its header is refused first
    (:func:`check_uncompressed_frames`). When the main and stream headers state different frame
    rates, ``fps`` is None and ``fps_note`` says both (:func:`avi_rate_conflict`)."""

    def __init__(self, path: str | Path) -> None:
        import cv2

        p = require_file(path, "AVI file")
        with open(p, "rb") as fh:
            head = fh.read(AVI_HEAD_BYTES)
        if head[:4] != b"RIFF" or head[8:12] != b"AVI ":
            raise InputDataError("not an AVI file (no RIFF/AVI header)", p)
        check_uncompressed_frames(head, p)
        conflict = avi_rate_conflict(*avi_header_rates(head))
        cap = cv2.VideoCapture(str(p), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            raise InputDataError("OpenCV cannot open this AVI (codec unsupported or corrupt)", p)
        self.path, self._cap, self._next = p, cap, 1
        try:
            tag = (int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)) & 0xFFFFFFFF).to_bytes(4, "little")
            self._native = avi_grey_dtype(tag, p)
            if self._native is not None:  # before the first read: frames as decoded, not 8-bit BGR
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            fps = float(cap.get(cv2.CAP_PROP_FPS)) or None
            ok, frame = cap.read()
            if not ok or n < 1:
                raise InputDataError("AVI holds no decodable frames", p)
            img = self._grey(frame)
            dtype = _check_dtype(img.dtype, p)
            self.meta = VideoMeta(
                path=str(p), kind="avi", n_frames=n, height=img.shape[0], width=img.shape[1],
                dtype=dtype, bit_depth=_bits_of(dtype),
                fps=None if conflict else fps if fps and np.isfinite(fps) and fps > 0 else None,
                fps_note=conflict,
                description=f"AVI ({n} frames, fourcc "
                            f"{int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, 'little')!r}, pixel format {tag!r})")
        except BaseException:
            cap.release()
            raise

    def _grey(self, frame: np.ndarray) -> np.ndarray:
        """A decoded frame as (H, W) grey: as decoded for a grey format, else OpenCV's BGR -> grey."""
        import cv2

        if self._native is not None:
            if frame.ndim != 2 or frame.dtype != self._native:
                raise InputDataError(f"a frame decoded as {frame.shape} {frame.dtype}, not (H, W) {self._native} "
                                     "grey as its pixel format states", self.path)
            return frame
        if frame.ndim == 3:
            return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        return frame

    def close(self) -> None:
        if getattr(self, "_cap", None) is not None:
            self._cap.release()

    def _read_range(self, start: int, stop: int) -> np.ndarray:
        import cv2

        m = self.meta
        if start != self._next:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        out = np.empty((stop - start, m.height, m.width), m.dtype)
        for j in range(stop - start):
            ok, frame = self._cap.read()
            if not ok:
                raise InputDataError(f"frame {start + j} of {m.n_frames} cannot be decoded",
                                     self.path)
            out[j] = self._grey(frame)
        self._next = stop
        return out


register_reader("avi", AviSource, (".avi",))
