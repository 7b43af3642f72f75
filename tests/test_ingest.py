"""`vfcli ingest-hsc` (the library call): the stored frames are the video's, bit for bit,
in a standard one-frame-per-chunk dataset, whatever the compression, frame range or ROI;
"auto" stores a 12-bit packed MRAW with HDF5's N-bit filter (its frames' bytes as they
are) and anything else with gzip; the raw files' hashes are recorded as before."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

from vfcli.errors import ConfigError, InputDataError
from vfcli.io.video.photron import write_mraw
from vfcli.store.provenance import sha256_file
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


#: HDF5 filter pipeline of each stored filter.
FILTERS = {"gzip": [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE],
           "gzip4": [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE],
           "nbit": [h5py.h5z.FILTER_NBIT], "none": []}


def _filters(ds: h5py.Dataset) -> list[int]:
    dcpl = ds.id.get_create_plist()
    return [dcpl.get_filter(i)[0] for i in range(dcpl.get_nfilters())]


@pytest.mark.parametrize("compression", ["auto", "nbit", "gzip", "gzip4", "none"])
@pytest.mark.parametrize("bits", [12, 16, 8])
def test_ingested_frames_are_the_videos_bit_for_bit_in_one_chunk_per_frame(tmp_path, compression, bits):
    frames, (mraw, cihx) = _video(tmp_path, bits=bits)
    store = tmp_path / "r.h5"
    if compression == "nbit" and bits == 8:
        with pytest.raises(ConfigError, match="'nbit' stores 12-bit pixels in uint16 only"):
            _ingest(store, cihx, "ingest_hsc.compression='nbit'")
        return
    res = _ingest(store, cihx, f"ingest_hsc.compression={compression!r}")
    stored_as = ("nbit" if bits == 12 else "gzip") if compression == "auto" else compression
    assert res.status == "written" and res.summary["frames"] == len(frames)
    assert res.summary["compression"] == stored_as
    with h5py.File(store, "r") as f:                      # plain h5py, standard filters
        ds = f["hsc/frames"]
        assert ds.chunks == (1, *frames.shape[1:]) and ds.dtype == frames.dtype
        assert _filters(ds) == FILTERS[stored_as] and ds.attrs["compression"] == stored_as
        assert ds.id.get_type().get_precision() == (12 if stored_as == "nbit" else 8 * frames.itemsize)
        assert ds[()].tobytes() == frames.tobytes()
    with Store(store).read() as r:                        # vfcli's own reader: the same frames
        assert r.frames("hsc", "frames")[::-1].tobytes() == frames[::-1].tobytes()


def test_a_12bit_mraw_is_stored_as_its_own_bytes_and_read_without_vfcli(tmp_path):
    """Each N-bit chunk is the MRAW frame's bytes plus one zero byte; libhdf5's built-in
    N-bit filter (no vfcli, no plugin) decodes them to the video's frames."""
    frames, (mraw, cihx) = _video(tmp_path, n=12, h=16, w=20)
    store = tmp_path / "r.h5"
    _ingest(store, cihx)
    raw = mraw.read_bytes()
    frame_bytes = 16 * 20 * 3 // 2
    with h5py.File(store, "r") as f:
        ds = f["hsc/frames"]
        for i in range(len(frames)):
            assert ds.id.read_direct_chunk((i, 0, 0)) == (0, raw[i * frame_bytes:(i + 1) * frame_bytes] + b"\0")
    out = tmp_path / "read.npy"
    code = ("import sys, h5py, numpy as np\n"
            "np.save(sys.argv[2], h5py.File(sys.argv[1], 'r')['hsc/frames'][()])\n"
            "assert 'vfcli' not in sys.modules\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["HDF5_PLUGIN_PATH"] = str(tmp_path / "no-plugins")
    subprocess.run([sys.executable, "-c", code, str(store), str(out)], check=True, env=env, cwd=tmp_path)
    read = np.load(out)
    assert read.dtype == np.uint16 and read.tobytes() == frames.tobytes()


def test_a_16bit_value_above_4095_with_nbit_is_an_input_error_and_the_store_is_unchanged(tmp_path):
    frames, (mraw, cihx) = _video(tmp_path, bits=16)
    h, w = frames.shape[1:]
    with open(mraw, "r+b") as fh:                          # frame 21, pixel (3, 4): 5000 in 16 bits
        fh.seek(2 * (21 * h * w + 3 * w + 4))
        fh.write((5000).to_bytes(2, "little"))
    store = tmp_path / "r.h5"
    _ingest(store, cihx, "ingest_hsc.compression='gzip'")
    before = store.read_bytes()
    with pytest.raises(InputDataError, match=r"v\.mraw: frame 21 holds the value 5000, more than the 12 bits"):
        run_ingest_hsc(RunContext.open(store, None, ["ingest_hsc.compression='nbit'"], force=True), cihx)
    assert store.read_bytes() == before
    assert Store(store).interrupted_writes() == []


@pytest.mark.parametrize("compression", ["auto", "gzip"])
def test_frame_range_and_roi_are_cut_from_the_video(tmp_path, compression):
    """An ROI of 17 x 11 px (an odd pixel count) of the 12-bit MRAW: decoded, cut and packed."""
    frames, (_, cihx) = _video(tmp_path)
    store = tmp_path / "r.h5"
    _ingest(store, cihx, "ingest_hsc.first_frame=5", "ingest_hsc.n_frames=20", "ingest_hsc.roi_px=[3, 2, 17, 11]",
            f"ingest_hsc.compression={compression!r}")
    with Store(store).read() as r:
        stored = r.read("hsc", "frames")
    with h5py.File(store, "r") as f:
        assert f["hsc/frames"].attrs["compression"] == ("nbit" if compression == "auto" else "gzip")
        assert f["hsc/frames"][()].tobytes() == stored.tobytes()
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
    from vfcli.io.video import photron

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


def test_an_avi_with_two_stated_rates_needs_camera_fps_hz(tmp_path):
    """An AVI written by FFmpeg at 10 kHz (avih: 100 us per frame, strh: 600 frames/s) is refused naming both
    rates and camera.fps_hz; with camera.fps_hz set, that rate is used."""
    import subprocess

    ffmpeg = pytest.importorskip("imageio_ffmpeg").get_ffmpeg_exe()
    frames = (_video(tmp_path, n=5)[0] >> 4).astype(np.uint8)
    avi = tmp_path / "v.avi"
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "gray", "-s", "30x24",
                    "-r", "10000", "-i", "-", "-c:v", "ffv1", str(avi)], input=frames.tobytes(), check=True)
    store = tmp_path / "r.h5"
    with pytest.raises(ConfigError, match=r"v\.avi: the AVI's main header \(avih\) states 100 us per frame \(10000 "
                                          r"frames/s\), its video stream header \(strh\) 600 frames/s; set "
                                          r"camera.fps_hz in the config"):
        _ingest(store, avi)
    res = _ingest(store, avi, "camera.fps_hz=10000")
    assert res.summary["fps_hz"] == 10000 and res.summary["frames"] == 5
