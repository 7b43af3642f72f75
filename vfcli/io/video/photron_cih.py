"""Photron metadata: ``.cihx`` (PFV 4: a short binary block, then UTF-8 XML ``<cih>``)
and legacy ``.cih`` (``key : value`` text lines), parsed without pyMRAW.

The fields come out under the keys pyMRAW's :func:`pyMRAW.get_cih` uses (the tests
check both against pyMRAW); importing pyMRAW, which pulls numba, would cost about a
second per command.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.errors import InputDataError
from vfcli.io._common import require_file

SUPPORTED_BITS = (8, 12, 16)


def _cihx_xml(raw: bytes, path: Path) -> ET.Element:
    i0 = raw.find(b"<cih>")
    i1 = raw.rfind(b"</cih>")
    if i0 < 0 or i1 < i0:
        raise InputDataError("not a CIHX file: no <cih> ... </cih> XML block", path)
    try:
        return ET.fromstring(raw[i0:i1 + len(b"</cih>")].decode("utf-8", errors="replace"))
    except ET.ParseError as exc:
        raise InputDataError(f"corrupt CIHX XML: {exc}", path) from None


#: CIHX elements read, by the key pyMRAW's ``get_cih`` gives them: (path, type).
_CIHX_FIELDS: dict[str, tuple[str, type]] = {
    "Date": ("fileInfo/date", str),
    "Camera Type": ("deviceInfo/deviceName", str),
    "Record Rate(fps)": ("recordInfo/recordRate", float),
    "Shutter Speed(s)": ("recordInfo/shutterSpeed", float),
    "Total Frame": ("frameInfo/totalFrame", int),
    "Original Total Frame": ("frameInfo/recordedFrame", int),
    "Start Frame": ("frameInfo/startFrame", int),
    "Image Width": ("imageDataInfo/resolution/width", int),
    "Image Height": ("imageDataInfo/resolution/height", int),
    "File Format": ("imageFileInfo/fileFormat", str),
    "EffectiveBit Depth": ("imageDataInfo/effectiveBit/depth", int),
    "EffectiveBit Side": ("imageDataInfo/effectiveBit/side", str),
    "Color Bit": ("imageDataInfo/colorInfo/bit", int),
    "Color Type": ("imageDataInfo/colorInfo/type", str),
    "Comment Text": ("basicInfo/comment", str),
}


def _cih_number(text: str) -> int | float | str:
    """A CIH value as pyMRAW reads it: float with a dot, else int, else the text."""
    try:
        return float(text) if "." in text else int(text)
    except ValueError:
        return text


def parse_cih_text(text: str) -> dict[str, int | float | str]:
    """``key : value`` lines of a legacy ``.cih`` header, up to the first blank line.

    Returns
    -------
    dict
        pyMRAW's ``get_cih`` keys and values (numbers converted).
    """
    cih: dict[str, int | float | str] = {}
    for line in text.splitlines():
        if not line:
            break
        parts = line.split(" : ")
        if len(parts) == 2:
            cih[parts[0].strip()] = _cih_number(parts[1].strip())
    return cih


def parse_cihx_xml(root: ET.Element) -> dict[str, int | float | str]:
    """The fields of a CIHX ``<cih>`` element that vfcli uses, under pyMRAW's keys.

    Missing elements are left out; numeric ones are converted (``int`` accepts a
    trailing ``.0``), a value that is not a number stays text.
    """
    cih: dict[str, int | float | str] = {}
    for key, (where, kind) in _CIHX_FIELDS.items():
        text = root.findtext(where)
        if text is None:
            continue
        text = text.strip()
        if kind is str:
            cih[key] = text
            continue
        try:
            value = float(text)
            cih[key] = int(value) if kind is int and value.is_integer() else value
        except ValueError:
            cih[key] = text
    return cih


def _field(cih: dict, key: str, kind: type, path: Path, default: Any = None) -> Any:
    """``cih[key]`` as ``kind`` (an int must be whole); ``default`` when absent or empty.

    Raises
    ------
    InputDataError
        Absent without a default, or not a number where one is needed.
    """
    value = cih.get(key)
    if value is None or value == "":
        value = default
    if value is None:
        raise InputDataError(f"metadata field {key!r} missing", path)
    if kind is str:
        return str(value)
    try:
        number = float(value)
        if kind is int:
            if not number.is_integer():
                raise ValueError
            return int(number)
        return number
    except (TypeError, ValueError, OverflowError):
        raise InputDataError(f"metadata field {key!r} is {value!r}, not a{'n integer' if kind is int else ' number'}",
                             path) from None


def read_cih(path: str | Path) -> dict:
    """Parse a ``.cihx`` or ``.cih`` file into vfcli's metadata fields.

    Returns
    -------
    dict
        ``fps`` (frames/s), ``n_frames``, ``width``, ``height``, ``bit_depth``
        (stored bits: 8, 12 or 16), ``effective_bits``, ``effective_side`` (``'lower'``:
        the effective bits are the low bits of each stored pixel, the default; ``'higher'``:
        the high bits), ``start_frame``,
        ``camera``, ``comment``, ``file_format`` and ``raw`` (every field read,
        under pyMRAW's ``get_cih`` keys).

    Raises
    ------
    InputDataError
        Unreadable, corrupt or incomplete metadata, or an unsupported layout.
    """
    p = require_file(path, "Photron metadata file")
    ext = p.suffix.lower()
    if ext == ".cihx":
        cih = parse_cihx_xml(_cihx_xml(p.read_bytes(), p))
    elif ext == ".cih":
        raw = p.read_bytes()
        if b"\x00" in raw[:4096] or b" : " not in raw[:4096]:
            raise InputDataError("not a CIH text header (no 'key : value' lines)", p)
        cih = parse_cih_text(raw.decode("utf-8", errors="replace"))
    else:
        raise InputDataError(f"not a CIH/CIHX file: {p.suffix!r}", p)
    color_bit = _field(cih, "Color Bit", int, p)
    info = dict(
        fps=_field(cih, "Record Rate(fps)", float, p),
        n_frames=_field(cih, "Total Frame", int, p),
        width=_field(cih, "Image Width", int, p),
        height=_field(cih, "Image Height", int, p),
        bit_depth=color_bit,
        effective_bits=_field(cih, "EffectiveBit Depth", int, p, default=color_bit),
        effective_side=_field(cih, "EffectiveBit Side", str, p, default="Lower").strip().lower(),
        file_format=_field(cih, "File Format", str, p),
        camera=str(cih.get("Camera Type", "") or ""),
        comment=str(cih.get("Comment Text", "") or ""),
        color_type=str(cih.get("Color Type", "Mono") or "Mono"),
        start_frame=_field(cih, "Start Frame", int, p, default=0),
        raw=cih,
    )
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
    if info["effective_side"] not in ("lower", "higher"):
        raise InputDataError(f"EffectiveBit Side is {info['effective_side']!r}; must be Lower or Higher", p)
    if info["effective_side"] == "higher" and info["bit_depth"] == 12 and info["effective_bits"] < 12:
        raise InputDataError(f"EffectiveBit Side Higher with {info['effective_bits']} effective bits in packed 12-bit "
                             "pixels: unsupported", p)
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
