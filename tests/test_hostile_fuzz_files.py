"""Mutation fuzzing of every raw-file reader from valid seed files (issue 20).

Each seed is a small valid file written once by the library that writes it in the wild (pyMRAW for
the legacy .cih/.mraw, tifffile, OpenCV for AVI, pyuff's dataset writers, scipy.io for .mat and WAV,
npTDMS) or by vfcli's own writer where no other exists (CIHX, the CSV layouts). Every case then
mutates the seed the way a damaged copy or a hand edit would:

* **numbers in the text** (headers of .cih/.cihx, UFF, the CSV layouts) replaced by hostile
  ones: NaN, inf, 1e300, 1e-300, negative, zero, 30-digit integers, text;
* **binary header fields** (AVI ``avih``/``strh``/``strf``, WAV ``fmt``) overwritten with hostile
  32-bit values;
* **truncation or extension** and **bit flips** anywhere.

Property (tests/_fuzz.py): a plausible result (vfcli/io/limits.py) or a one-line vfcli user error;
never another exception, never a hang (a per-case deadline). The case counts are listed in
docs/input-checks.md; the hypothesis profile ``vfcli-ci`` draws them reproducibly.
"""
from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests._fuzz import BACKSTOP, fresh, fuzz, mutate, user_error_or
from vfcli.io.ldv.read import LdvScan, read_ldv
from vfcli.io.ldv.write import write_ldv_csv, write_ldv_uff
from vfcli.io.limits import (FPS_RANGE, LDV_EXTENT_MM, LDV_FS_RANGE, LDV_MAX_ABS_VELOCITY_MM_S,
                             MAX_ABS_PRESSURE_PA, MAX_ABS_START_FRAME, PRESSURE_FS_RANGE)
from vfcli.io.pressure import read_pressure, write_pressure_csv
from vfcli.io.video.base import open_video
from vfcli.io.video.photron import write_mraw

pytestmark = BACKSTOP

#: Hostile numbers as text.
HOSTILE_TEXT = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "Infinity", "1e300", "-1e300", "1e-300", "-1", "0", "-0.0", "1e23",
                     "9" * 30, "-" + "9" * 30, "", " ", "abc", "0x10", "1,5", "4294967296", "2147483648", "65536",
                     "0.5", "1e6", "12", "8", "16", "7", "3"]),
    st.integers(-10**12, 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)
#: Hostile unsigned 32-bit values for binary header fields.
HOSTILE_U32 = st.one_of(st.sampled_from([0, 1, 2, 3, 7, 255, 65535, 65536, 2**31 - 1, 2**31, 2**32 - 1]),
                        st.integers(0, 2**32 - 1))
FLIPS = st.lists(st.tuples(st.integers(0, 10**7), st.integers(0, 7)), max_size=4)
_NUMBER = re.compile(rb"(?<![A-Za-z_])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def edit_numbers(data: bytes, edits: list[tuple[int, str]], head: int | None = None) -> bytes:
    """Replace numbers in ``data[:head]`` (all of it by default): edit ``(k, text)`` replaces the
    number ``k mod count`` by ``text``."""
    region = data if head is None else data[:head]
    spans = [m.span() for m in _NUMBER.finditer(region)]
    if not spans:
        return data
    chosen = {}
    for k, text in edits:
        chosen[spans[k % len(spans)]] = text.encode("utf-8", "replace")
    out, last = [], 0
    for (a, b) in sorted(chosen):
        out += [data[last:a], chosen[(a, b)]]
        last = b
    return b"".join(out) + data[last:]


def put_words(data: bytes, edits: list[tuple[int, int]], start: int = 0, end: int | None = None) -> bytes:
    """Overwrite aligned little-endian 32-bit words of ``data[start:end]``: edit ``(k, value)`` writes
    ``value`` into word ``k mod count``."""
    b = bytearray(data)
    n = max(1, ((len(b) if end is None else end) - start) // 4)
    for k, v in edits:
        off = start + 4 * (k % n)
        b[off:off + 4] = struct.pack("<I", v)
    return bytes(b)


NUMBER_EDITS = st.lists(st.tuples(st.integers(0, 10**6), HOSTILE_TEXT), min_size=1, max_size=3)


# --------------------------------------------------------------------------- what a result must satisfy

def _plausible_video(meta) -> None:
    assert meta.fps is None or FPS_RANGE[0] <= meta.fps <= FPS_RANGE[1], meta
    assert abs(meta.start_frame) <= MAX_ABS_START_FRAME and meta.n_frames >= 1, meta


def _read_video(path: Path):
    def read():
        with open_video(path) as v:
            for _ in v.iter_frames(batch=4):
                pass
            return v.meta
    return read


def _plausible_pressure(rec) -> None:
    assert rec.samples.size >= 1 and np.isfinite(rec.samples).all(), rec.source
    assert np.abs(rec.samples).max() <= MAX_ABS_PRESSURE_PA, rec.source
    assert PRESSURE_FS_RANGE[0] <= rec.fs <= PRESSURE_FS_RANGE[1] and np.isfinite(rec.t0), rec.source


def _plausible_scan(scan) -> None:
    assert LDV_FS_RANGE[0] <= scan.fs <= LDV_FS_RANGE[1]
    assert np.unique(scan.node_ids).size == scan.n_points      # whole, distinct node numbers
    assert np.isfinite(scan.coords_mm).all() and np.isfinite(scan.velocity_mm_s).all()
    if scan.n_points > 1:
        span = float(np.max(np.ptp(scan.coords_mm[:, :2], axis=0)))
        assert LDV_EXTENT_MM[0] <= span <= LDV_EXTENT_MM[1], span
    assert np.abs(scan.velocity_mm_s).max() <= LDV_MAX_ABS_VELOCITY_MM_S
    if scan.reference is not None:
        assert np.isfinite(scan.reference).all()


# --------------------------------------------------------------------------- seeds

def _frames(n=3, h=8, w=8, hi=4096, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, hi, (n, h, w)).astype(np.uint16)


def _scan(p=4, n_s=64) -> LdvScan:
    rng = np.random.default_rng(0)
    coords = np.column_stack([np.arange(p) * 0.7, np.arange(p) % 2 * 0.6, np.zeros(p)])
    t = np.arange(n_s) / 50_000.0
    ref = 800 + 300 * np.sin(2 * np.pi * 700 * t) + rng.normal(0, 1, (p, n_s))
    return LdvScan(np.arange(p) + 1, coords, rng.normal(0, 50, (p, n_s)), 50_000.0, ref, "Pa", np.zeros(p))


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    import cv2
    import pyMRAW
    import tifffile
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
    from scipy.io import savemat, wavfile

    d = tmp_path_factory.mktemp("seeds")
    out: dict[str, bytes] = {}
    mraw, cih = pyMRAW.save_mraw(_frames(hi=65535), str(d / "legacy.cih"), bit_depth=16,
                                 info_dict={"Record Rate(fps)": 10000, "Start Frame": -2})
    out["cih"], out["cih.mraw"] = Path(cih).read_bytes(), Path(mraw).read_bytes()
    mraw, cihx = write_mraw(d / "x", [_frames()], fps=10_000.0)
    out["cihx"], out["cihx.mraw"] = cihx.read_bytes(), mraw.read_bytes()
    tifffile.imwrite(d / "t.tif", _frames(hi=65535), imagej=True, metadata={"finterval": 1e-4})
    out["tif"] = (d / "t.tif").read_bytes()
    w = cv2.VideoWriter(str(d / "v.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 250.0, (16, 8), isColor=False)
    for f in _frames(n=4, w=16, hi=256).astype(np.uint8):
        w.write(f)
    w.release()
    out["avi"] = (d / "v.avi").read_bytes()
    scan = _scan()
    out["uff"] = write_ldv_uff(d / "b.uff", scan).read_bytes()
    out["uff_ascii"] = write_ldv_uff(d / "a.uff", scan, binary=False).read_bytes()
    out["ldv_csv"] = write_ldv_csv(d / "l.csv", scan).read_bytes()
    savemat(d / "l.mat", {"node_ids": scan.node_ids, "coords": scan.coords_mm, "velocity": scan.velocity_mm_s,
                          "reference": scan.reference, "fs": scan.fs, "length_unit": "mm",
                          "reference_unit": "Pa"}, do_compression=False)
    out["mat"] = (d / "l.mat").read_bytes()
    savemat(d / "z.mat", {"node_ids": scan.node_ids, "coords": scan.coords_mm, "velocity": scan.velocity_mm_s,
                          "fs": scan.fs}, do_compression=True)
    out["mat_z"] = (d / "z.mat").read_bytes()
    x = 800 + 300 * np.sin(np.arange(200) / 7.0)
    with TdmsWriter(d / "p.tdms") as tw:
        tw.write_segment([RootObject(), GroupObject("daq"), ChannelObject(
            "daq", "p_sub", x, properties={"wf_increment": 2e-5, "wf_start_offset": 0.0, "unit_string": "Pa"})])
    out["tdms"] = (d / "p.tdms").read_bytes()
    wavfile.write(d / "p.wav", 50_000, (np.sin(np.arange(400) / 5) * 1e4).astype(np.int16).reshape(200, 2))
    out["wav"] = (d / "p.wav").read_bytes()
    out["p_csv"] = write_pressure_csv(d / "p.csv", x[:40], 50_000.0).read_bytes()
    return out


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cases")


def _text_case(seed: bytes, path: Path, edits, cut: int, flips, read, check) -> None:
    """``seed`` with numbers edited, cut and flipped, written to ``path`` and read with ``read(path)``."""
    fresh(path).write_bytes(mutate(edit_numbers(seed, edits), cut, flips))
    user_error_or(lambda: read(path), check)


# --------------------------------------------------------------------------- video

def _photron_case(seeds, work: Path, meta: str, edits, cut: int, flips, mraw_cut: int, open_as: str) -> None:
    """The ``meta`` (cih/cihx) seed with numbers edited, cut and flipped, beside its MRAW cut by ``mraw_cut``;
    opened through the ``open_as`` file of the pair."""
    fresh(work / f"p.{meta}").write_bytes(mutate(edit_numbers(seeds[meta], edits), cut, flips))
    fresh(work / "p.mraw").write_bytes(mutate(seeds[f"{meta}.mraw"], mraw_cut, []))
    user_error_or(_read_video(work / f"p.{open_as}"), _plausible_video)
    (work / f"p.{meta}").unlink()


@fuzz(1250)
@given(edits=NUMBER_EDITS, cut=st.integers(-20, 60), flips=FLIPS, mraw_cut=st.integers(-64, 64))
def test_legacy_cih_numbers_sizes_and_bits(seeds, work, edits, cut, flips, mraw_cut):
    _photron_case(seeds, work, "cih", edits, cut, flips, mraw_cut, open_as="cih")


@fuzz(750)
@given(edits=NUMBER_EDITS, cut=st.integers(-20, 200), flips=FLIPS, mraw_cut=st.integers(-64, 64))
def test_cihx_numbers_sizes_and_bits(seeds, work, edits, cut, flips, mraw_cut):
    _photron_case(seeds, work, "cihx", edits, cut, flips, mraw_cut, open_as="mraw")


@fuzz(1000)
@given(cut=st.integers(-300, 300), flips=FLIPS, which=st.sampled_from(["cih", "cihx"]))
def test_mraw_truncated_extended_or_flipped(seeds, work, cut, flips, which):
    fresh(work / f"m.{which}").write_bytes(seeds[which])
    fresh(work / "m.mraw").write_bytes(mutate(seeds[f"{which}.mraw"], cut, flips))
    user_error_or(_read_video(work / "m.mraw"), _plausible_video)
    (work / f"m.{which}").unlink()


@fuzz(750)
@given(cut=st.integers(-40, 400), flips=FLIPS, edits=st.lists(st.tuples(st.integers(0, 10**6), HOSTILE_U32),
                                                                  max_size=3))
def test_tiff_ifd_values_sizes_and_bits(seeds, work, cut, flips, edits):
    b = bytearray(seeds["tif"])
    # overwrite the value fields of IFD entries (12-byte entries after the 2-byte count)
    ifd = struct.unpack("<I", b[4:8])[0]
    n = struct.unpack("<H", b[ifd:ifd + 2])[0] if ifd + 2 <= len(b) else 0
    for k, v in edits:
        if n:
            off = ifd + 2 + 12 * (k % n) + 8
            b[off:off + 4] = struct.pack("<I", v)
    fresh(work / "t.tif").write_bytes(mutate(bytes(b), cut, flips))
    user_error_or(_read_video(work / "t.tif"), _plausible_video)


#: (chunk tag, byte offset of a 32-bit field after the chunk's size): avih dwMicroSecPerFrame,
#: dwTotalFrames, dwStreams, dwWidth, dwHeight; strh dwScale, dwRate, dwLength; strf biWidth,
#: biHeight, biBitCount/planes, biCompression.
_AVI_FIELDS = [(b"avih", 0), (b"avih", 16), (b"avih", 24), (b"avih", 32), (b"avih", 36),
               (b"strh", 20), (b"strh", 24), (b"strh", 32), (b"strf", 4), (b"strf", 8), (b"strf", 12),
               (b"strf", 16)]


@fuzz(1000)
@given(edits=st.lists(st.tuples(st.sampled_from(_AVI_FIELDS), HOSTILE_U32), max_size=3),
       cut=st.integers(-40, 600), flips=FLIPS)
def test_avi_header_fields_sizes_and_bits(seeds, work, edits, cut, flips):
    b = bytearray(seeds["avi"])
    for (tag, off), v in edits:
        i = b.find(tag)
        if i >= 0 and i + 8 + off + 4 <= len(b):
            b[i + 8 + off:i + 12 + off] = struct.pack("<I", v)
    fresh(work / "v.avi").write_bytes(mutate(bytes(b), cut, flips))
    user_error_or(_read_video(work / "v.avi"), _plausible_video)


# --------------------------------------------------------------------------- vibrometer

@fuzz(1000)
@given(which=st.sampled_from(["uff", "uff_ascii"]), edits=NUMBER_EDITS, cut=st.integers(0, 300), flips=FLIPS)
def test_uff_numbers_sizes_and_bits(seeds, work, which, edits, cut, flips):
    data = seeds[which]
    # binary 58 records: edit only their text headers (the first 2 kB hold 151, 164, 2411 and the first header)
    head = 2048 if which == "uff" else None
    fresh(work / "s.uff").write_bytes(mutate(edit_numbers(data, edits, head), cut, flips))
    user_error_or(lambda: read_ldv(work / "s.uff", expected_grid=None), _plausible_scan)


@fuzz(750)
@given(which=st.sampled_from(["mat", "mat_z"]), cut=st.integers(0, 400), flips=FLIPS,
       edits=st.lists(st.tuples(st.integers(0, 10**6), HOSTILE_U32), max_size=2))
def test_mat_tags_sizes_and_bits(seeds, work, which, cut, flips, edits):
    data = put_words(seeds[which], edits, 128)   # after the 128-byte header: element tags and sizes
    fresh(work / "s.mat").write_bytes(mutate(data, cut, flips))
    user_error_or(lambda: read_ldv(work / "s.mat", expected_grid=None), _plausible_scan)


@fuzz(750)
@given(edits=NUMBER_EDITS, cut=st.integers(0, 200), flips=FLIPS)
def test_ldv_csv_numbers_sizes_and_bits(seeds, work, edits, cut, flips):
    _text_case(seeds["ldv_csv"], work / "s.csv", edits, cut, flips,
               lambda p: read_ldv(p, expected_grid=None), _plausible_scan)


# --------------------------------------------------------------------------- pressure

@fuzz(750)
@given(cut=st.integers(0, 600), flips=FLIPS, edits=st.lists(st.tuples(st.integers(0, 10**6), HOSTILE_U32),
                                                                 max_size=3))
def test_tdms_words_sizes_and_bits(seeds, work, cut, flips, edits):
    # lead-in and metadata (before the 1,600 data bytes): table of contents, lengths, property types and values
    data = put_words(seeds["tdms"], edits, 0, len(seeds["tdms"]) - 1600)
    fresh(work / "p.tdms").write_bytes(mutate(data, cut, flips))
    user_error_or(lambda: read_pressure(work / "p.tdms"), _plausible_pressure)


@fuzz(750)
@given(cut=st.integers(-16, 800), flips=FLIPS,
       edits=st.lists(st.tuples(st.sampled_from([4, 16, 20, 24, 28, 32, 34, 40]), HOSTILE_U32), max_size=3),
       channel=st.one_of(st.none(), st.integers(-2, 3)))
def test_wav_header_words_sizes_and_bits(seeds, work, cut, flips, edits, channel):
    b = bytearray(seeds["wav"])
    for off, v in edits:   # RIFF size, fmt size, format/channels, rate, byte rate, align/bits, data size
        b[off:off + 4] = struct.pack("<I", v)
    fresh(work / "p.wav").write_bytes(mutate(bytes(b), cut, flips))
    user_error_or(lambda: read_pressure(work / "p.wav", channel=channel), _plausible_pressure)


@fuzz(750)
@given(edits=NUMBER_EDITS, cut=st.integers(0, 300), flips=FLIPS)
def test_pressure_csv_numbers_sizes_and_bits(seeds, work, edits, cut, flips):
    _text_case(seeds["p_csv"], work / "p.csv", edits, cut, flips, read_pressure, _plausible_pressure)
