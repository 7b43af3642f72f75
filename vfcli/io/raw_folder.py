"""Finding a recording's instrument files in its raw folder (what `vfcli run --raw DIR` ingests).

A raw folder holds one recording: the layout `vfcli synth` writes, or a lab's folder. The
files are recognised by their extension:

- video: Photron ``.cihx``/``.cih`` (with its ``.mraw``), ``.tif``/``.tiff``, ``.avi``;
- pressure recorded with the video: ``.tdms``, ``.wav``;
- scanning vibrometer: ``.uff``, ``.unv``;
- config: ``recording.toml``.

When a folder holds more than one candidate of a kind (two videos, a ``.csv`` pressure, a
``.mat`` scan), a manifest ``vfcli-files.toml`` in the folder names the files, relative to it::

    video = "cam/take2.cihx"       # or a folder of numbered images: "frames/"
    pressure = "daq/pressure.csv"
    ldv = "scan/points.uff"
    config = "recording.toml"      # optional; "" for none

Files that differ only in their extension are one recording in several formats: the first
format listed above is used (``video.cihx`` before ``video.tif``). Keys the manifest leaves out are found by extension as above. Other files (``.h5``, notes,
a phantom's ``truth.h5`` and ``phantom.json``) are ignored.
"""
from __future__ import annotations

import difflib
import tomllib
from dataclasses import dataclass
from pathlib import Path

from vfcli.errors import ConfigError, InputDataError

#: The manifest naming a folder's files when extensions are not enough.
FILES_MANIFEST = "vfcli-files.toml"
#: The recording config a raw folder may carry.
CONFIG_NAME = "recording.toml"

_KINDS: dict[str, tuple[str, ...]] = {
    "video": (".cihx", ".cih", ".tif", ".tiff", ".avi"),
    "pressure": (".tdms", ".wav"),
    "ldv": (".uff", ".unv"),
}
_WHAT = {"video": "video", "pressure": "pressure recording", "ldv": "vibrometer scan"}


@dataclass(frozen=True)
class RawFiles:
    """The files of one recording. ``pressure`` and ``config`` may be None (not in the folder)."""

    folder: Path
    video: Path
    pressure: Path | None
    ldv: Path
    config: Path | None


def _read_manifest(folder: Path) -> dict[str, str]:
    path = folder / FILES_MANIFEST
    if not path.is_file():
        return {}
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    known = [*_KINDS, "config"]
    unknown = sorted(set(data) - set(known))
    if unknown:
        near = difflib.get_close_matches(unknown[0], known, n=1)
        hint = f"did you mean {near[0]!r}?" if near else "known: " + ", ".join(known)
        raise ConfigError(f"{path}: unknown key {unknown[0]!r} ({hint})")
    bad = [k for k, v in data.items() if not isinstance(v, str)]
    if bad:
        raise ConfigError(f"{path}: {bad[0]} must be a file name (a string), not {data[bad[0]]!r}")
    return data


def _candidates(folder: Path, kind: str) -> list[Path]:
    """The files of ``kind`` in ``folder``; of files that differ only in their extension (one
    recording saved in several formats, as `vfcli synth` writes video.cihx and video.tif) the
    first format of :data:`_KINDS` (the instrument's own)."""
    order = _KINDS[kind]
    found = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in order]
    best: dict[str, Path] = {}
    for p in sorted(found, key=lambda q: order.index(q.suffix.lower())):
        best.setdefault(p.stem, p)
    return sorted(best.values())


def _one(folder: Path, kind: str, manifest: dict[str, str], required: bool) -> Path | None:
    if kind in manifest:
        path = folder / manifest[kind]
        if kind == "video" and path.is_dir():      # a folder of numbered images, as `vfcli ingest-hsc` reads it
            return path
        if not path.is_file():
            what = "a file or a folder of images" if kind == "video" else "a file"
            raise InputDataError(f"{FILES_MANIFEST} names {kind} = {manifest[kind]!r}, which is not {what} in the folder",
                                 folder)
        return path
    found = _candidates(folder, kind)
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise ConfigError(f"more than one {_WHAT[kind]} ({names}); name the one to use in {folder / FILES_MANIFEST}, "
                          f"e.g. {kind} = {found[0].name!r}")
    if not found:
        if not required:
            return None
        other = " or is a folder of images" if kind == "video" else ""
        raise InputDataError(f"no {_WHAT[kind]} ({', '.join(_KINDS[kind])}) in the folder; name it in "
                             f"{FILES_MANIFEST} ({kind} = \"...\") if it has another extension{other}", folder)
    return found[0]


def find_raw_files(folder: str | Path, need_pressure: bool = True) -> RawFiles:
    """The video, pressure, scan and config of the recording in ``folder``.

    Raises
    ------
    InputDataError
        The folder is missing, or a file is (exit 3).
    ConfigError
        More than one candidate of a kind, or a bad manifest (exit 2).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputDataError("raw folder not found (or not a folder)", folder)
    manifest = _read_manifest(folder)
    video = _one(folder, "video", manifest, True)
    ldv = _one(folder, "ldv", manifest, True)
    pressure = _one(folder, "pressure", manifest, need_pressure)
    if "config" in manifest:
        config = folder / manifest["config"] if manifest["config"] else None
        if config is not None and not config.is_file():
            raise InputDataError(f"{FILES_MANIFEST} names config = {manifest['config']!r}, which is not a file", folder)
    else:
        config = folder / CONFIG_NAME if (folder / CONFIG_NAME).is_file() else None
    assert video is not None and ldv is not None
    return RawFiles(folder, video, pressure, ldv, config)
