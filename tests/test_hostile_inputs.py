"""Hostile inputs (issue 20): impossible values, broken files and environments give one line,
the documented exit code and an unchanged store.

Each test is a case that failed before (exit 0 with an impossible value stored, or a traceback).
Files are written by the libraries that write them in the wild (tifffile, pyuff, npTDMS,
scipy.io.wavfile/savemat) and edited the way the attacker did; the commands run as real
subprocesses. See docs/input-checks.md for the table of checks.
"""
from __future__ import annotations

import os
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, VFCLI, run_vfcli
from vfcli.errors import InputDataError
from vfcli.io._matcheck import check_mat5, inflate_budget
from vfcli.io.ldv.read import LdvScan, read_ldv
from vfcli.io.pressure import read_pressure
from vfcli.io.video.base import open_video
from vfcli.io.video.photron import write_mraw

FS_P = 50_000.0
N_FRAMES, FPS = 12, 10_000.0


# --------------------------------------------------------------------------- small real files

def _frames(n=N_FRAMES, h=24, w=32, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(100, 3000, (n, h, w)).astype(np.uint16)


def _pressure_samples(n=1000) -> np.ndarray:
    t = np.arange(n) / FS_P
    return 800 + 300 * np.sin(2 * np.pi * 120 * t)


def _tdms(path: Path, samples: np.ndarray, extra_channel: np.ndarray | None = None) -> Path:
    """A LabVIEW-style waveform channel written by npTDMS."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    props = {"wf_increment": 1 / FS_P, "wf_start_offset": 0.0, "unit_string": "Pa"}
    chans = [ChannelObject("daq", "p_sub", samples, properties=props)]
    if extra_channel is not None:
        chans.append(ChannelObject("daq", "trigger", extra_channel, properties=props))
    with TdmsWriter(path) as w:
        w.write_segment([RootObject(), GroupObject("daq"), *chans])
    return path


def _store_with_hsc(tmp_path: Path) -> tuple[Path, Path, bytes]:
    """A store holding /hsc from a small TIFF (tifffile) and a TDMS pressure: (store, tiff, bytes)."""
    import tifffile

    video = tmp_path / "good.tif"
    tifffile.imwrite(video, _frames(), description='{"fps": 10000.0}')
    pressure = _tdms(tmp_path / "good.tdms", _pressure_samples())
    store = tmp_path / "rec.h5"
    r = run_vfcli("ingest-hsc", "-q", store, video, "--pressure", pressure)
    assert r.returncode == 0, r.stderr
    return store, video, store.read_bytes()


def _assert_refused(r: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == code, r.stderr
    assert "Traceback" not in r.stderr
    last = lines[-1] if lines else ""
    for n in needles:
        assert n in last, last


@pytest.fixture
def hsc_store(tmp_path):
    return _store_with_hsc(tmp_path)


# --------------------------------------------------------------------------- video: impossible metadata

def test_tiff_with_negative_imagej_finterval_is_refused(tmp_path, hsc_store):
    import tifffile

    store, _, before = hsc_store
    bad = tmp_path / "neg.tif"
    tifffile.imwrite(bad, _frames().astype(np.uint16), imagej=True, metadata={"finterval": -0.001})
    assert tifffile.TiffFile(bad).imagej_metadata["finterval"] == -0.001
    r = run_vfcli("ingest-hsc", "-q", "--force", store, bad)
    _assert_refused(r, 3, "neg.tif", "frame rate -1000 frames/s")
    assert store.read_bytes() == before


def test_tiff_with_infinite_fps_in_its_description_is_refused(tmp_path, hsc_store):
    import tifffile

    store, _, before = hsc_store
    bad = tmp_path / "inf.tif"
    tifffile.imwrite(bad, _frames(), description='{"fps": Infinity}')
    r = run_vfcli("ingest-hsc", "-q", "--force", store, bad)
    _assert_refused(r, 3, "inf.tif", "frame rate inf")
    assert store.read_bytes() == before


def _cihx(tmp_path: Path, name: str, old: str, new: str) -> Path:
    mraw, cihx = write_mraw(tmp_path / name, [_frames(n=4)], fps=FPS)
    text = cihx.read_bytes()
    assert old.encode() in text
    cihx.write_bytes(text.replace(old.encode(), new.encode()))
    return cihx


@pytest.mark.parametrize("old, new, says", [
    ("<recordRate>10000</recordRate>", "<recordRate>1e300</recordRate>", "frame rate 1e+300"),
    ("<recordRate>10000</recordRate>", "<recordRate>1e-300</recordRate>", "frame rate 1e-300"),
    ("<startFrame>0</startFrame>", "<startFrame>1e23</startFrame>", "start frame 1e+23"),
    ("<type>Mono</type>", "<type>Color</type>", "only monochrome"),
])
def test_cihx_with_impossible_or_colour_metadata_is_refused(tmp_path, old, new, says):
    cihx = _cihx(tmp_path, "rec", old, new)
    with pytest.raises(InputDataError, match="frame|monochrome") as exc:
        open_video(cihx)
    assert says in str(exc.value)


def test_cihx_with_impossible_rate_is_exit_3_with_the_store_unchanged(tmp_path, hsc_store):
    store, _, before = hsc_store
    cihx = _cihx(tmp_path, "fast", "<recordRate>10000</recordRate>", "<recordRate>1e300</recordRate>")
    r = run_vfcli("ingest-hsc", "-q", "--force", store, cihx)
    _assert_refused(r, 3, "fast.mraw", "frame rate 1e+300")
    assert store.read_bytes() == before


# --------------------------------------------------------------------------- pressure

def test_truncated_tdms_is_refused_not_read_with_a_warning(tmp_path):
    path = _tdms(tmp_path / "p.tdms", _pressure_samples(1000))
    raw = path.read_bytes()
    cut = tmp_path / "cut.tdms"
    cut.write_bytes(raw[: len(raw) - 517 * 8])   # 483 of 1000 samples left, as in the report
    assert read_pressure(path).samples.size == 1000
    with pytest.raises(InputDataError, match="cut.tdms: channel daq/p_sub is truncated"):
        read_pressure(cut)


def test_tdms_channel_shorter_than_its_group_is_refused(tmp_path):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    props = {"wf_increment": 1 / FS_P}
    path = tmp_path / "two.tdms"
    with TdmsWriter(path) as w:   # two segments: the second one has no pressure samples
        w.write_segment([RootObject(), GroupObject("daq"),
                         ChannelObject("daq", "p_sub", _pressure_samples(500), properties=props),
                         ChannelObject("daq", "trigger", np.zeros(500), properties=props)])
        w.write_segment([ChannelObject("daq", "trigger", np.zeros(500), properties=props)])
    with pytest.raises(InputDataError, match="holds 500 samples, another channel of the group at the same rate 1000"):
        read_pressure(path, channel="p_sub")


def test_truncated_tdms_via_the_cli_is_exit_3(tmp_path, hsc_store):
    store, video, before = hsc_store
    path = _tdms(tmp_path / "p.tdms", _pressure_samples(1000))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 517 * 8])
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", path)
    _assert_refused(r, 3, "p.tdms", "truncated")
    assert store.read_bytes() == before


def test_wav_whose_data_chunk_claims_2_gib_is_refused(tmp_path):
    from scipy.io import wavfile

    path = tmp_path / "p.wav"
    wavfile.write(path, int(FS_P), (np.sin(np.arange(1000) / 7) * 1e4).astype(np.int16))
    raw = bytearray(path.read_bytes())
    i = raw.index(b"data")
    raw[i + 4:i + 8] = struct.pack("<I", 2**31)
    path.write_bytes(bytes(raw))
    with pytest.raises(InputDataError, match="truncated WAV: the data chunk claims 2147483648 bytes, the file "
                                             "holds 2000"):
        read_pressure(path)


def test_stereo_wav_with_a_channel_name_is_a_config_error(tmp_path, hsc_store):
    from scipy.io import wavfile

    store, video, before = hsc_store
    path = tmp_path / "st.wav"
    wavfile.write(path, int(FS_P), (np.random.default_rng(0).normal(0, 1e3, (1000, 2))).astype(np.int16))
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", path,
                  "--set", "ingest_hsc.pressure_channel=left")
    _assert_refused(r, 2, "st.wav", "ingest_hsc.pressure_channel")
    assert store.read_bytes() == before


def _stored_pressure(store: Path) -> tuple[np.ndarray, list[str]]:
    from vfcli.store import Store

    with Store(store).read() as r:
        return np.asarray(r.read("hsc", "pressure")), r.summary("hsc")["warnings"]


def test_a_wav_pressure_is_read_at_the_readers_calibration_and_an_unset_one_is_a_stored_warning(tmp_path):
    """`vfcli ingest-hsc --pressure p.wav` stored the pressure 10 times too small (the config's default full
    scale, 1000 Pa, against the reader's 10 kPa) without a word; a WAV states no unit."""
    import tifffile
    from scipy.io import wavfile

    video = tmp_path / "v.tif"
    tifffile.imwrite(video, _frames(), description='{"fps": 10000.0}')
    p = _pressure_samples()
    wavfile.write(tmp_path / "p.wav", int(FS_P), (p / 1e4).astype(np.float32))   # full scale 1.0 = 10 kPa
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "a.h5", video, "--pressure", tmp_path / "p.wav")
    assert r.returncode == 0, r.stderr
    stored, warnings = _stored_pressure(tmp_path / "a.h5")
    np.testing.assert_allclose(stored, p, rtol=1e-6)
    assert [w for w in warnings if "a WAV states no unit" in w and "ingest_hsc.wav_full_scale_pa" in w], warnings
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "b.h5", video, "--pressure", tmp_path / "p.wav",
                  "--set", "ingest_hsc.wav_full_scale_pa=2000")
    assert r.returncode == 0, r.stderr
    stored, warnings = _stored_pressure(tmp_path / "b.h5")
    np.testing.assert_allclose(stored, p / 5, rtol=1e-6)
    assert not [w for w in warnings if "WAV" in w], warnings
    # the default's value, stated on the command line, is a stated calibration (it was warned as "the default")
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "c.h5", video, "--pressure", tmp_path / "p.wav",
                  "--set", "ingest_hsc.wav_full_scale_pa=10000")
    assert r.returncode == 0, r.stderr
    stored, warnings = _stored_pressure(tmp_path / "c.h5")
    np.testing.assert_allclose(stored, p, rtol=1e-6)
    assert not [w for w in warnings if "WAV" in w], warnings


def test_a_stereo_wav_needs_its_channel_and_takes_it_as_a_number(tmp_path, hsc_store):
    """A stereo WAV was read from channel 0 without a word (all zeros here), and `pressure_channel=1` was
    refused as "Input should be a valid string" although the reader asks for the channel's index."""
    from scipy.io import wavfile

    store, video, before = hsc_store
    p = _pressure_samples()
    wavfile.write(tmp_path / "st.wav", int(FS_P), np.stack([0 * p, p / 1e4], axis=1).astype(np.float32))
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", tmp_path / "st.wav")
    _assert_refused(r, 3, "st.wav", "2 WAV channels", "ingest_hsc.pressure_channel")
    assert store.read_bytes() == before
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", tmp_path / "st.wav",
                  "--set", "ingest_hsc.pressure_channel=1", "--set", "ingest_hsc.wav_full_scale_pa=10000")
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(_stored_pressure(store)[0], p, rtol=1e-6)


def test_finite_but_absurd_pressure_is_refused_at_ingest(tmp_path, hsc_store):
    store, video, before = hsc_store
    path = _tdms(tmp_path / "huge.tdms", _pressure_samples() * 1e305)
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", path)
    _assert_refused(r, 3, "huge.tdms", "pressure reaches 1.1e+308 Pa")
    assert store.read_bytes() == before


def _bare_tdms(path: Path, samples: np.ndarray, fs: float = FS_P) -> Path:
    """A DAQ channel written by npTDMS with its sample interval and no unit (many DAQ programs write none)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    with TdmsWriter(path) as w:
        w.write_segment([RootObject(), GroupObject("daq"),
                         ChannelObject("daq", "ai0", samples, properties={"wf_increment": 1 / fs})])
    return path


def test_a_pressure_without_a_unit_is_a_stored_warning_and_pressure_unit_reads_it(tmp_path):
    """A TDMS channel in kPa with no unit was stored 1000 times too small under unit_in_file "Pa", exit 0, no
    word, and no setting could say otherwise (read_pressure's unit was never passed)."""
    import tifffile

    video = tmp_path / "v.tif"
    tifffile.imwrite(video, _frames(), description='{"fps": 10000.0}')
    p = _pressure_samples()
    path = _bare_tdms(tmp_path / "kpa.tdms", p / 1000)
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "a.h5", video, "--pressure", path)
    assert r.returncode == 0, r.stderr
    stored, warnings = _stored_pressure(tmp_path / "a.h5")
    np.testing.assert_allclose(stored, p / 1000, rtol=1e-12)
    assert [w for w in warnings if "states no pressure unit: read as Pa" in w and "ingest_hsc.pressure_unit" in w]
    assert [w for w in warnings if "no phonation pressure is that small" in w], warnings
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "b.h5", video, "--pressure", path,
                  "--set", "ingest_hsc.pressure_unit=kPa")
    assert r.returncode == 0, r.stderr
    stored, warnings = _stored_pressure(tmp_path / "b.h5")
    np.testing.assert_allclose(stored, p, rtol=1e-12)
    assert not [w for w in warnings if "pressure" in w], warnings
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "c.h5", video, "--pressure", path,
                  "--set", "ingest_hsc.pressure_unit=volt")
    _assert_refused(r, 2, "ingest_hsc.pressure_unit", "'volt' is not a pressure unit")
    assert not (tmp_path / "c.h5").exists()


def test_a_pressure_recorded_as_the_transducers_voltage_is_read_through_its_calibration(tmp_path, hsc_store):
    """A DAQ's raw channel in V (npTDMS, unit_string "V"): refused in one line that names the two settings, the store
    unchanged; with them, /hsc/pressure holds the pressure in Pa as the store of the same pressure in Pa does, and
    the calibration beside it. Before session 69: "'V' is not a pressure unit vfcli knows", no setting to read it."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    from vfcli.store.transaction import Store

    store, video, before = hsc_store
    path = tmp_path / "volts.tdms"
    with TdmsWriter(path) as w:
        w.write_segment([RootObject(), GroupObject("daq"), ChannelObject(
            "daq", "ai0", 0.25 + _pressure_samples() / 4000.0, properties={"wf_increment": 1 / FS_P,
                                                                           "unit_string": "V"})])
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", path)
    _assert_refused(r, 3, "volts.tdms", "recorded in V", "ingest_hsc.pressure_pa_per_volt",
                    "ingest_hsc.pressure_zero_volts")
    assert store.read_bytes() == before
    volt_store = tmp_path / "v.h5"
    r = run_vfcli("ingest-hsc", "-q", volt_store, video, "--pressure", path, "--set",
                  "ingest_hsc.pressure_pa_per_volt=4000", "--set", "ingest_hsc.pressure_zero_volts=0.25")
    assert r.returncode == 0, r.stderr
    with Store(store).read() as a, Store(volt_store).read() as b:
        np.testing.assert_allclose(b.read("hsc", "pressure"), a.read("hsc", "pressure"), rtol=0, atol=1e-9)
        attrs = dict(b.group("hsc")["pressure"].attrs)
    assert attrs["unit_in_file"] == "V" and attrs["pa_per_volt"] == 4000.0 and attrs["zero_volts"] == 0.25


def test_a_pressure_sampled_too_slowly_for_the_f0_range_is_refused_at_ingest_hsc(tmp_path, hsc_store):
    """A pressure sampled at 100 Hz (a CSV whose ms column was read as s, or a slow DAQ) was stored, and
    ingest-ldv then crashed with a traceback in the f0 search (argmax of an empty sequence)."""
    from vfcli.sync.f0 import coarse_f0

    store, video, before = hsc_store
    path = _bare_tdms(tmp_path / "slow.tdms", _pressure_samples(200), fs=100.0)
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--pressure", path)
    _assert_refused(r, 3, "slow.tdms", "sampled at 100 Hz", "up to 45 Hz", "sync.f0_max_hz = 500 Hz")
    assert "states no pressure unit" not in r.stderr   # refused first: no warning about a record not stored
    assert store.read_bytes() == before
    f0, _ = coarse_f0(_pressure_samples(200), 100.0, (50.0, 500.0))   # no candidate below 0.45 fs: NaN, no crash
    assert np.isnan(f0).all()


# --------------------------------------------------------------------------- vibrometer

def _scan(rows=3, cols=4, n_s=400, scale=1.0) -> LdvScan:
    rng = np.random.default_rng(1)
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    xy = np.column_stack([cc.ravel() * 1.0, rr.ravel() * 0.8]) + rng.normal(0, 0.02, (rows * cols, 2))
    coords = np.column_stack([xy, np.zeros(rows * cols)]) * scale
    t = np.arange(n_s) / FS_P
    vel = rng.uniform(50, 200, (rows * cols, 1)) * np.sin(2 * np.pi * 120 * t) + rng.normal(0, 1, (rows * cols, n_s))
    ref = 800 + 300 * np.sin(2 * np.pi * 120 * t) + rng.normal(0, 1, (rows * cols, n_s))
    return LdvScan(np.arange(rows * cols) + 1, coords, vel, FS_P, ref, "Pa", np.zeros(rows * cols))


def _pyuff(path: Path, scan: LdvScan, length_m_per_unit: float | None = 1.0, fs: float = FS_P,
           spacing: int = 1, velocity_label: str = "m/s", displacement: bool = False, rsp_dir: int = 3) -> Path:
    """A PSV-like UFF written with pyuff: 151, 164 (unless None), 2411, 58 records.

    Coordinates are written in file units of ``length_m_per_unit`` metres (mm: 1e-3); dataset
    164's length factor says so (SI = file / factor). ``spacing`` 0: the 58 records flagged uneven
    (abscissa values written beside each sample, no interval); ``velocity_label``: the velocity
    records' unit label ("" for none); ``displacement``: 'Vib  Displacement' records beside them;
    ``rsp_dir``: the velocity records' response direction (3: +Z, -3: -Z, the samples' sign turned).
    """
    import pyuff

    unit = 1.0 if length_m_per_unit is None else length_m_per_unit
    xyz = scan.coords_mm / 1e3 / unit
    p = scan.n_points
    sets = [pyuff.prepare_151(model_name="psv", description="scan", db_app="PSV", program="PSV",
                              return_full_dict=True)]
    if length_m_per_unit is not None:
        sets.append(pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=2,
                                      length=1.0 / length_m_per_unit, force=1.0, temp=1.0,
                                      temp_offset=273.15, return_full_dict=True))
    sets.append(pyuff.prepare_2411(node_nums=scan.node_ids, def_cs=np.zeros(p, int), disp_cs=np.zeros(p, int),
                                   color=np.ones(p, int), x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2],
                                   return_full_dict=True))
    t = np.arange(scan.n_samples) / fs
    per_unit = {"m/s": 1e3, "": 1e3, "mm/s": 1.0}[velocity_label] * (-1.0 if rsp_dir == -3 else 1.0)
    for i in range(p):
        records = [("Response Time Trace", "Vib  Velocity", scan.velocity_mm_s[i] / per_unit, velocity_label, 11),
                   ("Reference Time Trace", "Ref1  Pressure", scan.reference[i], "Pa", 0)]
        if displacement:
            records.append(("Response Time Trace", "Vib  Displacement", np.cumsum(scan.velocity_mm_s[i]) / fs / 1e3, "m",
                            8))
        for id1, id2, data, unit_lab, kind in records:
            sets.append(pyuff.prepare_58(
                binary=1, id1=id1, id2=id2, id3="", id4="", id5="", func_type=1, rsp_node=int(scan.node_ids[i]),
                rsp_dir=rsp_dir if kind == 11 else 3, ref_node=0, ref_dir=0, abscissa_spacing=spacing, abscissa_inc=1 / fs if spacing else 0.0,
                data=data, x=t, ordinate_axis_units_lab=unit_lab, orddenom_spec_data_type=0,
                abscissa_spec_data_type=17, ordinate_spec_data_type=kind))
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    return path


def test_pyuff_scans_with_uneven_flagged_abscissae_displacement_records_or_no_velocity_unit(tmp_path):
    """Legitimate PSV-style UFFs that were refused or misread (hH's walk-through, session 38): records flagged
    uneven (abscissa_spacing 0, pyuff's default) with uniform abscissa values were refused ("abscissa_inc 0.0 is
    not positive"); 'Vib  Displacement' records beside the velocity ones were "two velocity records for node 1";
    velocity records in mm/s without a unit label were read as m/s and refused as 1000 times too fast, with no
    word of the assumed unit and no setting to state it; records measured along -Z (response direction -3) were
    read with the sign of +Z ones."""
    scan = _scan()
    ref = read_ldv(_pyuff(tmp_path / "ref.uff", scan), expected_grid=(3, 4))
    for name, opts in (("uneven.uff", {"spacing": 0}), ("disp.uff", {"displacement": True})):
        got = read_ldv(_pyuff(tmp_path / name, scan, **opts), expected_grid=(3, 4))
        np.testing.assert_array_equal(got.velocity_mm_s, ref.velocity_mm_s)
        assert got.fs == ref.fs and np.allclose(got.t0, ref.t0, atol=1e-12)
    down = read_ldv(_pyuff(tmp_path / "down.uff", scan, rsp_dir=-3), expected_grid=(3, 4))
    np.testing.assert_array_equal(down.velocity_mm_s, ref.velocity_mm_s)    # measured along -Z: turned to +Z
    assert [n for n in down.notes if "12 of 12 velocity records measured along -Z" in n], down.notes
    bare = _pyuff(tmp_path / "bare.uff", scan, velocity_label="")
    quiet = read_ldv(bare, expected_grid=(3, 4))          # m/s assumed, and said
    np.testing.assert_allclose(quiet.velocity_mm_s, ref.velocity_mm_s, rtol=1e-12)
    assert [n for n in quiet.notes if "state no unit" in n and "ingest_ldv.velocity_unit" in n], quiet.notes
    assert not [n for n in ref.notes if "state no unit" in n]
    mm = _pyuff(tmp_path / "mm.uff", scan.__class__(**{**scan.__dict__, "velocity_mm_s": scan.velocity_mm_s * 1e3}),
                velocity_label="")          # the mm/s values written without a label: 1000 times too fast as m/s
    with pytest.raises(InputDataError, match="velocity reaches .* read as m/s: set ingest_ldv.velocity_unit"):
        read_ldv(mm, expected_grid=(3, 4))
    np.testing.assert_allclose(read_ldv(mm, expected_grid=(3, 4), velocity_unit="mm/s").velocity_mm_s,
                               ref.velocity_mm_s, rtol=1e-12)
    with pytest.raises(InputDataError, match="velocity unit mismatch: the records say 'm/s'"):
        read_ldv(_pyuff(tmp_path / "ref2.uff", scan), expected_grid=(3, 4), velocity_unit="mm/s")


def test_a_plausible_pyuff_scan_reads_in_mm(tmp_path):
    scan = _scan()
    back = read_ldv(_pyuff(tmp_path / "ok.uff", scan), expected_grid=(3, 4))
    assert np.allclose(back.coords_mm, scan.coords_mm, rtol=1e-12, atol=1e-12)
    mm = read_ldv(_pyuff(tmp_path / "mm.uff", scan, length_m_per_unit=1e-3), expected_grid=(3, 4))
    assert np.allclose(mm.coords_mm, scan.coords_mm, rtol=1e-12, atol=1e-12)


def test_scan_coordinates_scaled_by_1e6_are_refused(tmp_path):
    path = _pyuff(tmp_path / "big.uff", _scan(scale=1e6))
    with pytest.raises(InputDataError, match="big.uff: the scan points span 3.0..e\\+06 mm, implausible"):
        read_ldv(path, expected_grid=(3, 4))


def test_uff_sampling_rate_of_1_khz_is_refused(tmp_path):
    path = _pyuff(tmp_path / "slow.uff", _scan(), fs=1000.0)
    with pytest.raises(InputDataError, match="slow.uff: vibrometer sampling rate 1000 Hz is impossible"):
        read_ldv(path, expected_grid=(3, 4))


def test_uff_without_units_record_reads_the_one_plausible_unit_and_says_so(tmp_path, caplog):
    scan = _scan()                                                   # spans about 3 mm
    in_m = _pyuff(tmp_path / "nounits.uff", scan, length_m_per_unit=None)         # numbers in m
    with caplog.at_level("WARNING", logger="vfcli.io.ldv.read"):
        back = read_ldv(in_m, expected_grid=(3, 4))
    assert np.allclose(back.coords_mm, scan.coords_mm, rtol=1e-12, atol=1e-12)
    assert "read as m" in caplog.text and "ingest_ldv.length_unit" in caplog.text
    in_mm = _pyuff(tmp_path / "mm.uff", _scan(scale=1e3), length_m_per_unit=None)  # numbers in mm
    assert np.allclose(read_ldv(in_mm, expected_grid=(3, 4)).coords_mm, scan.coords_mm, atol=1e-9)
    # a stated unit wins over the inference: the mm file read as m is 1000 times too large
    with pytest.raises(InputDataError, match="span 3025 mm.*ingest_ldv.length_unit = 'm'"):
        read_ldv(in_mm, expected_grid=(3, 4), length_unit="m")


def test_uff_without_units_record_and_no_plausible_unit_needs_the_config(tmp_path):
    path = _pyuff(tmp_path / "tiny.uff", _scan(scale=1e-4), length_m_per_unit=None)   # 3e-7 file units
    with pytest.raises(InputDataError, match="no units dataset \\(164\\).*set ingest_ldv.length_unit"):
        read_ldv(path, expected_grid=(3, 4))


def test_uff_without_units_record_via_the_cli(tmp_path):
    store = tmp_path / "rec.h5"
    grid = ["--set", "ingest_ldv.grid_rows=3", "--set", "ingest_ldv.grid_cols=4"]
    tiny = _pyuff(tmp_path / "tiny.uff", _scan(scale=1e-4), length_m_per_unit=None)
    r = run_vfcli("ingest-ldv", "-q", store, tiny, *grid)
    _assert_refused(r, 3, "tiny.uff", "set ingest_ldv.length_unit")
    assert not store.exists()
    path = _pyuff(tmp_path / "nounits.uff", _scan(), length_m_per_unit=None)
    r = run_vfcli("ingest-ldv", store, path, *grid)
    assert r.returncode == 0, r.stderr
    assert "read as m" in r.stderr and "ingest_ldv.length_unit" in r.stderr


def _points(scan: LdvScan, keep: np.ndarray) -> LdvScan:
    return LdvScan(scan.node_ids[keep], scan.coords_mm[keep], scan.velocity_mm_s[keep], scan.fs,
                   scan.reference[keep], scan.reference_unit, scan.t0[keep])


def test_a_scan_with_points_left_out_is_read_on_its_grid_and_says_how_many(tmp_path):
    """Points deselected in the vibrometer's software (off the sample, or failed) are not in its export. Before
    session 69 such a scan was refused ("found 10 scan points (3x4), expected a 3 x 4 scan of 12; set
    ingest_ldv.grid_rows/grid_cols for another rig", advice no setting could follow). Now the points there are keep the
    cells they have in the whole scan, and the step says how many are missing."""
    from vfcli.store.transaction import Store

    scan = _scan()
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    assert run_vfcli("ingest-ldv", full, _pyuff(tmp_path / "all.uff", scan), *_GRID).returncode == 0
    keep = np.ones(scan.n_points, bool)
    keep[[0, 6]] = False                                  # a corner and an inner point
    r = run_vfcli("ingest-ldv", part, _pyuff(tmp_path / "part.uff", _points(scan, keep)), *_GRID)
    assert r.returncode == 0, r.stderr
    assert "part.uff: 2 of the 3 x 4 scan grid's points are not in the file" in r.stderr and "other 10" in r.stderr
    with Store(full).read() as a, Store(part).read() as b:
        np.testing.assert_array_equal(b.read("ldv", "node_id"), a.read("ldv", "node_id")[keep])
        np.testing.assert_array_equal(b.read("ldv", "grid_index"), a.read("ldv", "grid_index")[keep])
        np.testing.assert_array_equal(b.read("ldv", "velocity"), a.read("ldv", "velocity")[keep])
        assert b.summary("ldv")["figures"]["points"] == 10 and b.summary("ldv")["figures"]["grid"] == "3x4"


def test_a_scan_whose_points_share_grid_cells_is_refused_with_the_store_unchanged(tmp_path, hsc_store):
    store, _, before = hsc_store
    scan = _scan()
    scan.coords_mm[5] = scan.coords_mm[4] + 0.05           # two points in one cell, a cell of the 3 x 4 grid empty
    r = run_vfcli("ingest-ldv", "-q", store, _pyuff(tmp_path / "shared.uff", scan), *_GRID)
    _assert_refused(r, 3, "shared.uff", "the 12 scan points fill only 11 cells of their 3 x 4 grid")
    assert store.read_bytes() == before


@pytest.mark.parametrize("name, scale, fs, says", [
    ("big.uff", 1e6, FS_P, "the scan points span 3"),
    ("slow.uff", 1.0, 1000.0, "vibrometer sampling rate 1000 Hz is impossible"),
])
def test_scaled_or_slow_uff_via_the_cli_is_exit_3_with_the_store_unchanged(tmp_path, hsc_store, name, scale, fs,
                                                                           says):
    # before: ingest-ldv, sync and flow all exited 0 on these (valid fraction 0, 0 points aligned)
    store, _, before = hsc_store
    path = _pyuff(tmp_path / name, _scan(scale=scale), fs=fs)
    r = run_vfcli("ingest-ldv", "-q", store, path, "--set", "ingest_ldv.grid_rows=3", "--set", "ingest_ldv.grid_cols=4")
    _assert_refused(r, 3, name, says)
    assert store.read_bytes() == before


def test_scan_with_an_absurd_pressure_reference_is_refused(tmp_path):
    scan = _scan()
    scan.reference *= 1e305
    with pytest.raises(InputDataError, match="ref.uff: reference pressure reaches 1.1[0-9]*e\\+308 Pa"):
        read_ldv(_pyuff(tmp_path / "ref.uff", scan), expected_grid=(3, 4))


def test_scan_with_an_absurd_reference_in_volts_is_refused(tmp_path):
    scan = _scan()
    scan.reference = scan.reference / 100 * 1e305   # volts, scaled
    scan.reference_unit = "V"
    path = tmp_path / "volts.mat"
    from scipy.io import savemat

    savemat(path, {"coords": scan.coords_mm, "velocity": scan.velocity_mm_s, "fs": FS_P,
                   "reference": scan.reference, "reference_unit": "V"})
    with pytest.raises(InputDataError, match="volts.mat: reference reaches 1.1[0-9]*e\\+306 V"):
        read_ldv(path, expected_grid=(3, 4))


def test_mat_with_text_node_ids_is_an_input_error(tmp_path):
    from scipy.io import savemat

    s = _scan()
    path = tmp_path / "abc.mat"
    savemat(path, {"coords": s.coords_mm, "velocity": s.velocity_mm_s, "fs": FS_P, "node_ids": "abc"})
    with pytest.raises(InputDataError, match="abc.mat: node numbers are not integers"):
        read_ldv(path, expected_grid=(3, 4))


@pytest.mark.parametrize("bad", [2.5, np.nan, 1e300])
def test_node_numbers_that_are_not_whole_are_refused_not_truncated(tmp_path, bad):
    # found by the fuzzers: 2.5 was read as node 2 (a duplicate), NaN and 1e300 as -2**63 with a numpy warning
    from scipy.io import savemat

    s = _scan()
    ids = s.node_ids.astype(float)
    ids[1] = bad
    path = tmp_path / "frac.mat"
    savemat(path, {"coords": s.coords_mm, "velocity": s.velocity_mm_s, "fs": FS_P, "node_ids": ids})
    with pytest.raises(InputDataError, match="frac.mat: node numbers are not integers: \\[ *(2.5|nan|1.e\\+300)\\]"):
        read_ldv(path, expected_grid=(3, 4))


def _mat_bomb(path: Path, n_bytes: int) -> Path:
    """A MAT v5 file with one compressed double matrix of ``n_bytes`` zeros (deflates ~1000:1)."""
    n = n_bytes // 8
    body = (struct.pack("<II", 6, 8) + struct.pack("<II", 6, 0) + struct.pack("<II", 5, 8) + struct.pack("<ii", 1, n)
            + struct.pack("<II", 1, 8) + b"velocity" + struct.pack("<II", 9, n * 8))
    c = zlib.compressobj(9)
    parts = [c.compress(struct.pack("<II", 14, len(body) + n * 8) + body)]
    zero = bytes(8 * 2**20)
    for k in range(0, n * 8, len(zero)):
        parts.append(c.compress(zero[: min(len(zero), n * 8 - k)]))
    comp = b"".join(parts) + c.flush()
    head = b"MATLAB 5.0 MAT-file".ljust(116, b" ") + bytes(8) + struct.pack("<H", 0x0100) + b"IM"
    path.write_bytes(head + struct.pack("<II", 15, len(comp)) + comp)
    return path


def test_mat_that_inflates_past_its_budget_is_refused_before_inflating_it(tmp_path):
    big = _mat_bomb(tmp_path / "bomb.mat", 2 * inflate_budget(0))   # 128 MiB from about 130 kB
    assert big.stat().st_size < 1e6
    with pytest.raises(InputDataError, match="bomb.mat: compressed element inflates past 64 MiB"):
        read_ldv(big)
    ok = _mat_bomb(tmp_path / "half.mat", inflate_budget(0) // 2)   # within the budget: walked, then judged
    check_mat5(ok)
    with pytest.raises(InputDataError, match="'coords' missing"):
        read_ldv(ok)


# --------------------------------------------------------------------------- config

@pytest.mark.parametrize("toml, says", [
    ("[camera]\noffset_px = [nan, nan]\n", "camera.offset_px.0 = nan: Input should be a finite number"),
    ("[ldv_frame]\naffine = [[1.0, 0.0, nan], [0.0, 1.0, 0.0]]\n", "ldv_frame.affine.0.2 = nan"),
    ("[camera]\npx_per_mm = inf\n", "camera.px_per_mm = inf"),
    ("[optimize]\npressure_medial_shapes = [100000, 100000]\n",
     "optimize.pressure_medial_shapes.0 = 100000: Input should be less than or equal to 8"),
    ("[ingest_hsc]\nroi_px = [0, 0, -5, 99999999999]\n", "ingest_hsc.roi_px.2 = -5"),
    ("a = " + "[" * 100_000 + "]" * 100_000 + "\n", "nested too deep"),
    ("[camera]\npx_per_mm = " + "9" * 5000 + "\n", "not a config value"),
])
def test_impossible_config_is_exit_2_and_never_stored(tmp_path, hsc_store, toml, says):
    store, video, before = hsc_store
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--config", cfg)
    _assert_refused(r, 2, "bad.toml", says)
    assert store.read_bytes() == before


def test_roi_overflow_through_set_is_exit_2(tmp_path, hsc_store):
    store, video, before = hsc_store
    r = run_vfcli("ingest-hsc", "-q", "--force", store, video, "--set", "ingest_hsc.roi_px=[0,0,-5,99999999999]")
    _assert_refused(r, 2, "ingest_hsc.roi_px.3 = 99999999999")
    assert store.read_bytes() == before


# --------------------------------------------------------------------------- environment

def _no_dac() -> list[str]:
    """Command prefix under which file permissions apply (root bypasses them otherwise)."""
    if os.geteuid() != 0:
        return []
    # util-linux's setpriv drops root's permission override, so the permission cases are real
    assert shutil.which("setpriv"), "running as root without setpriv (util-linux): permissions cannot be tested"
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]


def _run_without_dac(*args) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([*_no_dac(), *VFCLI, *map(str, args)], capture_output=True, text=True, env=env,
                          timeout=300)


def test_store_in_a_read_only_folder_is_one_line_exit_4(tmp_path, hsc_store):
    store, video, before = hsc_store
    os.chmod(tmp_path, 0o555)
    try:
        r = _run_without_dac("ingest-hsc", "-q", "--force", store, video)
    finally:
        os.chmod(tmp_path, 0o755)
    _assert_refused(r, 4, "rec.h5", "cannot write the store", "not writable")
    assert store.read_bytes() == before


def _lock_unwritable(lock: Path) -> str:
    os.chmod(lock, 0o444)
    return "cannot write the store: Permission denied"


def _lock_a_directory(lock: Path) -> str:
    lock.unlink()
    lock.mkdir()
    return "cannot write the store: Is a directory"


@pytest.mark.parametrize("spoil", [_lock_unwritable, _lock_a_directory])
def test_lock_file_that_cannot_be_opened_is_one_line_exit_4(tmp_path, hsc_store, spoil):
    store, video, before = hsc_store
    says = spoil(tmp_path / ".rec.h5.lock")   # the lock file the first ingest left
    r = _run_without_dac("ingest-hsc", "-q", "--force", store, video)
    _assert_refused(r, 4, "rec.h5", says, ".rec.h5.lock")
    assert store.read_bytes() == before


def test_unreadable_mraw_partner_is_one_line_exit_3(tmp_path):
    mraw, cihx = write_mraw(tmp_path / "rec", [_frames(n=4)], fps=FPS)
    os.chmod(mraw, 0)
    try:
        r = _run_without_dac("ingest-hsc", "-q", tmp_path / "new.h5", cihx)
    finally:
        os.chmod(mraw, 0o644)
    _assert_refused(r, 3, "rec.mraw", "cannot be read: Permission denied")
    assert not (tmp_path / "new.h5").exists()


def test_image_folder_with_a_32_bit_colour_image_is_an_input_error(tmp_path):
    import tifffile

    d = tmp_path / "frames"
    d.mkdir()
    tifffile.imwrite(d / "f1.tif", np.ones((4, 5, 3), np.int32), photometric="rgb")
    with pytest.raises(InputDataError, match="f1.tif: unsupported pixel type int32"):
        with open_video(d) as v:
            v.read()


def test_info_on_a_fifo_refuses_instead_of_hanging(tmp_path):
    fifo = tmp_path / "pipe.h5"
    os.mkfifo(fifo)
    r = run_vfcli("info", fifo, timeout=60)
    _assert_refused(r, 4, "pipe.h5", "not a regular file")


def test_video_that_is_a_fifo_is_refused(tmp_path):
    fifo = tmp_path / "pipe.tif"
    os.mkfifo(fifo)
    with pytest.raises(InputDataError, match="not a regular file"):
        open_video(fifo)


def test_a_newline_in_a_file_name_or_a_set_key_still_gives_one_line(tmp_path):
    # found by the --set fuzzer: the message quoted the key with its newline (two lines on stderr)
    bad = tmp_path / "bad\nname.tif"
    bad.write_text("not a TIFF")
    r = run_vfcli("ingest-hsc", "-q", tmp_path / "a.h5", bad)
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "bad\\nname.tif" in r.stderr
    r = run_vfcli("config", tmp_path / "b.h5", "--set", "camera\n.x=1")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "camera\\n" in r.stderr


# --------------------------------------------------------------------------- cut-off CSV rows, library chatter

def _assert_one_line(r: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    """Refused with exactly one line on stderr: no library warning, log record or numpy advice."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == code, r.stderr
    assert len(lines) == 1, r.stderr
    for bad in ("Traceback", "Warning", "ERROR tifffile", "nptdms", "usecols"):
        assert bad not in r.stderr, r.stderr
    for n in needles:
        assert n in lines[0], lines[0]


def _cut_inside_last_row(path: Path) -> str:
    """Cut ``path`` two digits into the second value of its last row (a copy interrupted
    mid-line: ``...,14`` where the row had ``...,1404.22``); return what is left of the row."""
    raw = path.read_bytes()
    start = raw.rstrip(b"\r\n").rfind(b"\n") + 1
    path.write_bytes(raw[: raw.index(b",", start) + 3])
    return raw[start: raw.index(b",", start) + 3].decode()


def _csv_module_pressure(path: Path) -> Path:
    """A pressure CSV written by Python's csv module (CRLF line ends), time and pressure columns."""
    import csv

    x = _pressure_samples()
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time [s]", "p_sub [Pa]"])
        w.writerows([repr(k / FS_P), repr(float(v))] for k, v in enumerate(x))
    return path


@pytest.mark.parametrize("quiet", [True, False])
@pytest.mark.parametrize("writer", ["numpy", "csv"])
def test_pressure_csv_cut_inside_its_last_row_is_refused(tmp_path, hsc_store, writer, quiet):
    # before: exit 0, the last sample stored as 14 Pa where the file had 1404.22
    from vfcli.io.pressure import write_pressure_csv

    store, video, before = hsc_store
    path = tmp_path / "cut.csv"
    if writer == "numpy":
        write_pressure_csv(path, _pressure_samples(), FS_P)
    else:
        _csv_module_pressure(path)
    assert read_pressure(path).samples.size == 1000
    row = _cut_inside_last_row(path)
    r = run_vfcli("ingest-hsc", *(["-q"] if quiet else []), "--force", store, video, "--pressure", path)
    _assert_one_line(r, 3, "cut.csv", "last row", "cut off", repr(row), "add a line break")
    assert store.read_bytes() == before


def test_pressure_csv_complete_but_without_a_final_line_break_says_what_to_do(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("# fs = 1000\np\n1\n2\n3")
    with pytest.raises(InputDataError, match="p.csv: .*last row '3' .*add a line break at its end"):
        read_pressure(path)
    path.write_text("# fs = 1000\np\n1\n2\n3\n# end")   # a comment last: no data row cut off
    assert read_pressure(path).samples.tolist() == [1.0, 2.0, 3.0]


def test_pressure_csv_with_a_short_row_names_its_line_not_numpy_advice(tmp_path, hsc_store):
    store, video, before = hsc_store
    path = _csv_module_pressure(tmp_path / "short.csv")
    lines = path.read_bytes().split(b"\r\n")
    lines[500] = lines[500].split(b",")[0]           # line 501: the time value only
    path.write_bytes(b"\r\n".join(lines))
    r = run_vfcli("ingest-hsc", "--force", store, video, "--pressure", path)
    _assert_one_line(r, 3, "short.csv", "line 501", "1 value", "2")
    assert store.read_bytes() == before


def test_pressure_csv_with_text_in_a_row_names_line_and_column(tmp_path):
    path = _csv_module_pressure(tmp_path / "word.csv")
    text = path.read_text().splitlines()
    text[7] = text[7].split(",")[0] + ",n/a"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(InputDataError, match="word.csv: line 8, column 2 \\('p_sub \\[Pa\\]'\\): 'n/a' is not a number"):
        read_pressure(path)


@pytest.mark.parametrize("quiet", [True, False])
def test_tdms_cut_anywhere_gives_one_line_without_nptdms_warnings(tmp_path, hsc_store, quiet):
    # before: npTDMS's two warnings, each printed twice (its own handler and vfcli's), even with -q
    store, video, before = hsc_store
    raw = _tdms(tmp_path / "p.tdms", _pressure_samples(1000)).read_bytes()
    for keep in (3000, 1000, len(raw) - 3):
        path = tmp_path / f"cut{keep}.tdms"
        path.write_bytes(raw[:keep])
        r = run_vfcli("ingest-hsc", *(["-q"] if quiet else []), "--force", store, video, "--pressure", path)
        _assert_one_line(r, 3, path.name, "truncated")
    assert store.read_bytes() == before


def _ldv_csv(path: Path) -> Path:
    from vfcli.io.ldv.write import write_ldv_csv

    return write_ldv_csv(path, _scan())


_GRID = ("--set", "ingest_ldv.grid_rows=3", "--set", "ingest_ldv.grid_cols=4")


@pytest.mark.parametrize("quiet", [True, False])
def test_ldv_csv_cut_anywhere_gives_one_line(tmp_path, hsc_store, quiet):
    # before: a cut inside the header row printed numpy's UserWarning and a line of vfcli's source;
    # a cut inside a row passed on numpy's advice to "use `usecols`"
    store, _, before = hsc_store
    raw = _ldv_csv(tmp_path / "scan.csv").read_bytes()
    header_end = raw.index(b"\ns0,") if b"\ns0," in raw else raw.index(b",s1,")
    for keep in (header_end, raw.index(b"\n1,") + 500, len(raw) // 2, len(raw) - 7):
        path = tmp_path / f"cut{keep}.csv"
        path.write_bytes(raw[:keep])
        r = run_vfcli("ingest-ldv", *(["-q"] if quiet else []), store, path, *_GRID)
        _assert_one_line(r, 3, path.name, "last row", "cut off")
    assert store.read_bytes() == before


def test_ldv_csv_with_only_its_header_or_a_short_row_gives_one_line(tmp_path, hsc_store):
    store, _, before = hsc_store
    path = _ldv_csv(tmp_path / "scan.csv")
    lines = path.read_text().splitlines(keepends=True)
    head = tmp_path / "head.csv"
    head.write_text("".join(lines[:5]))                      # comments and header, no rows
    r = run_vfcli("ingest-ldv", store, head, *_GRID)
    _assert_one_line(r, 3, "head.csv", "no data rows")
    short = tmp_path / "short.csv"
    lines[9] = ",".join(lines[9].split(",")[:100]) + "\n"   # line 10: 100 of 406 values
    short.write_text("".join(lines))
    r = run_vfcli("ingest-ldv", store, short, *_GRID)
    _assert_one_line(r, 3, "short.csv", "line 10", "100 values", "406")
    assert store.read_bytes() == before


@pytest.mark.parametrize("quiet", [True, False])
def test_truncated_tiff_gives_one_line_without_tifffile_logging(tmp_path, hsc_store, quiet):
    # before: "ERROR tifffile: <tifffile.TiffPages @8> invalid page offset ..." above vfcli's line
    store, video, before = hsc_store
    raw = video.read_bytes()
    for keep in (len(raw) // 3, len(raw) - 100):
        path = tmp_path / f"cut{keep}.tif"
        path.write_bytes(raw[:keep])
        r = run_vfcli("ingest-hsc", *(["-q"] if quiet else []), "--force", store, path)
        _assert_one_line(r, 3, path.name)
    assert store.read_bytes() == before
