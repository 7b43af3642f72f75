"""Raw-file edges: readers and writers of the instruments' file formats.

* :mod:`vfcli.io.video.base` -- high-speed video (Photron MRAW+CIHX/CIH, multi-page
  TIFF, image folders, AVI): :func:`open_video` streams frame batches.
* :mod:`vfcli.io.video.photron` -- MRAW/CIHX reader and SA-X2 style writer.
* :mod:`vfcli.io.pressure` -- subglottal pressure from TDMS, CSV, WAV.
* :mod:`vfcli.io.ldv.read` -- Polytec PSV scans (UFF, CSV, MAT) and dropout flags.

Every reader raises :class:`vfcli.errors.InputDataError` naming the file on bad input.
"""
from vfcli.io.ldv.read import LdvChannels, LdvScan, detect_dropouts, read_ldv
from vfcli.io.pressure import PressureRecord, read_pressure
from vfcli.io.video.base import VideoMeta, VideoSource, open_video, register_reader, video_kinds

__all__ = ["VideoMeta", "VideoSource", "open_video", "register_reader", "video_kinds",
           "PressureRecord", "read_pressure", "LdvChannels", "LdvScan", "read_ldv",
           "detect_dropouts"]
