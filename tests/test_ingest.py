"""`vfcli ingest-hsc` (the library call): the stored frames are the video's, bit for bit,
in a standard one-frame-per-chunk dataset, whatever the compression, frame range or ROI;
the raw files' hashes are recorded as before."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from vfcli.io.photron import write_mraw
from vfcli.provenance import sha256_file
from vfcli.stages.base import RunContext
from vfcli.stages.ingest import run_ingest_hsc
from vfcli.store import Store

FPS = 10000.0


def _video(tmp_path, n=37, h=24, w=30, bits=12):
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:h, 0:w]
    texture = 1800 + 600 * np.sin(xx / 7.0) * np.cos(yy / 5.0)
    frames = np.clip(texture + rng.normal(0, 200, (n, h, w)), 0, 4095).astype(np.uint16)
    if bits == 8:
        frames = (frames >> 4).astype(np.uint8)
    return frames, write_mraw(tmp_path / "v", iter(frames), FPS, bit_depth=bits)


def _ingest(store, cihx, *sets):
    return run_ingest_hsc(RunContext.open(store, None, list(sets)), cihx)


@pytest.mark.parametrize("compression", ["gzip", "gzip4", "none"])
@pytest.mark.parametrize("bits", [12, 16, 8])
def test_ingested_frames_are_the_videos_bit_for_bit_in_one_chunk_per_frame(tmp_path, compression, bits):
    frames, (mraw, cihx) = _video(tmp_path, bits=bits)
    store = tmp_path / "r.h5"
    res = _ingest(store, cihx, f"ingest_hsc.compression={compression!r}")
    assert res.status == "written" and res.summary["frames"] == len(frames)
    with h5py.File(store, "r") as f:                      # plain h5py, standard filters
        ds = f["hsc/frames"]
        assert ds.chunks == (1, *frames.shape[1:]) and ds.dtype == frames.dtype
        assert (ds.compression, ds.shuffle) == (("gzip", True) if compression != "none" else (None, False))
        assert ds[()].tobytes() == frames.tobytes()


def test_frame_range_and_roi_are_cut_from_the_video(tmp_path):
    frames, (_, cihx) = _video(tmp_path)
    store = tmp_path / "r.h5"
    _ingest(store, cihx, "ingest_hsc.first_frame=5", "ingest_hsc.n_frames=20", "ingest_hsc.roi_px=[3, 2, 17, 11]")
    with Store(store).read() as r:
        stored = r.read("hsc", "frames")
    assert np.array_equal(stored, frames[5:25, 2:13, 3:20])


def test_provenance_records_the_hashes_of_the_raw_files(tmp_path):
    """The hashes are computed while the frames are written (not before): same record."""
    _, (mraw, cihx) = _video(tmp_path)
    store = tmp_path / "r.h5"
    _ingest(store, cihx)
    with Store(store).read() as r:
        inputs = json.loads(r.status("/hsc").provenance["inputs_json"])
    assert {k: v["sha256"] for k, v in inputs.items()} == {
        str(p.resolve()): sha256_file(p) for p in (mraw, cihx)}
    assert _ingest(store, cihx).status == "up-to-date"
    with open(mraw, "r+b") as fh:                          # same size, new content
        fh.write(b"\x00\x01\x02")
    assert _ingest(store, cihx).status == "written"


def test_a_read_error_midway_leaves_the_store_untouched(tmp_path, monkeypatch):
    """The error raised in a decoding thread reaches the command; the transaction aborts."""
    from vfcli.io import photron

    _, (_, cihx) = _video(tmp_path)
    store = tmp_path / "r.h5"
    _ingest(store, cihx)
    before = store.read_bytes()
    decode = photron.Packed12Frames.__getitem__

    def failing(self, i):
        if i == 20:
            raise OSError("I/O error")
        return decode(self, i)

    monkeypatch.setattr(photron.Packed12Frames, "__getitem__", failing)
    with pytest.raises(OSError, match="I/O error"):
        run_ingest_hsc(RunContext.open(store, None, ["ingest_hsc.compression='gzip4'"], force=True), cihx)
    assert store.read_bytes() == before
    assert Store(store).interrupted_writes() == []
