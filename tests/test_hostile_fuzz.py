"""Structure-aware fuzzing of every raw-file reader and of the config loader (issue 20).

The byte-level fuzzers in test_io_*.py flip bits of valid files; these write files whose
structure is valid and whose *values* are hostile (NaN, inf, 1e300, negative, huge integers,
text where a number belongs, sizes that lie), the way an attacker or a clumsy export does.
Every reader must then either return plausible values (vfcli/io/limits.py) or raise one of
vfcli's user errors (ConfigError or InputDataError); anything else is a bug.

Profiles, the per-case deadline and the one-line check: tests/_fuzz.py. Mutation fuzzers of
valid seed files: tests/test_hostile_fuzz_files.py. Case counts: docs/input-checks.md.
"""
from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests._fuzz import BACKSTOP, fresh, fuzz, user_error_or
from vfcli.config import RecordingConfig, load_config
from vfcli.io.ldv.read import LdvScan, read_ldv
from vfcli.io.ldv.write import write_ldv_csv, write_ldv_uff
from vfcli.io.limits import (FPS_RANGE, LDV_EXTENT_MM, LDV_FS_RANGE, LDV_MAX_ABS_VELOCITY_MM_S,
                             MAX_ABS_PRESSURE_PA, PRESSURE_FS_RANGE)
from vfcli.io.pressure import read_pressure
from vfcli.io.video.base import open_video
from vfcli.io.video.photron import write_mraw


pytestmark = BACKSTOP

#: Numbers as the text of a file would hold them, hostile ones first.
_NUM_TEXT = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "Infinity", "1e300", "1e-300", "-1", "0", "-0.0", "1e23",
                     "9" * 30, "", " ", "abc", "0x10", "1,5", "10000", "10000.0", "12", "8", "16", "-5"]),
    st.integers(-10**25, 10**25).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=8),
)

#: Numbers as a library would store them (floats, ints, NaN, inf).
_NUM = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20),
                 st.sampled_from([0.0, -1.0, 1e300, 1e-300, 1e6, 5e4, 1e3]))


# --------------------------------------------------------------------------- config loader

_FIELDS = {name: list(section.annotation.model_fields) for name, section in RecordingConfig.model_fields.items()
           if hasattr(section.annotation, "model_fields")}
_LEAF = st.one_of(_NUM, st.booleans(), st.text(max_size=6), st.none(),
                  st.lists(_NUM, max_size=4), st.lists(st.lists(_NUM, max_size=3), max_size=3))


@st.composite
def _config_doc(draw) -> dict:
    doc: dict = {}
    for sec in draw(st.lists(st.sampled_from(sorted(_FIELDS) + ["bogus"]), max_size=4, unique=True)):
        names = _FIELDS.get(sec, ["x"])
        keys = draw(st.lists(st.sampled_from(names + ["typo_key"]), max_size=4, unique=True))
        doc[sec] = {k: draw(_LEAF) for k in keys}
    if draw(st.booleans()):
        doc["name"] = draw(st.one_of(st.text(max_size=10), _NUM))
    return doc


def _toml(doc: dict) -> str:
    """TOML text for ``doc`` (tomli_w cannot write None; hostile values stay in)."""
    def val(v):
        if v is None:
            return '"null"'
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
        if isinstance(v, (int,)):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        return "[" + ", ".join(val(x) for x in v) + "]"
    lines = [f"name = {val(doc['name'])}"] if "name" in doc else []
    for sec, body in doc.items():
        if sec == "name":
            continue
        lines.append(f"[{sec}]")
        lines += [f"{k} = {val(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"


def _finite_everywhere(cfg: RecordingConfig) -> None:
    def walk(x):
        if isinstance(x, float):
            assert math.isfinite(x), cfg
        elif isinstance(x, (list, tuple)):
            for y in x:
                walk(y)
        elif isinstance(x, dict):
            for y in x.values():
                walk(y)
    walk(cfg.model_dump())


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@fuzz(750)
@given(doc=_config_doc())
def test_config_files_with_hostile_values_load_or_give_a_config_error(workdir, doc):
    path = fresh(workdir / "c.toml")
    path.write_text(_toml(doc))
    user_error_or(lambda: load_config(path), lambda out: [_finite_everywhere(c) for c in out])


@fuzz(500)
@given(key=st.one_of(st.sampled_from([f"{s}.{f}" for s, fs in _FIELDS.items() for f in fs]), st.text(max_size=12)),
       value=st.one_of(_NUM_TEXT, st.text(max_size=30), st.just("[" * 3000), st.just("9" * 5000)))
def test_set_overrides_with_hostile_values_load_or_give_a_config_error(key, value):
    user_error_or(lambda: load_config(overrides=[f"{key}={value}"]),
                   lambda out: [_finite_everywhere(c) for c in out])


@fuzz(300)
@given(text=st.text(alphabet=st.sampled_from(list("[]{}=.\"' \nabc01-+e_,#")), max_size=200))
def test_random_toml_text_loads_or_gives_a_config_error(workdir, text):
    path = fresh(workdir / "r.toml")
    path.write_text(text)
    user_error_or(lambda: load_config(path), lambda out: None)


# --------------------------------------------------------------------------- video

_CIHX_FIELDS = ["recordRate", "startFrame", "totalFrame", "width", "height", "bit", "type", "depth", "fileFormat"]


@pytest.fixture(scope="module")
def cihx_text(workdir) -> tuple[bytes, bytes]:
    frames = np.random.default_rng(0).integers(0, 4096, (3, 8, 8)).astype(np.uint16)
    mraw, cihx = write_mraw(workdir / "seed", [frames], fps=10_000.0)
    return mraw.read_bytes(), cihx.read_bytes()


def _video_ok(path):
    def read():
        with open_video(path) as v:
            meta = v.meta
            for _ in v.iter_frames(batch=2):
                pass
            return meta
    return read


def _plausible_meta(meta) -> None:
    assert meta.fps is None or FPS_RANGE[0] <= meta.fps <= FPS_RANGE[1]
    assert abs(meta.start_frame) <= 10**9 and meta.n_frames >= 1


@fuzz(500)
@given(edits=st.lists(st.tuples(st.sampled_from(_CIHX_FIELDS), _NUM_TEXT), min_size=1, max_size=3))
def test_cihx_with_hostile_field_values(workdir, cihx_text, edits):
    import re

    mraw_bytes, text = cihx_text
    for field, value in edits:
        new = b"<%s>%s</%s>" % (field.encode(), value.encode("utf-8", "replace").replace(b"<", b"")
                                .replace(b"&", b""), field.encode())
        text = re.sub(rb"<%s>[^<]*</%s>" % (field.encode(), field.encode()), lambda _m, new=new: new, text, count=1)
    d = workdir / "cx"
    d.mkdir(exist_ok=True)
    fresh(d / "v.mraw").write_bytes(mraw_bytes)
    fresh(d / "v.cihx").write_bytes(text)
    user_error_or(_video_ok(d / "v.cihx"), _plausible_meta)


@fuzz(500)
@given(how=st.sampled_from(["json", "imagej", "text"]), value=_NUM,
       text=st.text(alphabet=st.characters(min_codepoint=1, max_codepoint=127), max_size=20),
       n=st.integers(1, 3), dtype=st.sampled_from([np.uint8, np.uint16, np.float32, np.int16]))
def test_tiff_with_hostile_frame_rate_metadata(workdir, how, value, text, n, dtype):
    import tifffile

    path = fresh(workdir / "t.tif")
    frames = np.ones((n, 6, 7), dtype)
    if how == "json":
        tifffile.imwrite(path, frames, description=json.dumps({"fps": value}))
    elif how == "imagej" and dtype in (np.uint8, np.uint16, np.float32):
        fin = float(value) if abs(float(value)) < 1e308 else float("inf")
        tifffile.imwrite(path, frames, imagej=True, metadata={"finterval": fin})
    else:
        tifffile.imwrite(path, frames, description=text)
    user_error_or(_video_ok(path), _plausible_meta)


# --------------------------------------------------------------------------- pressure

@fuzz(500)
@given(fs=_NUM_TEXT, header=st.sampled_from(["p_sub [Pa]", "time [s],p_sub [Pa]", "p [kPa]", "x,y", ""]),
       values=st.lists(st.one_of(_NUM, _NUM_TEXT), min_size=0, max_size=12))
def test_pressure_csv_with_hostile_values(workdir, fs, header, values):
    path = fresh(workdir / "p.csv")
    rows = []
    for i, v in enumerate(values):
        rows.append(f"{i / 5e4!r},{v}" if header.startswith("time") or header == "x,y" else f"{v}")
    path.write_text(f"# fs = {fs}\n{header}\n" + "\n".join(rows) + "\n")

    def check(rec):
        assert np.isfinite(rec.samples).all() and np.abs(rec.samples).max() <= MAX_ABS_PRESSURE_PA
        assert PRESSURE_FS_RANGE[0] <= rec.fs <= PRESSURE_FS_RANGE[1]
    user_error_or(lambda: read_pressure(path), check)


@pytest.fixture(scope="module")
def wav_bytes(workdir) -> bytes:
    from scipy.io import wavfile

    path = workdir / "seed.wav"
    wavfile.write(path, 50_000, (np.sin(np.arange(200) / 5) * 1e4).astype(np.int16).reshape(100, 2))
    return path.read_bytes()


@fuzz(500)
@given(riff_size=st.integers(0, 2**32 - 1), data_size=st.integers(0, 2**32 - 1),
       rate=st.integers(0, 2**32 - 1), channels=st.integers(0, 70000), bits=st.sampled_from([0, 8, 16, 24, 32, 64, 7]),
       channel=st.one_of(st.none(), st.integers(-3, 3), st.text(max_size=3)), keep=st.integers(0, 500))
def test_wav_with_hostile_header_fields(workdir, wav_bytes, riff_size, data_size, rate, channels, bits, channel,
                                       keep):
    b = bytearray(wav_bytes)
    b[4:8] = struct.pack("<I", riff_size)
    b[22:24] = struct.pack("<H", channels % 65536)
    b[24:28] = struct.pack("<I", rate)
    b[34:36] = struct.pack("<H", bits)
    i = b.index(b"data")
    b[i + 4:i + 8] = struct.pack("<I", data_size)
    path = fresh(workdir / "w.wav")
    path.write_bytes(bytes(b[: 44 + keep]))

    def check(rec):
        assert np.isfinite(rec.samples).all() and PRESSURE_FS_RANGE[0] <= rec.fs <= PRESSURE_FS_RANGE[1]
    user_error_or(lambda: read_pressure(path, channel=channel), check)


@fuzz(500)
@given(inc=_NUM, offset=_NUM, n=st.integers(0, 50), scale=_NUM, cut=st.integers(0, 400),
       unit=st.sampled_from(["Pa", "kPa", "V", "", "furlong"]))
def test_tdms_with_hostile_properties_and_truncation(workdir, inc, offset, n, scale, cut, unit):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    path = fresh(workdir / "p.tdms")
    with np.errstate(all="ignore"):
        data = np.sin(np.arange(n) / 3.0) * float(scale)
    props = {"wf_increment": float(inc), "wf_start_offset": float(offset), "unit_string": unit}
    with TdmsWriter(path) as w:
        w.write_segment([RootObject(), GroupObject("g"), ChannelObject("g", "p_sub", data, properties=props)])
    raw = path.read_bytes()
    fresh(path).write_bytes(raw[: max(1, len(raw) - cut)])

    def check(rec):
        assert np.isfinite(rec.samples).all() and np.abs(rec.samples).max() <= MAX_ABS_PRESSURE_PA
        assert PRESSURE_FS_RANGE[0] <= rec.fs <= PRESSURE_FS_RANGE[1]
    user_error_or(lambda: read_pressure(path), check)


# --------------------------------------------------------------------------- vibrometer

def _scan(p=4, n_s=16, coord_scale=1.0, vel_scale=1.0, fs=50_000.0) -> LdvScan:
    rng = np.random.default_rng(0)
    coords = np.column_stack([np.arange(p) * 0.7, np.arange(p) % 2 * 0.6, np.zeros(p)]) * coord_scale
    vel = rng.normal(0, 50, (p, n_s)) * vel_scale
    return LdvScan(np.arange(p) + 1, coords, vel, fs, rng.normal(800, 100, (p, n_s)), "Pa", np.zeros(p))


def _plausible_scan(scan) -> None:
    assert LDV_FS_RANGE[0] <= scan.fs <= LDV_FS_RANGE[1]
    assert np.unique(scan.node_ids).size == scan.n_points      # whole, distinct node numbers
    assert np.isfinite(scan.coords_mm).all() and np.isfinite(scan.velocity_mm_s).all()
    span = float(np.max(np.ptp(scan.coords_mm[:, :2], axis=0))) if scan.n_points > 1 else 1.0
    assert LDV_EXTENT_MM[0] <= span <= LDV_EXTENT_MM[1]
    assert np.abs(scan.velocity_mm_s).max() <= LDV_MAX_ABS_VELOCITY_MM_S


@pytest.fixture(scope="module")
def csv_lines(workdir) -> list[str]:
    return write_ldv_csv(workdir / "seed.csv", _scan()).read_text().splitlines()


@fuzz(500)
@given(fs=_NUM_TEXT, length=st.sampled_from(["mm", "m", "um", "km", ""]), cells=st.lists(
    st.tuples(st.integers(0, 4), st.integers(0, 30), st.one_of(_NUM_TEXT, _NUM.map(str))), max_size=5))
def test_ldv_csv_with_hostile_values(workdir, csv_lines, fs, length, cells):
    lines = list(csv_lines)
    lines = [f"# fs = {fs}" if ln.startswith("# fs") else (f"# length_unit = {length}"
                                                            if ln.startswith("# length_unit") else ln)
             for ln in lines]
    body0 = next(i for i, ln in enumerate(lines) if ln.startswith("node")) + 1
    for row, col, value in cells:
        i = body0 + row % (len(lines) - body0)
        parts = lines[i].split(",")
        parts[col % len(parts)] = value.replace(",", "").replace("\n", "")
        lines[i] = ",".join(parts)
    path = fresh(workdir / "l.csv")
    path.write_text("\n".join(lines) + "\n")
    user_error_or(lambda: read_ldv(path, expected_grid=None), _plausible_scan)


@fuzz(500)
@given(coords=st.one_of(_NUM, st.text(max_size=3)), vel=st.one_of(_NUM, st.text(max_size=3)),
       fs=st.one_of(_NUM, st.text(max_size=3), st.lists(_NUM, max_size=2)),
       node_ids=st.one_of(st.none(), st.text(max_size=4), st.lists(_NUM, min_size=0, max_size=5)),
       unit=st.sampled_from(["mm", "m", "parsec", "", "mm/s"]))
def test_ldv_mat_with_hostile_variables(workdir, coords, vel, fs, node_ids, unit):
    from scipy.io import savemat

    base = _scan()
    m = {"coords": base.coords_mm * (coords if isinstance(coords, (int, float)) else 1.0)
         if isinstance(coords, (int, float)) and abs(coords) < 1e300 else coords,
         "velocity": base.velocity_mm_s * vel if isinstance(vel, (int, float)) and abs(vel) < 1e300 else vel,
         "fs": fs if not isinstance(fs, list) or fs else 0.0, "length_unit": unit}
    if node_ids is not None:
        m["node_ids"] = node_ids if not isinstance(node_ids, list) or node_ids else "x"
    path = fresh(workdir / "l.mat")
    try:
        savemat(path, m)
    except (ValueError, TypeError, OverflowError):
        return   # scipy cannot write it: no such file exists in the wild
    user_error_or(lambda: read_ldv(path, expected_grid=None), _plausible_scan)


@fuzz(400)
@given(coord_scale=st.sampled_from([1.0, 1e-3, 1e3, 1e6, 0.0, -1.0]), vel_scale=st.sampled_from([1.0, 1e6, 1e-9]),
       fs=st.sampled_from([50_000.0, 1000.0, 1e9, 25_600.0]),
       length=st.sampled_from(["m", "mm", "um"]), units=st.booleans(), cut=st.integers(0, 50))
def test_ldv_uff_with_hostile_scales(workdir, coord_scale, vel_scale, fs, length, units, cut):
    path = write_ldv_uff(workdir / "l.uff", _scan(coord_scale=coord_scale, vel_scale=vel_scale, fs=fs),
                         length_unit=length)
    raw = path.read_bytes()
    if not units:   # drop dataset 164
        i = raw.index(b"   164")
        raw = raw[: raw.rindex(b"    -1", 0, i)] + raw[raw.index(b"    -1", i) + 7:]
    fresh(path).write_bytes(raw[: len(raw) - cut])
    user_error_or(lambda: read_ldv(path, expected_grid=None), _plausible_scan)
    user_error_or(lambda: read_ldv(path, expected_grid=None, length_unit=length), _plausible_scan)


@fuzz(1000)
@given(shapes=st.lists(st.tuples(st.integers(1, 6), st.integers(1, 6), st.sampled_from([1, 3])), min_size=1,
                       max_size=4),
       dtypes=st.lists(st.sampled_from([np.uint8, np.uint16, np.float32, np.int32]), min_size=1, max_size=4),
       names=st.lists(st.sampled_from(["a1.tif", "a2.tif", "a10.tif", "b.tif", "x.png.tif"]), min_size=1,
                      max_size=4, unique=True))
def test_image_folder_with_mixed_frames(workdir, shapes, dtypes, names):
    import shutil

    import tifffile

    d = workdir / "folder"
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir()
    for i, name in enumerate(names):
        h, w, c = shapes[i % len(shapes)]
        img = np.ones((h, w) if c == 1 else (h, w, c), dtypes[i % len(dtypes)])
        tifffile.imwrite(d / name, img)
    user_error_or(_video_ok(d), _plausible_meta)
