"""HDF5 chunk bytes of video frames, encoded in parallel.

HDF5's standard ``shuffle`` and ``deflate`` (gzip) filters store a chunk as the zlib
stream of its byte-shuffled bytes: byte 0 of every element, then byte 1, ... This
module produces that encoding itself, per frame (one frame = one chunk), in a thread
pool pipelined with the caller's decoding, so the store can hand finished chunks to
HDF5 unfiltered (``write_direct_chunk``). Every HDF5 reader decodes them with the
dataset's ordinary filter pipeline: plain zlib, no plugin.

Two things make it fast:

* Deflate runs in `ISA-L <https://github.com/intel/isa-l>`_ (``isal``; several times
  faster than zlib at a similar ratio) or zlib, both of which release the GIL: two
  workers compress two frames while the caller reads and decodes the next batch.
* Each byte plane of the shuffled chunk is its own run of deflate blocks
  (:func:`deflate_planes`), still one zlib stream. A plane that a small sample shows to
  be incompressible (the low byte of 12-bit sensor noise: half the data) is written as
  stored blocks instead of being compressed for nothing, and the compressible planes
  get Huffman tables of their own (files come out no larger, often smaller).

No HDF5 here: :mod:`vfcli.store` owns the file.
"""
from __future__ import annotations

import logging
import os
import struct
import zlib
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Iterator, Literal

import numpy as np
from isal import isal_zlib

if TYPE_CHECKING:
    from vfcli.io.video import FrameBatch

log = logging.getLogger(__name__)

#: Frames in flight (queued, being decoded and encoded, or waiting to be written), at most,
#: in bytes of decoded frames: about one batch of :meth:`vfcli.io.video.VideoSource.iter_frames`,
#: enough to keep the workers busy while the caller reads the next batch. Memory stays
#: about this plus two of the caller's batches, whatever the video's size.
DEFAULT_PENDING_BYTES = 32 * 2**20


@dataclass(frozen=True)
class ChunkCodec:
    """How one chunk's bytes are made.

    Attributes
    ----------
    shuffle : bool
        Byte-shuffle first (HDF5's ``shuffle`` filter).
    deflate : {'isal', 'zlib'} or None
        Deflate engine (HDF5's ``deflate`` filter, zlib format); None stores raw bytes.
    level : int
        Deflate level of that engine (isal: 0..3, zlib: 0..9).
    per_plane : bool
        Deflate each byte plane on its own, storing incompressible planes
        (:func:`deflate_planes`); otherwise one deflate call on the whole chunk.
    """

    shuffle: bool = False
    deflate: Literal["isal", "zlib"] | None = None
    level: int = 1
    per_plane: bool = False


def shuffle_bytes(chunk: np.ndarray) -> np.ndarray:
    """Byte-shuffle a chunk as HDF5's shuffle filter does.

    Parameters
    ----------
    chunk : (...) array, C-contiguous, any fixed-size dtype
        The chunk's elements in file byte order.

    Returns
    -------
    (chunk.nbytes,) uint8
        Byte 0 of every element, then byte 1, ... (a copy; the input itself for 1-byte
        elements).
    """
    size = chunk.dtype.itemsize
    raw = np.ascontiguousarray(chunk).reshape(-1).view(np.uint8)
    if size == 1:
        return raw
    if size not in (2, 4, 8):
        return np.ascontiguousarray(raw.reshape(-1, size).T).reshape(-1)
    # Memory bytes read as a little-endian word: byte j is (word >> 8 j) & 0xFF. Two
    # ufuncs per byte plane run about 3x faster than a transposing copy.
    words = raw.view(f"<u{size}")
    out = np.empty((size, words.size), np.uint8)
    np.bitwise_and(words, 0xFF, out=out[0], casting="unsafe")
    if size == 2:
        np.right_shift(words, 8, out=out[1], casting="unsafe")
    else:
        shifted = np.empty_like(words)
        for j in range(1, size):
            np.right_shift(words, 8 * j, out=shifted)
            np.bitwise_and(shifted, 0xFF, out=out[j], casting="unsafe")
    return out.reshape(-1)


def unshuffle_bytes(data: bytes | np.ndarray, dtype: np.dtype | str) -> np.ndarray:
    """Inverse of :func:`shuffle_bytes` (for tests and checks).

    Parameters
    ----------
    data : bytes or (n * itemsize,) uint8
        Shuffled bytes.
    dtype : numpy dtype
        Element type in file byte order.

    Returns
    -------
    (n,) array of ``dtype``
    """
    dtype = np.dtype(dtype)
    raw = np.frombuffer(data, np.uint8)
    return np.ascontiguousarray(raw.reshape(dtype.itemsize, -1).T).reshape(-1).view(dtype)


#: zlib header: deflate, 32 KiB window, no preset dictionary, level field "fastest".
ZLIB_HEADER = b"\x78\x01"
#: Bytes of a plane sampled to decide whether to compress it, and in how many pieces.
SAMPLE_BYTES, SAMPLE_PIECES = 8192, 8
#: A plane whose sample deflates to at least this fraction of its size is stored.
STORE_ABOVE_RATIO = 0.97
_STORED_MAX = 65535  # bytes per stored deflate block


def stored_blocks(data: memoryview, final: bool) -> list[bytes | memoryview]:
    """Raw deflate stored blocks holding ``data`` (byte-aligned, as after a sync flush).

    Parameters
    ----------
    data : memoryview of bytes
    final : bool
        Mark the last block as the stream's final block.

    Returns
    -------
    list of bytes-like
        Block headers and slices of ``data``, to be joined.
    """
    parts: list[bytes | memoryview] = []
    n = len(data)
    for a in range(0, max(n, 1), _STORED_MAX):
        b = min(n, a + _STORED_MAX)
        parts.append(struct.pack("<BHH", int(final and b == n), b - a, (b - a) ^ 0xFFFF))
        parts.append(data[a:b])
    return parts


def raw_deflate(data: memoryview, codec: ChunkCodec, final: bool) -> bytes:
    """Raw deflate blocks of ``data``; byte-aligned and open (sync flush) unless ``final``."""
    lib = isal_zlib if codec.deflate == "isal" else zlib
    if final:
        return lib.compress(data, codec.level, wbits=-15)
    c = lib.compressobj(codec.level, lib.DEFLATED, -15)
    return c.compress(data) + c.flush(lib.Z_SYNC_FLUSH)


def looks_incompressible(plane: np.ndarray, codec: ChunkCodec) -> bool:
    """Whether a byte plane is not worth deflating, judged on a sample.

    Parameters
    ----------
    plane : (n,) uint8
        One byte plane of a shuffled chunk.
    codec : ChunkCodec

    Returns
    -------
    bool
        True when :data:`SAMPLE_PIECES` slices spread over the plane, :data:`SAMPLE_BYTES`
        in all, deflate to at least :data:`STORE_ABOVE_RATIO` of their size. Planes under
        four samples long are always compressed.
    """
    n = plane.size
    if n < 4 * SAMPLE_BYTES:
        return False
    piece = SAMPLE_BYTES // SAMPLE_PIECES
    rows = plane[: n - n % SAMPLE_PIECES].reshape(SAMPLE_PIECES, -1)
    sample = np.ascontiguousarray(rows[:, :piece])
    return len(raw_deflate(memoryview(sample).cast("B"), codec, final=True)) >= STORE_ABOVE_RATIO * sample.size


def deflate_planes(shuffled: np.ndarray, itemsize: int, codec: ChunkCodec) -> bytes:
    """A zlib stream of a shuffled chunk, one run of deflate blocks per byte plane.

    Planes that :func:`looks_incompressible` are stored blocks; the others are deflated
    on their own (their own Huffman tables). Any inflater reads the result as one
    ordinary zlib stream of ``shuffled``.

    Parameters
    ----------
    shuffled : (itemsize * n,) uint8
        Output of :func:`shuffle_bytes`.
    itemsize : int
        Bytes per element: the number of planes.
    codec : ChunkCodec

    Returns
    -------
    bytes
        zlib header, deflate blocks, Adler-32 of ``shuffled``.
    """
    whole = memoryview(shuffled).cast("B")
    planes = shuffled.reshape(itemsize, -1)
    parts: list[bytes | memoryview] = [ZLIB_HEADER]
    for j in range(itemsize):
        final = j == itemsize - 1
        plane = memoryview(planes[j]).cast("B")
        if looks_incompressible(planes[j], codec):
            parts.extend(stored_blocks(plane, final))
        else:
            parts.append(raw_deflate(plane, codec, final))
    parts.append(struct.pack(">I", isal_zlib.adler32(whole)))
    return b"".join(parts)


def encode_chunk(chunk: np.ndarray, codec: ChunkCodec) -> bytes | np.ndarray:
    """The bytes HDF5 stores for one chunk under ``codec``'s filters.

    Parameters
    ----------
    chunk : (...) array
        One whole chunk (here: one frame, (H, W)), already in the dataset's file dtype.
    codec : ChunkCodec

    Returns
    -------
    bytes or (chunk.nbytes,) uint8 array
        A zlib stream (deflate) or the raw, possibly shuffled, bytes.
    """
    data = shuffle_bytes(chunk) if codec.shuffle else np.ascontiguousarray(chunk).reshape(-1).view(np.uint8)
    if codec.deflate is None:
        return data
    if codec.per_plane and data.size:
        return deflate_planes(data, chunk.dtype.itemsize if codec.shuffle else 1, codec)
    lib = isal_zlib if codec.deflate == "isal" else zlib
    return lib.compress(data, codec.level)


def default_workers() -> int:
    """Encoding threads: one per core available to this process, at most 4."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def encode_frame(batch: FrameBatch, i: int, dtype: np.dtype, codec: ChunkCodec) -> bytes | np.ndarray:
    """Frame ``i`` of ``batch`` (decoded here if the batch is lazy) as chunk bytes.

    Parameters
    ----------
    batch : FrameBatch
        A (k, H, W) array or a lazily decoding batch (:class:`vfcli.io.video.FrameBatch`).
    i : int
        Frame within the batch.
    dtype : numpy dtype
        The dataset's file dtype.
    codec : ChunkCodec

    Returns
    -------
    bytes or uint8 array
        :func:`encode_chunk` of the frame.
    """
    return encode_chunk(np.ascontiguousarray(batch[i], dtype=dtype), codec)


def encode_frames(
    batches: Iterable[FrameBatch],
    dtype: np.dtype,
    codec: ChunkCodec,
    *,
    workers: int | None = None,
    pending_bytes: int | None = None,
) -> Iterator[tuple[int, bytes | np.ndarray]]:
    """Decode and encode a stream of frame batches, one chunk per frame, in a thread pool.

    The caller's iterator (reading the file) runs in the calling thread while the workers
    decode (lazy batches) and encode the frames already read; chunks come back in frame
    order, to be written by the calling thread.

    Parameters
    ----------
    batches : iterable of FrameBatch
        (k, H, W) arrays, or lazy batches that decode frame ``i`` on ``batch[i]``
        (:class:`vfcli.io.video.FrameBatch`); k >= 0 per batch.
    dtype : numpy dtype
        The dataset's file dtype (frames are converted to it).
    codec : ChunkCodec
    workers : int, optional
        Threads (default :func:`default_workers`).
    pending_bytes : int, optional
        Most decoded-frame bytes in flight, bytes (default :data:`DEFAULT_PENDING_BYTES`);
        at least two frames per worker.

    Yields
    ------
    (index, chunk) : (int, bytes or uint8 array)
        Frame index from 0 and its encoded chunk (:func:`encode_chunk`).
    """
    dtype = np.dtype(dtype)
    pending_bytes = DEFAULT_PENDING_BYTES if pending_bytes is None else pending_bytes
    index = 0
    n_workers = workers or default_workers()
    log.debug("encoding chunks (%s) in %d threads, up to %d MB of frames in flight", codec, n_workers,
              pending_bytes // 10**6)
    pool = ThreadPoolExecutor(max_workers=n_workers, thread_name_prefix="vfcli-encode")
    pending: deque[Future] = deque()
    try:
        for batch in batches:
            k = len(batch)
            if k == 0:
                continue
            frame_bytes = int(np.prod(batch.shape[1:])) * dtype.itemsize
            max_pending = max(2 * n_workers, pending_bytes // max(1, frame_bytes))
            for i in range(k):
                pending.append(pool.submit(encode_frame, batch, i, dtype, codec))
                while len(pending) > max_pending:
                    yield index, pending.popleft().result()
                    index += 1
        while pending:
            yield index, pending.popleft().result()
            index += 1
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
