"""The model over the video: the projected mesh on the high-speed frames, as PNG and MP4 (H.264).

Rendering is numpy + OpenCV (no display); encoding uses the ffmpeg binary that the
``imageio-ffmpeg`` wheel ships (optional extra ``vfcli[export]``), H.264 in yuv420p with
``+faststart`` so that browsers play it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.errors import ConfigError

_SHIFT = 4  # sub-pixel bits of cv2's polygon filling


def _lut(cmap: str = "inferno") -> np.ndarray:
    """(256, 3) uint8 RGB colour table of a matplotlib colormap."""
    from matplotlib import colormaps

    return (colormaps[cmap](np.linspace(0, 1, 256))[:, :3] * 255).round().astype(np.uint8)


def gray_to_rgb(frame: np.ndarray, lo: float, hi: float, scale: int) -> np.ndarray:
    """(H, W) counts -> (H*scale, W*scale, 3) uint8 grey image, ``lo``..``hi`` counts mapped to 0..255."""
    import cv2

    g = np.clip((np.asarray(frame, dtype=np.float32) - lo) / max(hi - lo, 1e-9), 0, 1) * 255
    g = cv2.resize(g.astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    return np.repeat(g[..., None], 3, axis=2)


def draw_mesh(image: np.ndarray, camera: Camera, vertices: np.ndarray, faces: np.ndarray, values: np.ndarray,
              vmax: float, scale: int, alpha: float = 0.55, wire: bool = True) -> np.ndarray:
    """Draw the visible surface of a mesh on an RGB image (painter's order, far faces first).

    vertices : (N, 3) deformed node positions, model frame, mm.
    faces : (K, 3) triangles to draw (e.g. the superior surface).
    values : (N,) per-node value coloured from 0 (dark) to ``vmax`` (bright), e.g. |displacement| in mm.
    scale : the image's pixels per camera pixel.
    Returns a new (H, W, 3) uint8 image.
    """
    import cv2

    px = (camera.project(vertices) + 0.5) * scale - 0.5          # camera pixel centres -> scaled image
    fixed = np.round(px * (1 << _SHIFT)).astype(np.int32)
    order = np.argsort(vertices[faces, 2].mean(axis=1))           # largest z (nearest the camera) last
    lut = _lut()
    face_val = np.asarray(values, dtype=float)[faces].mean(axis=1)
    idx = np.clip((face_val / max(vmax, 1e-12) * 255).round(), 0, 255).astype(int)
    layer = image.copy()
    for f in order:
        cv2.fillPoly(layer, [fixed[faces[f]]], tuple(int(c) for c in lut[idx[f]]), lineType=cv2.LINE_AA, shift=_SHIFT)
    out = cv2.addWeighted(layer, alpha, image, 1 - alpha, 0)
    if wire:
        cv2.polylines(out, [fixed[faces[f]] for f in order], True, (40, 40, 40), 1, lineType=cv2.LINE_AA, shift=_SHIFT)
    return out


def annotate(image: np.ndarray, lines: list[str], vmax: float, unit: str = "mm") -> np.ndarray:
    """Text in the top-left corner and a colour bar (0..vmax ``unit``) on the right edge."""
    import cv2

    out = image.copy()
    for i, text in enumerate(lines):
        y = 18 + 18 * i
        cv2.putText(out, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(out, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    h, w = out.shape[:2]
    top, bottom, x0 = 30, h - 30, w - 22
    lut = _lut()
    for y in range(top, bottom):
        out[y, x0:x0 + 12] = lut[int(round(255 * (bottom - 1 - y) / max(bottom - top - 1, 1)))]
    for text, y in ((f"{vmax:.2f} {unit}", top - 8), (f"0 {unit}", bottom + 16)):
        (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        xt = min(x0, w - tw - 2)
        cv2.putText(out, text, (xt, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(out, text, (xt, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def side_by_side(panels: list[np.ndarray], gap: int = 4) -> np.ndarray:
    """Panels (H, W_i, 3) next to each other with a white gap, padded to even width and height."""
    h = max(p.shape[0] for p in panels)
    parts = []
    for i, p in enumerate(panels):
        pad = np.full((h, p.shape[1], 3), 255, np.uint8)
        pad[:p.shape[0]] = p
        parts.append(pad)
        if i < len(panels) - 1:
            parts.append(np.full((h, gap, 3), 255, np.uint8))
    img = np.concatenate(parts, axis=1)
    return np.pad(img, ((0, img.shape[0] % 2), (0, img.shape[1] % 2), (0, 0)), constant_values=255)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Write an RGB uint8 image as PNG."""
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(image[..., ::-1])):
        raise RuntimeError(f"{path}: OpenCV could not write the PNG")
    return Path(path)


def write_jpeg(path: str | Path, image: np.ndarray, quality: int = 82) -> Path:
    """Write an RGB uint8 image as JPEG (photographic frames: a fraction of the PNG's size)."""
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]):
        raise RuntimeError(f"{path}: OpenCV could not write the JPEG")
    return Path(path)


def _ffmpeg():
    try:
        import imageio_ffmpeg
    except ImportError:
        raise ConfigError("the video export needs imageio-ffmpeg (it ships the H.264 encoder): "
                          "pip install 'vfcli[export]'") from None
    return imageio_ffmpeg


def write_mp4(path: str | Path, frames: list[np.ndarray], fps: float) -> Path:
    """Encode RGB uint8 frames (all the same even size) as MP4: H.264, yuv420p, faststart."""
    ff = _ffmpeg()
    h, w = frames[0].shape[:2]
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    writer = ff.write_frames(str(tmp), (w, h), fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
                             quality=None, bitrate=None, macro_block_size=2,
                             output_params=["-crf", "20", "-movflags", "+faststart"], ffmpeg_log_level="error")
    writer.send(None)
    for f in frames:
        writer.send(np.ascontiguousarray(f))
    writer.close()
    tmp.replace(path)
    return path


def probe_mp4(path: str | Path) -> dict[str, object]:
    """Codec, pixel format, size and frame count of a video, read back by ffmpeg (for tests and the report)."""
    ff = _ffmpeg()
    reader = ff.read_frames(str(path), pix_fmt="rgb24")
    meta = reader.__next__()
    n = sum(1 for _ in reader)
    return {**meta, "n_frames": n}
