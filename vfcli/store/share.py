"""A copy of a store for sharing: the video re-encoded with another filter, everything else as is.

The default 12-bit N-bit video (:data:`vfcli.store.frames.COMPRESSIONS` "nbit") is read by
vfcli with numpy, but h5py, HDFView and MATLAB decode it with libhdf5's N-bit filter, about
10x slower than gzip (docs/benchmarks.md, "Ingest"). :func:`copy_for_sharing` writes a new
store whose ``/hsc/frames`` hold the same values under another filter (gzip by default).
The values are unchanged, so every stage keeps its provenance and digest: nothing becomes
stale. The source store is only read. The copy is ONE self-contained file: the stages a store
keeps in its part files (:mod:`vfcli.store.parts`) are copied into it, so it can be sent
or moved alone.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterator

import h5py

from vfcli.errors import ConfigError, MissingStageError
from vfcli.store import integrity, layout
from vfcli.store.frames import COMPRESSIONS, FrameReader
from vfcli.store.parts import own_parts, refuse_missing, writing
from vfcli.store.reader import check_format, open_h5
from vfcli.store.transaction import StageWriter

_SCALE_LINKS = ("DIMENSION_LIST", "REFERENCE_LIST")
_BATCH = 16


def _stage_groups(f: h5py.File) -> Iterator[tuple[h5py.Group, layout.Stage]]:
    for name, st in layout.STAGES.items():
        if name in f:
            for g in (f[name].values() if st.has_runs else [f[name]]):
                yield g, st


def copy_for_sharing(src: str | Path, dst: str | Path, compression: str = "gzip") -> dict[str, Any]:
    """Write ``dst``: the store ``src`` with its video frames re-encoded with ``compression``
    (one of :data:`COMPRESSIONS`), every other group, dataset and attribute copied as is.

    Returns the summary ``{"frames", "compression", "size_bytes", "source_size_bytes"}``.

    Raises
    ------
    ConfigError
        ``dst`` exists or is ``src``, or ``src`` has no complete /hsc.
    """
    src, dst = Path(src), Path(dst)
    if compression not in COMPRESSIONS:
        raise ConfigError(f"--compression {compression!r}: use one of {', '.join(COMPRESSIONS)}")
    if dst.exists() or dst.resolve() == src.resolve():
        raise ConfigError("exists; give a new file name for the copy", dst)
    if not src.exists():
        raise ConfigError("no such store file", src)
    tmp = dst.with_name(f"{dst.name}.tmp-{os.getpid()}")
    real = Path(os.path.realpath(src))
    f = open_h5(real, "r")  # a symlinked store: its parts are beside the target
    try:
        check_format(f, src)
        refuse_missing(f, real, src)
        if "hsc" not in f or not f["hsc"].attrs.get("complete", False) or "frames" not in f["hsc"]:
            raise MissingStageError("has no complete /hsc video to re-encode; run `vfcli ingest-hsc` first", src)
        with writing(tmp, fs_strategy="fsm", fs_persist=True, libver=("v110", "latest")) as out:
            for k, v in f.attrs.items():
                out.attrs[k] = v
            for name in f:
                if name != "hsc":  # part files' stages copied in (links resolved): one self-contained file
                    f.copy(f[name], out, name=name, expand_external=True)
            hsc_in, hsc = f["hsc"], out.create_group("hsc")
            for k, v in hsc_in.attrs.items():
                hsc.attrs[k] = v
            if layout.SUMMARY_ATTR in hsc.attrs:  # what `vfcli info` shows of the frames' filter
                summary = json.loads(str(hsc.attrs[layout.SUMMARY_ATTR]))
                if "compression" in summary.get("figures", {}):
                    summary["figures"]["compression"] = compression
                    hsc.attrs[layout.SUMMARY_ATTR] = json.dumps(summary, sort_keys=True)
            for k in hsc_in:
                if k != "frames":
                    f.copy(hsc_in[k], hsc, name=k, expand_external=True)
            frames_in = hsc_in["frames"]
            frames = FrameReader(frames_in)
            n = len(frames)
            batches = (frames[a:a + _BATCH] for a in range(0, n, _BATCH))
            extra = {k: v for k, v in frames_in.attrs.items()
                     if k not in (*_SCALE_LINKS, "units", "description", "DIMENSION_LABELS")}
            if "compression" in extra:
                extra["compression"] = compression
            writer = StageWriter(hsc, layout.stage("hsc"))
            writer.write_frames("frames", frames.shape, frames.dtype, batches, units=str(frames_in.attrs["units"]),
                                description=str(frames_in.attrs["description"]), attrs=extra, compression=compression)
            # copied object references point into the source file: link every axis again
            for g, st in _stage_groups(out):
                for ds in g.values():
                    for k in _SCALE_LINKS:
                        if isinstance(ds, h5py.Dataset) and k in ds.attrs:
                            del ds.attrs[k]
                StageWriter(g, st).attach_scales()
            hsc.attrs[layout.MANIFEST_ATTR] = integrity.manifest(hsc)  # the re-encoded frames' checksums
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, dst)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        f.close()
    return {"frames": n, "compression": compression, "size_bytes": dst.stat().st_size,
            "source_size_bytes": src.stat().st_size + sum(p.stat().st_size for p in own_parts(Path(os.path.realpath(src))))}
