"""Chunk encoding: the bytes vfcli writes are what HDF5's shuffle + deflate filters read
back with plain zlib, incompressible byte planes are stored, and the parallel pipeline
keeps frame order, bounded memory and errors."""
from __future__ import annotations

import threading
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from vfcli.frame_chunks import (
    ZLIB_HEADER,
    ChunkCodec,
    deflate_planes,
    encode_chunk,
    encode_frames,
    looks_incompressible,
    shuffle_bytes,
    unshuffle_bytes,
)
from vfcli.store import CHUNK_CODECS

CODECS = {**CHUNK_CODECS, "isal whole": ChunkCodec(True, "isal", 1), "zlib whole": ChunkCodec(True, "zlib", 1)}


def _sensor_frame(h=256, w=256, seed=0):
    """12-bit texture plus noise: a compressible high byte, an incompressible low byte."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = 1800 + 600 * np.sin(xx / 7.0) * np.cos(yy / 5.0) + rng.normal(0, 200, (h, w))
    return np.clip(img, 0, 4095).astype(np.uint16)


def _hdf5_shuffle(a: np.ndarray) -> bytes:
    """Reference: HDF5's shuffle filter is a transpose of the (n, itemsize) byte matrix."""
    return np.ascontiguousarray(a.reshape(-1).view(np.uint8).reshape(-1, a.dtype.itemsize).T).tobytes()


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(st.sampled_from(["<u2", ">u2", "u1", "<i4", "<f8", ">f4"]),
                  hnp.array_shapes(min_dims=1, max_dims=3, max_side=9)))
def test_shuffle_bytes_is_hdf5s_shuffle_and_unshuffle_inverts_it(a):
    shuffled = shuffle_bytes(a)
    assert shuffled.tobytes() == _hdf5_shuffle(a)
    assert unshuffle_bytes(shuffled.tobytes(), a.dtype).tobytes() == a.tobytes()


@pytest.mark.parametrize("codec", CODECS, ids=str)
@pytest.mark.parametrize("frame", [
    _sensor_frame(),
    np.zeros((64, 80), np.uint16),
    np.full((3, 5), 4095, np.uint16),
    np.random.default_rng(1).integers(0, 256, (200, 300), dtype=np.uint8),
    np.random.default_rng(2).integers(0, 2**16, (1, 1), dtype=np.uint16),
    (np.arange(512 * 512) % 4096).astype(np.uint16).reshape(512, 512),
], ids=["sensor", "zeros", "saturated", "u8-noise", "one-pixel", "ramp"])
def test_encoded_chunk_inflates_with_plain_zlib_to_the_shuffled_frame(codec, frame):
    c = CODECS[codec]
    out = bytes(encode_chunk(frame, c))
    expected = _hdf5_shuffle(frame) if c.shuffle else frame.tobytes()
    assert (zlib.decompress(out) if c.deflate else out) == expected


def test_noise_plane_is_stored_and_texture_plane_deflated():
    frame = _sensor_frame(512, 512)
    n = frame.size
    planes = shuffle_bytes(frame).reshape(2, n)
    codec = CHUNK_CODECS["gzip"]
    assert looks_incompressible(planes[0], codec)        # low byte: sensor noise
    assert not looks_incompressible(planes[1], codec)    # high byte: 4 bits of texture
    out = deflate_planes(shuffle_bytes(frame), 2, codec)
    assert out.startswith(ZLIB_HEADER)
    # stored low plane (plus 5-byte block headers) + a deflated high plane well under n
    assert n < len(out) < n + 0.6 * n
    assert zlib.decompress(out) == _hdf5_shuffle(frame)


def test_per_plane_deflate_is_no_larger_than_one_deflate_call():
    frames = [_sensor_frame(seed=s) for s in range(4)]
    planes = sum(len(encode_chunk(f, CHUNK_CODECS["gzip"])) for f in frames)
    whole = sum(len(encode_chunk(f, CODECS["isal whole"])) for f in frames)
    assert planes <= 1.01 * whole


class _LazyBatch:
    """A FrameBatch that counts decodes in flight and can fail on one frame."""

    def __init__(self, frames, counter, fail_at=None):
        self._frames, self._counter, self._fail_at = frames, counter, fail_at
        self.shape, self.dtype = frames.shape, frames.dtype

    def __len__(self):
        return len(self._frames)

    def __getitem__(self, i):
        if i == self._fail_at:
            raise OSError("disk read error")
        self._counter.decoded()
        return self._frames[i]


class _Counter:
    def __init__(self):
        self.lock = threading.Lock()
        self.n_decoded = 0

    def decoded(self):
        with self.lock:
            self.n_decoded += 1


@pytest.mark.parametrize("compression", ["gzip", "none"])
def test_encode_frames_keeps_frame_order_and_bounds_the_frames_in_flight(compression):
    frames = np.stack([_sensor_frame(32, 48, seed=s) for s in range(200)])
    counter = _Counter()
    batches = (_LazyBatch(frames[a:a + 7], counter) for a in range(0, len(frames), 7))
    frame_bytes = frames[0].nbytes
    max_ahead = 0
    for index, chunk in encode_frames(batches, frames.dtype, CHUNK_CODECS[compression],
                                      workers=2, pending_bytes=10 * frame_bytes):
        max_ahead = max(max_ahead, counter.n_decoded - index)
        if compression == "gzip":
            decoded = unshuffle_bytes(zlib.decompress(bytes(chunk)), frames.dtype)
        else:
            decoded = np.frombuffer(bytes(chunk), frames.dtype)
        assert decoded.tobytes() == frames[index].tobytes()
    assert index == len(frames) - 1
    assert max_ahead <= 10 + 1, f"{max_ahead} frames decoded ahead of the writer"


def test_a_frame_that_fails_to_decode_stops_the_stream_with_its_error():
    frames = np.stack([_sensor_frame(16, 16, seed=s) for s in range(40)])
    batches = [_LazyBatch(frames[:20], _Counter()), _LazyBatch(frames[20:], _Counter(), fail_at=5)]
    seen = []
    with pytest.raises(OSError, match="disk read error"):
        for index, _ in encode_frames(iter(batches), frames.dtype, CHUNK_CODECS["gzip"], workers=2):
            seen.append(index)
    assert seen == list(range(len(seen))) and len(seen) <= 25
    assert not [t for t in threading.enumerate() if t.name.startswith("vfcli-encode")]
