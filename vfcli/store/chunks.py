"""HDF5 chunk bytes of video frames, encoded in parallel.

Deflate
-------
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

N-bit
-----
HDF5's built-in N-bit filter (filter 5, in every libhdf5) on a uint16 type of precision 12
stores a chunk as its values' 12 significant bits, one after the other, most significant
bit first, then zero bits up to the next byte and one more zero byte:
``n * 12 // 8 + 1`` bytes for ``n`` pixels (:func:`pack_nbit12`). For an even ``n`` that is
exactly the packed big-endian 12-bit layout of a Photron MRAW
(:func:`vfcli.io.video.photron.pack_12bit`) plus a zero byte, so a 12-bit MRAW frame becomes its
chunk without being decoded at all (:func:`nbit12_chunk_of_packed`), and a chunk is read
back with the same vectorised unpacking (:func:`unpack_nbit12`), several times faster than
libhdf5's own N-bit decoder.

No HDF5 here: :mod:`vfcli.store.transaction` and :mod:`vfcli.store.frames` own the file.
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

from vfcli.io.video.photron import Packed12Frames, pack_12bit, unpack_12bit

if TYPE_CHECKING:
    from vfcli.io.video.base import FrameBatch

log = logging.getLogger(__name__)

#: Frames in flight (queued, being decoded and encoded, or waiting to be written), at most,
#: in bytes of decoded frames: about one batch of :meth:`vfcli.io.video.base.VideoSource.iter_frames`,
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
    nbit : int or None
        Bits kept of each unsigned integer (HDF5's N-bit filter, :func:`pack_nbit12`; only
        12 is supported, alone: no shuffle or deflate). None: every bit.
    """

    shuffle: bool = False
    deflate: Literal["isal", "zlib"] | None = None
    level: int = 1
    per_plane: bool = False
    nbit: int | None = None

    def __post_init__(self) -> None:
        if self.nbit is not None and (self.nbit != NBIT_BITS or self.shuffle or self.deflate):
            raise ValueError(f"N-bit chunks keep {NBIT_BITS} bits, without shuffle or deflate; got {self}")


#: The one precision the N-bit chunks support, bits per pixel (12-bit sensors).
NBIT_BITS = 12


class ValueRangeError(ValueError):
    """A pixel value that the chunk's bits cannot hold.

    Attributes
    ----------
    value : int
        The largest value of the frame.
    bits : int
        Bits kept per value.
    frame : int or None
        Index of the frame in the stream (:func:`encode_frames`), when known.
    """

    def __init__(self, value: int, bits: int, frame: int | None = None) -> None:
        self.value, self.bits, self.frame = value, bits, frame
        where = "" if frame is None else f"frame {frame}: "
        super().__init__(f"{where}value {value} does not fit in {bits} bits (0..{2**bits - 1})")


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


def nbit_chunk_nbytes(n_values: int, bits: int = NBIT_BITS) -> int:
    """Bytes of HDF5's N-bit filter output for ``n_values`` values of ``bits`` bits:
    ``n_values * bits // 8 + 1`` (libhdf5 always writes one byte more than the bits need)."""
    return n_values * bits // 8 + 1


def pack_nbit12(values: np.ndarray) -> np.ndarray:
    """The N-bit chunk of 12-bit values: what HDF5's N-bit filter writes for them.

    Parameters
    ----------
    values : (...) unsigned integer array
        One whole chunk (here one (H, W) frame), each value 0..4095.

    Returns
    -------
    (n * 12 // 8 + 1,) uint8, n = values.size
        The values' 12 bits most significant first (:func:`vfcli.io.video.photron.pack_12bit`),
        then zero bits to the end.

    Raises
    ------
    ValueRangeError
        A value above 4095 (the largest one is named).
    ValueError
        Values that are not unsigned integers.
    """
    flat = np.asarray(values).reshape(-1)
    if flat.dtype.kind != "u":
        raise ValueError(f"N-bit chunks hold unsigned integers, got {flat.dtype}")
    if flat.size and (top := int(flat.max())) >= 1 << NBIT_BITS:
        raise ValueRangeError(top, NBIT_BITS)
    out = np.zeros(nbit_chunk_nbytes(flat.size), np.uint8)
    if flat.size % 2:                        # a zero pixel completes the last pair
        flat = np.append(flat, flat.dtype.type(0))
    packed = pack_12bit(flat)
    m = min(out.size, packed.size)           # odd n: the zero pixel's last byte is cut
    out[:m] = packed[:m]
    return out


def nbit12_chunk_of_packed(packed: np.ndarray) -> bytes:
    """The N-bit chunk of a frame already packed as 12-bit MRAW pixels, without decoding it.

    Parameters
    ----------
    packed : (3 m,) uint8
        Packed big-endian 12-bit pixels, two per three bytes (an even pixel count ``2 m``).

    Returns
    -------
    bytes, 3 m + 1 of them
        ``packed`` and a zero byte: equal to :func:`pack_nbit12` of the decoded pixels.
    """
    if packed.size % 3:
        raise ValueError(f"packed 12-bit bytes come in threes (two pixels), got {packed.size}")
    return b"".join((memoryview(np.ascontiguousarray(packed)).cast("B"), b"\0"))


def unpack_nbit12(chunk: bytes | np.ndarray, n: int, out: np.ndarray | None = None) -> np.ndarray:
    """Values of an N-bit chunk of 12-bit values (inverse of :func:`pack_nbit12`).

    Parameters
    ----------
    chunk : bytes or (n * 12 // 8 + 1,) uint8
        The chunk as stored (``read_direct_chunk``).
    n : int
        Values in the chunk.
    out : (n,) uint16, optional
        Where to write them (C-contiguous).

    Returns
    -------
    (n,) uint16
        Values 0..4095.

    Raises
    ------
    ValueError
        A chunk of another size than ``n`` values need.
    """
    raw = np.frombuffer(chunk, np.uint8)
    if raw.size != nbit_chunk_nbytes(n):
        raise ValueError(f"an N-bit chunk of {n} 12-bit values has {nbit_chunk_nbytes(n)} bytes, got {raw.size}")
    if n % 2 == 0:
        return unpack_12bit(raw[: 3 * n // 2], out)
    whole = np.zeros(3 * (n + 1) // 2, np.uint8)   # odd n: complete the last pair
    whole[: raw.size] = raw
    values = unpack_12bit(whole)[:n]
    if out is None:
        return values
    out[...] = values
    return out


def encode_chunk(chunk: np.ndarray, codec: ChunkCodec) -> bytes | np.ndarray:
    """The bytes HDF5 stores for one chunk under ``codec``'s filters.

    Parameters
    ----------
    chunk : (...) array
        One whole chunk (here: one frame, (H, W)), already in the dataset's file dtype.
    codec : ChunkCodec

    Returns
    -------
    bytes or uint8 array
        A zlib stream (deflate), the N-bit packed values (:func:`pack_nbit12`), or the raw,
        possibly shuffled, bytes.

    Raises
    ------
    ValueRangeError
        N-bit: a value the bits cannot hold.
    """
    if codec.nbit is not None:
        return pack_nbit12(chunk)
    data = shuffle_bytes(chunk) if codec.shuffle else np.ascontiguousarray(chunk).reshape(-1).view(np.uint8)
    if codec.deflate is None:
        return data
    if codec.per_plane and data.size:
        return deflate_planes(data, chunk.dtype.itemsize if codec.shuffle else 1, codec)
    lib = isal_zlib if codec.deflate == "isal" else zlib
    return lib.compress(data, codec.level)


def default_workers() -> int:
    """Encoding threads: one per core available to this process (:func:`vfcli.parallel.available_cores`), at most 4."""
    from vfcli.parallel import available_cores

    return min(4, available_cores())


def encode_frame(batch: FrameBatch, i: int, dtype: np.dtype, codec: ChunkCodec) -> bytes | np.ndarray:
    """Frame ``i`` of ``batch`` (decoded here if the batch is lazy) as chunk bytes.

    A whole frame of 12-bit packed MRAW (:class:`vfcli.io.video.photron.Packed12Frames`) becomes
    its N-bit chunk as it is, not decoded (:func:`nbit12_chunk_of_packed`).

    Parameters
    ----------
    batch : FrameBatch
        A (k, H, W) array or a lazily decoding batch (:class:`vfcli.io.video.base.FrameBatch`).
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
    if codec.nbit == NBIT_BITS and isinstance(batch, Packed12Frames):
        packed = batch.packed(i)
        if packed is not None:
            return nbit12_chunk_of_packed(packed)
    return encode_chunk(np.ascontiguousarray(batch[i], dtype=dtype), codec)


def _chunk(future: Future, index: int) -> bytes | np.ndarray:
    """The chunk a worker made of frame ``index``; a :class:`ValueRangeError` names the frame."""
    try:
        return future.result()
    except ValueRangeError as exc:
        raise ValueRangeError(exc.value, exc.bits, index) from None


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
        (:class:`vfcli.io.video.base.FrameBatch`); k >= 0 per batch.
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

    Raises
    ------
    ValueRangeError
        A frame value the codec's bits cannot hold, with the frame's index.
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
                    yield index, _chunk(pending.popleft(), index)
                    index += 1
        while pending:
            yield index, _chunk(pending.popleft(), index)
            index += 1
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
