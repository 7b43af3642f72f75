"""Chunk encoding: the bytes vfcli writes are what HDF5's shuffle + deflate filters read
back with plain zlib, incompressible byte planes are stored, N-bit chunks are byte for
byte what HDF5's own N-bit filter writes (a 12-bit MRAW frame's bytes plus a zero byte),
and the parallel pipeline keeps frame order, bounded memory and errors."""
from __future__ import annotations

import threading
import zlib

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from vfcli.store.chunks import (
    ZLIB_HEADER,
    ChunkCodec,
    ValueRangeError,
    deflate_planes,
    encode_chunk,
    encode_frame,
    encode_frames,
    looks_incompressible,
    nbit12_chunk_of_packed,
    pack_nbit12,
    shuffle_bytes,
    unpack_nbit12,
    unshuffle_bytes,
)
from vfcli.io.video.photron import Packed12Frames, pack_12bit
from vfcli.store import CHUNK_CODECS

#: Codecs whose chunks are zlib streams or raw bytes (N-bit chunks are tested on their own).
CODECS = {**{k: c for k, c in CHUNK_CODECS.items() if c.nbit is None},
          "isal whole": ChunkCodec(True, "isal", 1), "zlib whole": ChunkCodec(True, "zlib", 1)}


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


# --------------------------------------------------------------------------- N-bit chunks

def _hdf5_nbit_chunk(frame: np.ndarray, tmp_path) -> bytes:
    """Reference: the chunk libhdf5's own N-bit filter writes for ``frame`` (uint16 of 12 bits
    of precision, one frame per chunk, written through h5py's ordinary filtered path)."""
    tid = h5py.h5t.STD_U16LE.copy()
    tid.set_precision(12)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_filter(h5py.h5z.FILTER_NBIT, h5py.h5z.FLAG_OPTIONAL, ())
    with h5py.File(tmp_path / "ref.h5", "w") as f:
        ds = f.create_dataset("x", shape=(1, *frame.shape), dtype=tid, chunks=(1, *frame.shape), dcpl=dcpl)
        ds[0] = frame
        mask, chunk = ds.id.read_direct_chunk((0,) * (frame.ndim + 1))
    assert mask == 0
    return chunk


NBIT_FRAMES = {
    "sensor": _sensor_frame(512, 512),
    "zeros": np.zeros((64, 80), np.uint16),
    "saturated": np.full((4, 6), 4095, np.uint16),
    "odd 3x5": np.random.default_rng(3).integers(0, 4096, (3, 5), dtype=np.uint16),
    "one pixel": np.array([[2748]], np.uint16),
    "ramp": (np.arange(512 * 512) % 4096).astype(np.uint16).reshape(512, 512),
}


@pytest.mark.parametrize("name", NBIT_FRAMES)
def test_nbit_chunk_is_byte_for_byte_what_hdf5s_nbit_filter_writes(name, tmp_path):
    frame = NBIT_FRAMES[name]
    expected = _hdf5_nbit_chunk(frame, tmp_path)
    assert len(expected) == frame.size * 12 // 8 + 1      # libhdf5 writes one byte more than the bits
    assert bytes(encode_chunk(frame, CHUNK_CODECS["nbit"])) == expected
    assert unpack_nbit12(expected, frame.size).tobytes() == frame.tobytes()
    if frame.size % 2 == 0:                                # the MRAW frame's bytes plus a zero byte
        assert nbit12_chunk_of_packed(pack_12bit(frame.reshape(-1))) == expected


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.uint16, st.integers(1, 40), elements=st.integers(0, 4095)))
def test_unpack_nbit12_inverts_pack_nbit12_for_any_pixel_count(values):
    chunk = pack_nbit12(values)
    assert chunk.size == values.size * 12 // 8 + 1
    out = np.empty(values.size, np.uint16)
    assert unpack_nbit12(chunk.tobytes(), values.size, out=out) is out
    assert out.tobytes() == values.tobytes()


def _packed_batch(frames: np.ndarray, rows=slice(None), cols=slice(None)) -> Packed12Frames:
    k, h, w = frames.shape
    return Packed12Frames(pack_12bit(frames.reshape(-1)), h, w, rows, cols)


def test_a_whole_mraw_frame_becomes_its_nbit_chunk_without_being_decoded(monkeypatch):
    frames = np.stack([_sensor_frame(32, 48, seed=s) for s in range(3)])
    batch = _packed_batch(frames)

    def no_decoding(self, i):
        raise AssertionError("decoded a frame the N-bit chunk copies as stored")

    monkeypatch.setattr(Packed12Frames, "__getitem__", no_decoding)
    for i in range(3):
        chunk = encode_frame(batch, i, np.dtype(np.uint16), CHUNK_CODECS["nbit"])
        assert bytes(chunk) == pack_nbit12(frames[i]).tobytes()


@pytest.mark.parametrize("rows,cols", [(slice(1, 30), slice(2, 47)), (slice(0, 32), slice(3, 4))],
                         ids=["odd window", "one column"])
def test_a_cropped_mraw_frame_is_decoded_cut_and_packed(rows, cols):
    frames = np.stack([_sensor_frame(32, 48, seed=s) for s in range(2)])
    batch = _packed_batch(frames, rows, cols)
    for i in range(2):
        chunk = bytes(encode_frame(batch, i, np.dtype(np.uint16), CHUNK_CODECS["nbit"]))
        window = frames[i, rows, cols]
        assert chunk == pack_nbit12(window).tobytes()
        assert unpack_nbit12(chunk, window.size).reshape(window.shape).tobytes() == window.tobytes()


def test_a_value_above_4095_stops_the_nbit_stream_naming_frame_and_value():
    frames = np.stack([_sensor_frame(16, 16, seed=s) for s in range(40)])
    frames[23, 5, 7] = 4096
    frames[23, 1, 1] = 60000
    with pytest.raises(ValueRangeError, match="frame 23: value 60000 does not fit in 12 bits") as err:
        for _ in encode_frames((frames[a:a + 9] for a in range(0, 40, 9)), frames.dtype, CHUNK_CODECS["nbit"],
                               workers=2):
            pass
    assert (err.value.frame, err.value.value, err.value.bits) == (23, 60000, 12)


@pytest.mark.parametrize("codec", [dict(nbit=10), dict(nbit=12, shuffle=True), dict(nbit=12, deflate="isal")],
                         ids=str)
def test_nbit_chunks_are_12_bit_and_unfiltered_only(codec):
    with pytest.raises(ValueError, match="12 bits"):
        ChunkCodec(**codec)


@pytest.mark.parametrize("dtype, frame_shape", [(np.float32, (48, 40, 2)), (bool, (48, 40)), (np.float32, (37, 3))])
def test_a_frame_sink_writes_what_libhdf5s_own_filters_write(tmp_path, dtype, frame_shape):
    """:class:`vfcli.store.frames.FrameSink` (the flow and synth stages' per-frame datasets): frames written
    one at a time and in slices read back through h5py (libhdf5's shuffle + deflate) equal to the same frames
    written by ``ds[k] = frame``, in a dataset with the same filters; a frame of another shape or a slice of the
    wrong length is refused."""
    from vfcli.store.frames import COMPRESSIONS, FrameSink

    rng = np.random.default_rng(3)
    n = 7
    frames = rng.normal(0, 100, (n, *frame_shape)).astype(np.float32)
    frames[:, : frame_shape[0] // 2] = np.round(frames[:, : frame_shape[0] // 2])   # a compressible half
    frames = (frames > 40) if dtype is bool else frames
    with h5py.File(tmp_path / "a.h5", "w") as f:
        plain = f.create_dataset("plain", (n, *frame_shape), dtype, chunks=(1, *frame_shape), **COMPRESSIONS["gzip"])
        sunk = f.create_dataset("sunk", (n, *frame_shape), dtype, chunks=(1, *frame_shape), **COMPRESSIONS["gzip"])
        sink = FrameSink(sunk)
        for k in range(n):
            plain[k] = frames[k]
        sink[0] = frames[0]
        sink[1:5] = frames[1:5]
        for k in (6, 5):
            sink[k] = frames[k]
        with pytest.raises(ValueError, match="shape"):
            sink[2] = frames[2][:-1]
        with pytest.raises(ValueError, match="need shape"):
            sink[1:3] = frames[1:4]
    with h5py.File(tmp_path / "a.h5", "r") as f:
        assert (f["sunk"].compression, f["sunk"].shuffle) == ("gzip", True)
        np.testing.assert_array_equal(f["sunk"][()], f["plain"][()])
        np.testing.assert_array_equal(f["sunk"][()], frames)
        assert f["sunk"].dtype == f["plain"].dtype


def test_a_frame_sink_needs_one_frame_per_chunk(tmp_path):
    from vfcli.store.frames import FrameSink

    with h5py.File(tmp_path / "b.h5", "w") as f:
        ds = f.create_dataset("x", (4, 8, 8), np.float32, chunks=(2, 8, 8), compression="gzip")
        with pytest.raises(ValueError, match="one frame per chunk"):
            FrameSink(ds)


@pytest.mark.parametrize("name", ["gzip", "gzip4", "none"])
def test_a_frame_sink_encodes_with_the_datasets_own_filters(tmp_path, name):
    """The sink's codec is read from the dataset's filters, never assumed: chunks written under each of vfcli's
    filters read back equal through h5py; filters vfcli does not write (LZF, gzip at level 9) are refused."""
    from vfcli.store.frames import COMPRESSIONS, FrameSink, compression_of

    frames = np.round(np.random.default_rng(5).normal(0, 50, (3, 16, 12)).astype(np.float32))
    with h5py.File(tmp_path / "c.h5", "w") as f:
        ds = f.create_dataset("x", frames.shape, np.float32, chunks=(1, 16, 12), **COMPRESSIONS[name])
        assert compression_of(ds) == name
        FrameSink(ds)[0:3] = frames
        for other in ({"compression": "lzf"}, {"compression": "gzip", "compression_opts": 9, "shuffle": True}):
            odd = f.create_dataset(f"odd{len(f)}", frames.shape, np.float32, chunks=(1, 16, 12), **other)
            with pytest.raises(ValueError, match="none of vfcli's"):
                FrameSink(odd)
    with h5py.File(tmp_path / "c.h5", "r") as f:
        np.testing.assert_array_equal(f["x"][()], frames)


def test_the_nbit_filter_is_read_from_the_dataset(tmp_path):
    from vfcli.store.frames import compression_of, nbit_dataset

    with h5py.File(tmp_path / "d.h5", "w") as f:
        ds = nbit_dataset(f, "v", (2, 8, 8), np.uint16, (1, 8, 8), 12)
        assert compression_of(ds) == "nbit"
