"""Per-frame datasets: their filters (gzip, N-bit), how vfcli encodes their chunks, and
:class:`FrameReader`, which reads them back fast (N-bit chunks unpacked by numpy).

Video frames are stored one frame per chunk with standard filters (shuffle + gzip, or
N-bit for 12-bit video). :meth:`vfcli.store.stage_writer.StageWriter.write_frames` encodes
the chunks itself, in worker threads (:mod:`vfcli.store.chunks`), and writes them with
``write_direct_chunk``; :class:`FrameSink` does the same frame by frame in the caller's thread
(the flow stage's five per-frame datasets, the phantom's truth); every HDF5 reader reads them as
usual.
"""
from __future__ import annotations

from typing import Any

import h5py
import numpy as np

from vfcli.store.chunks import NBIT_BITS, ChunkCodec, encode_chunk, unpack_nbit12

#: Filters of large per-frame datasets, by name: h5py ``create_dataset`` options, except
#: "nbit", HDF5's built-in N-bit filter on uint16 of 12 bits of precision (lossless for
#: 12-bit video, 75 % of uint16, no compression work; :meth:`StageWriter.create`). Every
#: HDF5 reader opens all of them without plugins (HDFView, MATLAB, h5py). "gzip" (deflate
#: level 1 + shuffle) is the default; see docs/benchmarks.md ("Ingest") for the measured
#: speed of each.
COMPRESSIONS: dict[str, dict[str, Any]] = {
    "gzip": {"compression": "gzip", "compression_opts": 1, "shuffle": True},
    "gzip4": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
    "nbit": {"nbit": NBIT_BITS},
    "none": {},
}
_COMPRESSION = COMPRESSIONS["gzip"]
#: How :meth:`StageWriter.write_frames` encodes the chunks of each of :data:`COMPRESSIONS`
#: itself (the dataset keeps the filters above, so every reader decodes them with plain
#: zlib). Each byte plane is deflated on its own and incompressible planes are stored
#: (:func:`vfcli.store.chunks.deflate_planes`): "gzip" with ISA-L at level 1 (files the
#: size of zlib's level 1, several times faster), "gzip4" with zlib's level 4. "nbit" packs
#: the 12 bits of each pixel (12-bit packed MRAW frames are copied as they are).
CHUNK_CODECS: dict[str, ChunkCodec] = {
    "gzip": ChunkCodec(shuffle=True, deflate="isal", level=1, per_plane=True),
    "gzip4": ChunkCodec(shuffle=True, deflate="zlib", level=4, per_plane=True),
    "nbit": ChunkCodec(nbit=NBIT_BITS),
    "none": ChunkCodec(),
}


def compression_of(ds: h5py.Dataset) -> str:
    """The name in :data:`COMPRESSIONS` of ``ds``'s filters ("gzip", "gzip4", "nbit", "none").

    Raises
    ------
    ValueError
        Filters vfcli does not write (e.g. LZF, or gzip at another level).
    """
    dcpl = ds.id.get_create_plist()
    if any(dcpl.get_filter(i)[0] == h5py.h5z.FILTER_NBIT for i in range(dcpl.get_nfilters())):
        return "nbit"
    for name, opts in COMPRESSIONS.items():
        if "nbit" in opts:
            continue
        if (ds.compression, ds.compression_opts, bool(ds.shuffle)) == (
                opts.get("compression"), opts.get("compression_opts"), bool(opts.get("shuffle", False))):
            return name
    raise ValueError(f"{ds.name}: filters {ds.compression!r} (options {ds.compression_opts!r}, shuffle {ds.shuffle}) "
                     f"are none of vfcli's {sorted(COMPRESSIONS)}")


class FrameSink:
    """Frames written one at a time (or a few) into a one-frame-per-chunk dataset, each chunk
    encoded by vfcli (:data:`CHUNK_CODECS`: shuffle + ISA-L deflate for "gzip") and stored with
    ``write_direct_chunk``, in the calling thread: the dataset every reader sees is the one
    libhdf5's own filters would have written (same filters, same values), at a fraction of the
    cost (libhdf5's zlib at level 1 took 24 % of `vfcli flow` on the demo recording). For a
    stream of frames from one source, :meth:`vfcli.store.stage_writer.StageWriter.write_frames`
    also encodes in parallel; a sink serves a stage that fills several datasets from one loop.

    ``sink[k] = frame`` writes frame k ((*shape[1:]) array), ``sink[i:j] = frames`` frames i..j-1
    ((j - i, *shape[1:])); frames are converted to the dataset's dtype. The codec is the one of the
    dataset's own filters (:func:`compression_of`), so the chunks always match them.
    """

    def __init__(self, ds: h5py.Dataset) -> None:
        if ds.chunks is None or ds.chunks != (1, *ds.shape[1:]):
            raise ValueError(f"{ds.name}: a frame sink needs one frame per chunk, the dataset's chunks are {ds.chunks}")
        self.dataset = ds
        self._codec = CHUNK_CODECS[compression_of(ds)]
        self._zeros = (0,) * (ds.ndim - 1)

    def __setitem__(self, index: int | slice, frames: Any) -> None:
        ds = self.dataset
        if isinstance(index, slice):
            start, stop, step = index.indices(ds.shape[0])
            if step != 1:
                raise ValueError(f"{ds.name}: frames are written in order (step 1), not step {step}")
            block = np.asarray(frames)
            if block.shape != (stop - start, *ds.shape[1:]):
                raise ValueError(f"{ds.name}: frames {start}..{stop - 1} need shape {(stop - start, *ds.shape[1:])}, "
                                 f"got {block.shape}")
            for k in range(start, stop):
                self._write(k, block[k - start])
            return
        k = int(index)
        if not 0 <= k < ds.shape[0]:
            raise IndexError(f"{ds.name}: frame {k} outside 0..{ds.shape[0] - 1}")
        self._write(k, frames)

    def _write(self, k: int, frame: Any) -> None:
        ds = self.dataset
        arr = np.ascontiguousarray(frame, dtype=ds.dtype)
        if arr.shape != ds.shape[1:]:
            raise ValueError(f"{ds.name}: frame {k} has shape {arr.shape}, the dataset's frames {ds.shape[1:]}")
        ds.id.write_direct_chunk((k, *self._zeros), encode_chunk(arr, self._codec))


def nbit_dataset(
    group: h5py.Group, key: str, shape: tuple[int, ...], dtype: Any, chunks: Any, bits: int
) -> h5py.Dataset:
    """An empty dataset of unsigned integers of ``bits`` bits of precision under HDF5's
    N-bit filter (what ``H5Pset_nbit`` makes; the library fills in the filter's parameters).

    Raises
    ------
    ValueError
        Another dtype than uint16 or another precision than :data:`NBIT_BITS`.
    """
    if np.dtype(dtype) != np.uint16 or bits != NBIT_BITS:
        raise ValueError(f"the nbit frame filter stores {NBIT_BITS}-bit values in uint16 only (for now), "
                         f"got {np.dtype(dtype)} of {bits} bits; use gzip")
    tid = h5py.h5t.STD_U16LE.copy()
    tid.set_precision(bits)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_filter(h5py.h5z.FILTER_NBIT, h5py.h5z.FLAG_OPTIONAL, ())
    return group.create_dataset(key, shape=shape, dtype=tid, chunks=chunks, dcpl=dcpl)


def _is_nbit12_frames(ds: h5py.Dataset) -> bool:
    """Whether ``ds`` is (n, ...) little-endian uint16 of 12 bits of precision, one frame per
    chunk, every chunk written, under the N-bit filter alone: chunks :func:`unpack_nbit12` reads."""
    if ds.ndim < 2 or ds.chunks != (1, *ds.shape[1:]) or ds.dtype != np.dtype("<u2"):
        return False
    tid, dcpl = ds.id.get_type(), ds.id.get_create_plist()
    if (tid.get_precision(), tid.get_offset()) != (NBIT_BITS, 0) or dcpl.get_nfilters() != 1:
        return False
    return dcpl.get_filter(0)[0] == h5py.h5z.FILTER_NBIT and ds.id.get_num_chunks() == ds.shape[0]


class FrameReader:
    """Frames of a one-frame-per-chunk dataset, indexed along the first axis, read fast.

    N-bit 12-bit datasets (:data:`COMPRESSIONS` "nbit") are read chunk by chunk as stored
    (``read_direct_chunk``) and unpacked with numpy (:func:`vfcli.store.chunks.unpack_nbit12`),
    several times faster than libhdf5's N-bit filter; any other dataset, and any other key,
    is read by h5py. Same values either way.

    Attributes
    ----------
    shape, dtype, ndim
        The dataset's.
    """

    def __init__(self, ds: h5py.Dataset) -> None:
        self._ds = ds
        self.shape: tuple[int, ...] = ds.shape
        self.dtype: np.dtype = ds.dtype
        self.ndim: int = ds.ndim
        self._nbit = _is_nbit12_frames(ds)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        """Frames by ``key``: an int ((H, W) frame), a slice or a 1-D integer array of frame
        indices, in any order ((k, H, W); numpy's rules), or ``()``/``...`` (all); any other
        key as h5py indexes."""
        idx = self._indices(key)
        if idx is None:
            return self._ds[key]
        if self._nbit:
            frames = self._read(idx)
        elif isinstance(key, slice) and (key.step or 1) > 0:
            frames = self._ds[key]
        else:                                   # h5py reads increasing indices only
            unique, inverse = np.unique(idx, return_inverse=True)
            frames = self._ds[unique][inverse]
        return frames[0] if isinstance(key, (int, np.integer)) else frames

    def _indices(self, key: Any) -> np.ndarray | None:
        """Frame indices (k,), each in 0..n-1, that ``key`` selects; None where h5py reads
        the key as it is (not a frame selection; all frames of a dataset not unpacked here).

        Raises
        ------
        IndexError
            Indices outside the dataset.
        """
        if self.ndim == 0:
            return None
        n = len(self)
        if isinstance(key, slice):
            return np.arange(*key.indices(n))
        if key is Ellipsis or (isinstance(key, tuple) and key == ()):
            return np.arange(n) if self._nbit else None
        idx = None if isinstance(key, tuple) else np.asarray(key)
        if idx is None or idx.ndim > 1 or idx.dtype.kind not in "iu":
            return None
        idx = idx.reshape(-1)
        if idx.size and (idx.min() < -n or idx.max() >= n):
            raise IndexError(f"frame index out of range for {n} frames")
        return idx % n

    def _read(self, idx: np.ndarray) -> np.ndarray:
        """Frames ``idx`` (k,), each in 0..n-1, of an N-bit dataset as a (k, *frame shape) array."""
        out = np.empty((idx.size, *self.shape[1:]), self.dtype)
        pixels = int(np.prod(self.shape[1:]))
        flat = out.reshape(idx.size, pixels)
        zeros = (0,) * (self.ndim - 1)
        for k, i in enumerate(idx.tolist()):
            mask, chunk = self._ds.id.read_direct_chunk((i, *zeros))
            if mask:                      # the optional filter was skipped: not packed
                out[k] = self._ds[i]
            else:
                unpack_nbit12(chunk, pixels, out=flat[k])
        return out

