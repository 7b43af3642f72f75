"""Pressure readers and writers, checked against npTDMS and scipy's WAV reader."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests._fuzz import fresh, fuzz
from vfcli.errors import InputDataError
from vfcli.io.pressure import (WAV_PA_PER_FULL_SCALE, read_pressure, write_pressure_csv,
                               write_pressure_tdms)

FS = 50_000.0


def _signal(n=2000):
    t = np.arange(n) / FS
    return 800.0 + 300.0 * np.sin(2 * np.pi * 150 * t) + 0.1234567890123 * np.cos(7e3 * t)


# --------------------------------------------------------------------------- TDMS

def test_tdms_round_trip_through_nptdms(tmp_path):
    from nptdms import TdmsFile

    x = _signal()
    path = write_pressure_tdms(tmp_path / "p.tdms", x, FS, t0=0.25)
    ch = TdmsFile.read(path)["pressure"]["p_sub"]
    assert np.array_equal(ch[:], x)
    assert ch.properties["unit_string"] == "Pa"
    assert ch.time_track()[1] == pytest.approx(0.25 + 1 / FS)
    rec = read_pressure(path)
    assert np.array_equal(rec.samples, x)
    assert (rec.fs, rec.t0, rec.unit) == (FS, 0.25, "Pa")
    assert "p_sub" in rec.source


def _tdms_with(tmp_path, channels, unit="kPa", name="lab.tdms"):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    path = tmp_path / name
    objs = [RootObject(), GroupObject("daq")]
    for cname, data, props in channels:
        objs.append(ChannelObject("daq", cname, data, properties=props))
    with TdmsWriter(path) as w:
        w.write_segment(objs)
    return path


def test_tdms_picks_the_pressure_channel_and_converts_kpa(tmp_path):
    x = _signal(100)
    wf = {"wf_increment": 1 / FS, "unit_string": "kPa"}
    path = _tdms_with(tmp_path, [("Mic", x * 0, {"wf_increment": 1 / FS}),
                                 ("P_sub", x / 1000, wf)])
    rec = read_pressure(path)
    assert np.allclose(rec.samples, x, rtol=1e-15) and rec.unit == "kPa"
    assert read_pressure(path, group="daq", channel="Mic").samples.max() == 0


def test_tdms_with_two_unnamed_channels_needs_the_channel_named(tmp_path):
    wf = {"wf_increment": 1 / FS}
    path = _tdms_with(tmp_path, [("ai0", _signal(10), wf), ("ai1", _signal(10), wf)])
    with pytest.raises(InputDataError, match="cannot choose.*ai0.*lab.tdms|lab.tdms.*cannot"):
        read_pressure(path)
    assert read_pressure(path, channel="ai1", unit="Pa").samples.size == 10


def test_tdms_unit_mismatch_with_the_config(tmp_path):
    path = _tdms_with(tmp_path, [("p_sub", _signal(10), {"wf_increment": 1 / FS,
                                                         "unit_string": "kPa"})])
    with pytest.raises(InputDataError, match="unit mismatch.*kPa.*Pa"):
        read_pressure(path, unit="Pa")


def test_tdms_with_a_unit_that_is_neither_a_pressure_nor_a_voltage(tmp_path):
    path = _tdms_with(tmp_path, [("p_sub", _signal(10), {"wf_increment": 1 / FS,
                                                         "unit_string": "A"})])
    with pytest.raises(InputDataError, match="'A' is not a unit vfcli knows \\(pa, .*mmhg; a transducer's output in v, mv"):
        read_pressure(path)


@pytest.mark.parametrize("unit, volts_per_unit", [("V", 1.0), ("mV", 1e-3)])
def test_a_transducers_voltage_reads_in_pa_through_its_calibration_and_is_refused_without(tmp_path, unit,
                                                                                           volts_per_unit):
    """A DAQ's raw channel: the transducer's output, 0.5 V at zero pressure and 1 V per 2 kPa. Before session 69 such
    a TDMS or CSV was refused ("'V' is not a pressure unit") and no setting could read it."""
    x = _signal()
    volts = (0.5 + x / 2000.0) / volts_per_unit
    from vfcli.io.pressure import Transducer

    tdms = _tdms_with(tmp_path, [("ai0", volts, {"wf_increment": 1 / FS, "unit_string": unit})])
    csv = tmp_path / "daq.csv"
    csv.write_text(f"# fs = {FS:g}\np_sub [{unit}]\n" + "\n".join(f"{v:.17g}" for v in volts) + "\n")
    for path in (tdms, csv):
        with pytest.raises(InputDataError, match=f"recorded in {unit} .*ingest_hsc.pressure_pa_per_volt.*"
                                                 "ingest_hsc.pressure_zero_volts"):
            read_pressure(path)
        rec = read_pressure(path, transducer=Transducer(2000.0, 0.5))
        np.testing.assert_allclose(rec.samples, x, rtol=0, atol=1e-9)
        assert rec.unit == unit and rec.unit_source == "file"
    # a file without a unit, stated in the config
    bare = _tdms_with(tmp_path, [("p_sub", volts, {"wf_increment": 1 / FS})], name="bare.tdms")
    rec = read_pressure(bare, unit=unit, transducer=Transducer(2000.0, 0.5))
    np.testing.assert_allclose(rec.samples, x, rtol=0, atol=1e-9)
    assert rec.unit_source == "config"
    with pytest.raises(InputDataError, match=f"unit mismatch: the file says '{unit}'.*'kPa'"):
        read_pressure(tdms, unit="kPa", transducer=Transducer(2000.0, 0.5))


def test_tdms_nan_samples(tmp_path):
    x = _signal(10)
    x[4] = np.nan
    path = _tdms_with(tmp_path, [("p_sub", x, {"wf_increment": 1 / FS})])
    with pytest.raises(InputDataError, match="lab.tdms.*NaN/Inf.*index \\(4,\\)"):
        read_pressure(path)


def test_tdms_without_wf_increment(tmp_path):
    path = _tdms_with(tmp_path, [("p_sub", _signal(10), {})])
    with pytest.raises(InputDataError, match="no wf_increment"):
        read_pressure(path)



def test_tdms_unit_in_ni_unit_description_is_read_and_a_file_without_a_unit_says_so(tmp_path):
    """A DAQmx channel states its unit in NI_UnitDescription: it was read as Pa (1000 times too small for kPa).
    A channel stating no unit is Pa by assumption, and the record says it was assumed (ingest-hsc warns)."""
    x = _signal(100)
    ni = _tdms_with(tmp_path, [("p_sub", x / 1000, {"wf_increment": 1 / FS, "NI_UnitDescription": "kPa"})], name="ni.tdms")
    rec = read_pressure(ni)
    assert np.allclose(rec.samples, x, rtol=1e-14) and (rec.unit, rec.unit_source) == ("kPa", "file")
    bare = _tdms_with(tmp_path, [("p_sub", x / 1000, {"wf_increment": 1 / FS})], name="bare.tdms")
    assert read_pressure(bare).unit_source == "assumed"
    rec = read_pressure(bare, unit="kPa")
    assert np.allclose(rec.samples, x, rtol=1e-14) and (rec.unit, rec.unit_source) == ("kPa", "config")


def test_tdms_with_a_time_channel_in_place_of_waveform_properties(tmp_path):
    """A DAQ that logs a time channel beside the pressure (no wf_increment): it was refused as "not a waveform";
    the time channel's own unit counts (ms here)."""
    x = _signal(200)
    t_ms = (0.002 + np.arange(200) / FS) * 1e3
    path = _tdms_with(tmp_path, [("Time", t_ms, {"unit_string": "ms"}), ("Dev1/ai0", x, {"unit_string": "Pa"})])
    rec = read_pressure(path)
    assert rec.fs == pytest.approx(FS, rel=1e-9) and rec.t0 == pytest.approx(0.002, abs=1e-12)
    assert np.array_equal(rec.samples, x)
    hours = _tdms_with(tmp_path, [("Time", t_ms, {"unit_string": "h"}), ("p", x, {})], name="h.tdms")
    with pytest.raises(InputDataError, match="time channel daq/Time: unit 'h' is not a time unit"):
        read_pressure(hours)

# --------------------------------------------------------------------------- CSV

def test_csv_round_trip_with_and_without_time_column(tmp_path):
    x = _signal()
    for with_time in (True, False):
        path = write_pressure_csv(tmp_path / f"p{with_time}.csv", x, FS, t0=0.5,
                                  with_time=with_time)
        rec = read_pressure(path)
        assert np.array_equal(rec.samples, x)
        assert rec.fs == FS and rec.t0 == 0.5


def test_csv_time_column_in_ms_and_unit_in_header(tmp_path):
    path = tmp_path / "lab.csv"
    t_ms = np.arange(50) / FS * 1e3
    rows = "\n".join(f"{a:.6f};{b}" for a, b in zip(t_ms, np.arange(50) * 0.01))
    path.write_text("Time [ms];Pressure (kPa)\n" + rows + "\n")
    rec = read_pressure(path)
    assert rec.fs == pytest.approx(FS, rel=1e-9) and rec.unit == "kPa"
    assert np.allclose(rec.samples, np.arange(50) * 10.0)


@pytest.mark.parametrize("header, scale", [("Time (msec),p_sub (Pa)", 1e3), ("time [us],p_sub [Pa]", 1e6),
                                           ("time [min],p_sub [Pa]", 1 / 60), ("t_ms,p_sub_kPa", 1e3)])
def test_csv_time_units_in_the_header_are_read_or_refused_by_name(tmp_path, header, scale):
    """'Time (msec)' and 'time [min]' were read as seconds (the record 1000 times too long or 60 times too short,
    exit 0), 'time [us]' refused as an impossible rate; a unit after an underscore (t_ms, p_sub_kPa) was no time
    column at all."""
    x = _signal(100)
    kpa = header.endswith("kPa")
    rows = "\n".join(f"{float(t)!r},{float(p)!r}" for t, p in zip((0.5 + np.arange(100) / FS) * scale, x / 1000 if kpa else x))
    path = tmp_path / "p.csv"
    path.write_text(header + "\n" + rows + "\n")
    rec = read_pressure(path)
    assert rec.fs == pytest.approx(FS, rel=1e-6) and rec.t0 == pytest.approx(0.5, rel=1e-9)
    assert np.allclose(rec.samples, x, rtol=1e-12) and rec.unit == ("kPa" if kpa else "Pa")
    path.write_text(header.replace("[us]", "[h]").replace("(msec)", "(h)").replace("[min]", "[h]").replace("t_ms", "t [h]")
                    + "\n" + rows + "\n")
    with pytest.raises(InputDataError, match="time column .*unit 'h' is not a time unit vfcli knows"):
        read_pressure(path)


def test_csv_comment_values_with_units_and_a_byte_order_mark(tmp_path):
    """'# sample_rate = 50 kHz' was read as 50 Hz and '# t0 = -1 ms' as -1 s (the unit dropped); Excel's
    "CSV UTF-8" (a byte-order mark) hid the first line: 'no time column' for a file that has one."""
    x = _signal(100)
    body = "p_sub [Pa]\n" + "\n".join(repr(float(v)) for v in x) + "\n"
    path = tmp_path / "p.csv"
    path.write_text("# sample_rate = 50 kHz\n# t0 = -1 ms\n" + body)
    rec = read_pressure(path)
    assert (rec.fs, rec.t0) == (FS, pytest.approx(-1e-3, abs=1e-15)) and np.array_equal(rec.samples, x)
    path.write_text("# sample_rate = 50 furlongs\n" + body)
    with pytest.raises(InputDataError, match="'# sample_rate = 50 furlongs': 'furlongs' is not a frequency"):
        read_pressure(path)
    rows = "\n".join(f"{float(t)!r},{float(p)!r}" for t, p in zip(np.arange(100) / FS, x))
    path.write_bytes(("time [s],p_sub [Pa]\n" + rows + "\n").encode("utf-8-sig"))
    rec = read_pressure(path)
    assert rec.fs == pytest.approx(FS, rel=1e-9) and np.array_equal(rec.samples, x)


def test_csv_with_decimal_commas_says_so(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("Zeit [s];Druck [Pa]\n0,00000;812,5\n0,00002;815,0\n")
    with pytest.raises(InputDataError, match="'0,00000' is not a number \\(a decimal comma: .*'\\.' as the decimal"):
        read_pressure(path)


def test_csv_whose_t0_comment_contradicts_its_time_column_is_refused(tmp_path):
    """A '# t0' that disagrees with the time column was dropped without a word (a contradicting '# fs' was
    refused); one that agrees, to within a tenth of a sample, is kept."""
    path = write_pressure_csv(tmp_path / "p.csv", _signal(), FS, t0=0.0)
    text = path.read_text()
    for t0, ok in (("0.002", False), ("nan", False), (repr(0.05 / FS), True)):
        (tmp_path / "q.csv").write_text(text.replace("# t0 = 0.0", f"# t0 = {t0}"))
        if ok:
            assert read_pressure(tmp_path / "q.csv").t0 == 0.0
        else:
            with pytest.raises(InputDataError, match=rf"q.csv.*'# t0 = {t0}' disagrees with the time column"):
                read_pressure(tmp_path / "q.csv")


def test_csv_non_uniform_time_column(tmp_path):
    t = np.arange(100) / FS
    t[60:] += 1 / FS  # one sample missing
    path = tmp_path / "gap.csv"
    path.write_text("t,p_sub\n" + "\n".join(f"{float(a)!r},1.0" for a in t) + "\n")
    with pytest.raises(InputDataError, match="gap.csv.*non-uniform time column"):
        read_pressure(path)


def test_csv_without_rate(tmp_path):
    path = tmp_path / "norate.csv"
    path.write_text("p_sub\n1\n2\n3\n")
    with pytest.raises(InputDataError, match="norate.csv.*neither a time column nor"):
        read_pressure(path)


def test_csv_with_inf_and_text(tmp_path):
    bad = tmp_path / "inf.csv"
    bad.write_text("# fs = 1000\np\n1\ninf\n")
    with pytest.raises(InputDataError, match="inf.csv.*NaN/Inf"):
        read_pressure(bad)
    txt = tmp_path / "words.csv"
    txt.write_text("# fs = 1000\np\n1\nbanana\n")
    with pytest.raises(InputDataError, match="words.csv: line 4, column 1 \\('p'\\): 'banana' is not a number"):
        read_pressure(txt)


# --------------------------------------------------------------------------- WAV

def test_wav_scaled_by_the_documented_full_scale(tmp_path):
    from scipy.io import wavfile

    x = (np.sin(np.arange(500) / 5) * 20000).astype(np.int16)
    path = tmp_path / "p.wav"
    wavfile.write(path, 44100, x)
    rec = read_pressure(path)
    assert rec.fs == 44100
    assert np.allclose(rec.samples, x / 32768 * WAV_PA_PER_FULL_SCALE)
    rec2 = read_pressure(path, wav_pa_per_full_scale=2000.0)
    assert np.allclose(rec2.samples, x / 32768 * 2000.0)


def test_stereo_float_wav_channel_choice(tmp_path):
    from scipy.io import wavfile

    x = np.column_stack([np.zeros(100), np.linspace(-1, 1, 100)]).astype(np.float32)
    path = tmp_path / "s.wav"
    wavfile.write(path, 8000, x)
    rec = read_pressure(path, channel=1, wav_pa_per_full_scale=100.0)
    assert np.allclose(rec.samples, x[:, 1] * 100.0)


# --------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("name,content,match", [
    ("empty.tdms", b"", "empty"),
    ("note.tdms", b"hello, this is text\n", "not a TDMS"),
    ("note.wav", b"hello, this is text\n", "not a WAV"),
    ("bin.csv", b"\xff\xfe\x00\x81garbage", "not a text CSV"),
    ("p.xlsx", b"PK\x03\x04", "unsupported pressure file type"),
])
def test_bad_files_name_the_file(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputDataError, match=match) as exc:
        read_pressure(path)
    assert name in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(InputDataError, match="nothere.tdms: pressure file not found"):
        read_pressure(tmp_path / "nothere.tdms")


# --------------------------------------------------------------------------- fuzz

_SETTINGS = fuzz(400)


@_SETTINGS
@given(kind=st.sampled_from(["tdms", "csv", "wav"]), cut=st.integers(0, 300),
       flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 7)), max_size=6))
def test_fuzzed_pressure_files_raise_only_input_errors(tmp_path, kind, cut, flips):
    from scipy.io import wavfile

    path = fresh(tmp_path / f"f.{kind}")
    x = _signal(64)
    if kind == "tdms":
        write_pressure_tdms(path, x, FS)
    elif kind == "csv":
        write_pressure_csv(path, x, FS)
    else:
        wavfile.write(path, 8000, (x * 10).astype(np.int16))
    b = bytearray(path.read_bytes()[: max(0, len(path.read_bytes()) - cut)])
    for pos, bit in flips:
        if b:
            b[pos % len(b)] ^= 1 << bit
    fresh(path).write_bytes(bytes(b))
    try:
        rec = read_pressure(path)
        assert np.isfinite(rec.samples).all() and rec.fs > 0
    except InputDataError:
        pass


@_SETTINGS
@given(data=st.binary(max_size=400), ext=st.sampled_from(["tdms", "csv", "wav"]))
def test_random_bytes_raise_only_input_errors(tmp_path, data, ext):
    path = fresh(tmp_path / f"r.{ext}")
    path.write_bytes(data)
    try:
        read_pressure(path)
    except InputDataError:
        pass
