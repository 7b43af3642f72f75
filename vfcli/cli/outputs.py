"""Output paths given on the command line, checked before any work is done.

A picture option whose extension names a format the writer cannot write, or a path in a folder
that cannot be written, failed only when the file was written: after a fit or a diagnosis
(minutes thrown away), after `vfcli mesh` had committed /mesh, or after `vfcli run` had run every
stage, and always with a traceback (exit 1). Here each such option is one line naming the option,
the path and what is wrong, exit 2 (:class:`vfcli.errors.ConfigError`), before the command reads
or writes anything.
"""
from __future__ import annotations

import os
from pathlib import Path

from vfcli.errors import ConfigError

#: picture formats matplotlib's ``savefig`` writes (the convergence plot, the uncertainty and residual maps)
PICTURE_FORMATS = (".png", ".svg", ".pdf", ".eps", ".ps", ".jpg", ".jpeg", ".tif", ".tiff", ".webp")
#: what both renderers of the mesh preview write (pyvista's screenshot, matplotlib's savefig)
PREVIEW_FORMATS = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its nearest ancestor that exists (the folder a new path is created in)."""
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_output_file(path: str | os.PathLike | None, option: str, formats: tuple[str, ...] | None = None) -> None:
    """Refuse an output file that cannot be written: a format not in ``formats`` (by its extension, any
    case), a folder, an existing file without write permission, or a folder (or the nearest existing one
    it would be created in) where no file can be made.

    Raises
    ------
    ConfigError
        One line naming ``option``, the path and what is wrong.
    """
    if path is None:
        return
    p = Path(path)
    if formats is not None and p.suffix.lower() not in formats:
        raise ConfigError(f"{option} {path}: the extension says which format to write; "
                          f"{p.suffix or 'none'} is not one of {', '.join(formats)}")
    if p.is_dir():
        raise ConfigError(f"{option} {path}: is a folder; give a file name")
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(f"{option} {path}: the file exists and cannot be written (permission denied)")
    _check_folder(p.parent, option, path)


def check_output_folder(path: str | os.PathLike | None, option: str) -> None:
    """Refuse an output folder that is a file, or that (or the nearest existing folder it would be created
    in) cannot be written into.

    Raises
    ------
    ConfigError
        One line naming ``option``, the path and what is wrong.
    """
    if path is None:
        return
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{option} {path}: is a file, not a folder")
    _check_folder(p, option, path)


def _check_folder(folder: Path, option: str, given: str | os.PathLike) -> None:
    base = _nearest_existing(folder)
    if not base.is_dir():
        raise ConfigError(f"{option} {given}: {base} is a file, so no folder can be made there")
    if not os.access(base, os.W_OK | os.X_OK):
        where = "into" if base == folder.absolute() else "a folder in"
        raise ConfigError(f"{option} {given}: cannot write {where} {base} (permission denied)")
