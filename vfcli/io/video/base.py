"""High-speed video: a common streaming interface and a reader registry.

Every format reader returns a :class:`VideoSource`: metadata up front
(:class:`VideoMeta`) and :meth:`VideoSource.iter_frames`, which streams frame
batches ``(k, H, W)`` without ever holding the whole video in memory.

Readers are registered per file extension (after pyvista's reader registry):

===============  ==================================================  ============
kind             files                                               module
===============  ==================================================  ============
``photron``      ``.mraw`` with ``.cihx``/``.cih`` beside it          photron
``tiff``         multi-page ``.tif``/``.tiff``                       tiff_avi
``folder``       a directory of numbered ``.png``/``.tif`` images    tiff_avi
``avi``          ``.avi`` (OpenCV / FFmpeg)                          tiff_avi
===============  ==================================================  ============

Examples
--------
>>> from vfcli.io.video.base import open_video                    # doctest: +SKIP
>>> with open_video("run1.cihx") as video:                   # doctest: +SKIP
...     for batch in video.iter_frames(batch=64):
...         process(batch)          # (<=64, H, W) uint16 counts
"""
from __future__ import annotations

import abc
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Protocol

import numpy as np

from vfcli.errors import ConfigError, InputDataError
from vfcli.io.limits import FPS_RANGE, MAX_ABS_START_FRAME, check_range

logger = logging.getLogger(__name__)

#: Default memory budget of one streamed batch, bytes (decoded frames).
DEFAULT_BATCH_BYTES = 32 * 2**20


@dataclass(frozen=True)
class VideoMeta:
    """What a video file says about itself.

    Attributes
    ----------
    path : str
        The file (or folder) that was opened.
    kind : str
        Reader kind (``'photron'``, ``'tiff'``, ``'folder'``, ``'avi'``).
    n_frames, height, width : int
        Frame count and frame size, pixels.
    dtype : numpy.dtype
        dtype of the frames yielded (uint8 or uint16).
    bit_depth : int
        Significant bits per pixel (12 for the SA-X2: values 0..4095 in uint16).
    fps : float or None
        Frame rate, frames/s; None when the format does not record one.
    start_frame : int
        Camera frame number of the first stored frame relative to the trigger
        (Photron "Start Frame"; negative for end/centre triggers); 0 if unknown.
    trigger_index : int or None
        Index in the file of the trigger frame (``-start_frame`` when it lies
        inside the recording), None when unknown or outside.
    description : str
        One-line human description of the source (camera, format, comment).
    packed_bits : int or None
        Bits per pixel when the file stores its pixels bit-packed (12 for a 12-bit
        Photron MRAW: two pixels in three bytes), None when it stores whole bytes or
        compresses them. Said by the file's format, not guessed from the values.
    fps_note : str or None
        Why ``fps`` is None although the file states a frame rate: rates that disagree (an AVI's main
        and stream headers) or a time unit vfcli does not know (a TIFF's ImageJ ``tunit``); the ingest
        stage refuses it, with this note, unless ``camera.fps_hz`` is set.
    """

    path: str
    kind: str
    n_frames: int
    height: int
    width: int
    dtype: np.dtype
    bit_depth: int
    fps: float | None
    start_frame: int = 0
    trigger_index: int | None = None
    description: str = ""
    packed_bits: int | None = None
    fps_note: str | None = None

    def __post_init__(self) -> None:
        """Refuse a frame rate or start frame no recording can have (vfcli/io/limits.py)."""
        if self.fps is not None:
            object.__setattr__(self, "fps", check_range(self.fps, *FPS_RANGE, "frame rate", "frames/s",
                                                        self.path))
        check_range(self.start_frame, -MAX_ABS_START_FRAME, MAX_ABS_START_FRAME, "start frame", "frames",
                    self.path)

    @property
    def t0(self) -> float | None:
        """Time of the first frame relative to the trigger, s (None without fps)."""
        return None if self.fps is None else self.start_frame / self.fps

    @property
    def frame_nbytes(self) -> int:
        """Bytes of one decoded frame."""
        return self.height * self.width * np.dtype(self.dtype).itemsize


class FrameBatch(Protocol):
    """A batch of frames that may decode each frame only when it is asked for.

    A ``(k, H, W)`` numpy array is one; :meth:`VideoSource.iter_lazy_frames` may yield
    others, whose ``batch[i]`` decodes frame ``i`` (safe to call from several threads at
    once, for different ``i``), so that the caller can decode in parallel.
    """

    shape: tuple[int, ...]
    dtype: np.dtype

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> np.ndarray: ...


class VideoSource(abc.ABC):
    """A video opened for streaming; subclasses implement :meth:`_read_range`.

    Use as a context manager (or call :meth:`close`).
    """

    meta: VideoMeta

    @abc.abstractmethod
    def _read_range(self, start: int, stop: int) -> np.ndarray:
        """Frames ``start..stop-1`` as a new ``(stop-start, H, W)`` array."""

    def close(self) -> None:
        """Release file handles (no-op by default)."""

    def __enter__(self) -> "VideoSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return self.meta.n_frames

    def default_batch(self) -> int:
        """Frames per batch so that one batch is about DEFAULT_BATCH_BYTES."""
        return max(1, DEFAULT_BATCH_BYTES // max(1, self.meta.frame_nbytes))

    def iter_frames(
        self,
        start: int = 0,
        stop: int | None = None,
        roi: tuple[int, int, int, int] | None = None,
        batch: int | None = None,
    ) -> Iterator[np.ndarray]:
        """Stream frames ``start..stop-1`` in batches.

        Parameters
        ----------
        start, stop : int
            Frame range (half-open); ``stop=None`` means the last frame.
        roi : (row0, row1, col0, col1) or None
            Half-open pixel window to keep, in full-frame pixel indices.
        batch : int or None
            Frames per yielded array; default: about 32 MB of decoded frames.

        Yields
        ------
        frames : (k, H', W') array of meta.dtype, k <= batch
            Each a fresh array the caller may keep.

        Raises
        ------
        ConfigError
            On a frame range or ROI outside the video.
        InputDataError
            On a file that turns out to be unreadable while streaming.
        """
        start, stop, batch = self._check_range(start, stop, batch)
        rows, cols = self._roi_slices(roi)
        for b0 in range(start, stop, batch):
            frames = self._read_range(b0, min(b0 + batch, stop))
            if roi is not None:
                frames = np.ascontiguousarray(frames[:, rows, cols])
            yield frames

    def iter_lazy_frames(
        self,
        start: int = 0,
        stop: int | None = None,
        roi: tuple[int, int, int, int] | None = None,
        batch: int | None = None,
    ) -> Iterator[FrameBatch]:
        """Like :meth:`iter_frames`, but a batch may be read and not yet decoded.

        Readers whose decoding costs CPU (12-bit MRAW) yield :class:`FrameBatch` objects
        that decode frame ``i`` on ``batch[i]``, so a caller can decode the frames of a
        batch in worker threads while this iterator reads the next one. The default
        yields :meth:`iter_frames`'s arrays. Same parameters and errors.
        """
        return self.iter_frames(start, stop, roi, batch)

    def read(self, start: int = 0, stop: int | None = None,
             roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """All frames of a range as one ``(k, H', W')`` array (mind the memory)."""
        parts = list(self.iter_frames(start, stop, roi))
        if not parts:
            h, w = self.meta.height, self.meta.width
            if roi is not None:
                h, w = roi[1] - roi[0], roi[3] - roi[2]
            return np.empty((0, h, w), self.meta.dtype)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _check_range(self, start: int, stop: int | None, batch: int | None) -> tuple[int, int, int]:
        """``(start, stop, batch)`` checked and defaulted; ConfigError when outside the video."""
        m = self.meta
        stop = m.n_frames if stop is None else int(stop)
        start = int(start)
        if not 0 <= start <= stop <= m.n_frames:
            raise ConfigError(
                f"{m.path}: frame range {start}..{stop} outside the video's 0..{m.n_frames}"
            )
        batch = self.default_batch() if batch is None else int(batch)
        if batch < 1:
            raise ConfigError(f"batch must be >= 1 frame, got {batch}")
        return start, stop, batch

    def _roi_slices(self, roi) -> tuple[slice, slice]:
        if roi is None:
            return slice(None), slice(None)
        r0, r1, c0, c1 = (int(v) for v in roi)
        if not (0 <= r0 < r1 <= self.meta.height and 0 <= c0 < c1 <= self.meta.width):
            raise ConfigError(
                f"{self.meta.path}: ROI rows {r0}..{r1}, cols {c0}..{c1} outside the "
                f"{self.meta.height} x {self.meta.width} frame"
            )
        return slice(r0, r1), slice(c0, c1)


# --------------------------------------------------------------------------- registry

ReaderFactory = Callable[[Path], VideoSource]
_READERS: dict[str, ReaderFactory] = {}
_EXTENSIONS: dict[str, str] = {}
_builtins_loaded = False


def register_reader(kind: str, factory: ReaderFactory, extensions: tuple[str, ...] = ()) -> None:
    """Register ``factory(path) -> VideoSource`` under ``kind`` and file extensions.

    Extensions are given with their dot, lower case (``'.mraw'``).
    """
    _READERS[kind] = factory
    for ext in extensions:
        _EXTENSIONS[ext.lower()] = kind


def _load_builtin_readers() -> None:
    global _builtins_loaded
    if not _builtins_loaded:
        from vfcli.io.video import photron, tiff_avi  # noqa: F401  (register themselves)

        _builtins_loaded = True


def video_kinds() -> dict[str, list[str]]:
    """Registered reader kinds and the extensions mapped to each."""
    _load_builtin_readers()
    out: dict[str, list[str]] = {k: [] for k in _READERS}
    for ext, kind in _EXTENSIONS.items():
        out[kind].append(ext)
    return out


def open_video(path: str | Path, kind: str | None = None) -> VideoSource:
    """Open a high-speed video for streaming.

    Parameters
    ----------
    path : str or Path
        A video file (``.mraw``/``.cihx``/``.cih``, ``.tif``/``.tiff``, ``.avi``) or
        a folder of numbered images.
    kind : str or None
        Force a reader kind (see :func:`video_kinds`); default: from the
        extension (a directory is ``'folder'``).

    Returns
    -------
    VideoSource

    Raises
    ------
    InputDataError
        Missing, empty, truncated, inconsistent or unsupported file.
    ConfigError
        Unknown ``kind``.
    """
    _load_builtin_readers()
    p = Path(path)
    if kind is None:
        if p.is_dir():
            kind = "folder"
        else:
            kind = _EXTENSIONS.get(p.suffix.lower())
            if kind is None:
                known = ", ".join(sorted(_EXTENSIONS))
                raise InputDataError(
                    f"unsupported video file extension {p.suffix!r} (known: {known}, or a folder)",
                    p,
                )
    elif kind not in _READERS:
        raise ConfigError(f"unknown video kind {kind!r}; known: {', '.join(sorted(_READERS))}")
    if not p.exists():
        raise InputDataError("video not found", p)
    source = _READERS[kind](p)
    logger.debug("opened %s video %s: %s", kind, p, source.meta)
    return source
