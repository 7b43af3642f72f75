"""LDV scan readers and writers (PSV UFF layout via pyuff, CSV, MAT), grid
inference and dropout flags."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests._fuzz import fresh, fuzz
from vfcli.errors import ConfigError, InputDataError
from vfcli.io.ldv.read import LdvChannels, LdvScan, detect_dropouts, infer_grid, read_ldv
from vfcli.io.ldv.write import write_ldv_csv, write_ldv_mat, write_ldv_uff

FS = 50_000.0


def _scan(rows=3, cols=4, n_s=200, seed=0, shuffle=True) -> LdvScan:
    rng = np.random.default_rng(seed)
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    xy = np.column_stack([cc.ravel() * 0.5, rr.ravel() * 0.4])
    xy += rng.normal(0, 0.02, xy.shape)
    coords = np.column_stack([xy, rng.normal(0, 0.1, len(xy))])
    p = rows * cols
    nodes = rng.permutation(p) + 101 if shuffle else np.arange(p) + 101
    t = np.arange(n_s) / FS
    vel = (rng.uniform(10, 100, (p, 1)) * np.sin(2 * np.pi * 150 * t)
           + rng.normal(0, 0.5, (p, n_s)))
    ref = 800 + 200 * np.sin(2 * np.pi * 150 * t) + rng.normal(0, 1, (p, n_s))
    return LdvScan(nodes, coords, vel, FS, ref, "Pa", rng.uniform(0, 1e-3, p))


def _sorted(scan: LdvScan):
    o = np.argsort(scan.node_ids)
    return o


# --------------------------------------------------------------------------- UFF

def test_pyuff_reads_our_uff_back_exactly(tmp_path):
    import pyuff

    scan = _scan()
    path = write_ldv_uff(tmp_path / "scan.uff", scan)
    sets = pyuff.UFF(str(path)).read_sets()
    assert [s["type"] for s in sets[:3]] == [151, 164, 2411]
    geo = sets[2]
    assert np.array_equal(geo["node_nums"], scan.node_ids)
    assert np.array_equal(geo["x"], scan.coords_mm[:, 0] / 1000)
    recs = sets[3:]
    assert len(recs) == 2 * scan.n_points
    for i, node in enumerate(scan.node_ids):
        v, r = recs[2 * i], recs[2 * i + 1]
        assert v["rsp_node"] == r["rsp_node"] == node
        assert v["id1"] == "Response Time Trace" and r["id1"] == "Reference Time Trace"
        assert np.array_equal(v["data"], scan.velocity_mm_s[i] / 1000)   # m/s
        assert np.array_equal(r["data"], scan.reference[i])
        assert v["abscissa_inc"] == pytest.approx(1 / FS)


@pytest.mark.parametrize("binary", [True, False])
def test_read_ldv_round_trip_sorted_by_node(tmp_path, binary):
    scan = _scan()
    back = read_ldv(write_ldv_uff(tmp_path / "s.uff", scan, binary=binary),
                    expected_grid=(3, 4))
    o = _sorted(scan)
    rtol = 1e-15 if binary else 1e-11
    assert np.array_equal(back.node_ids, scan.node_ids[o])
    assert np.allclose(back.velocity_mm_s, scan.velocity_mm_s[o], rtol=rtol, atol=0)
    assert np.allclose(back.reference, scan.reference[o], rtol=rtol, atol=0)
    assert np.allclose(back.coords_mm, scan.coords_mm[o], rtol=1e-15, atol=1e-15)
    assert np.allclose(back.t0, scan.t0[o], rtol=1e-5)   # UFF stores 6 digits
    assert back.fs == FS and back.reference_unit == "Pa"
    assert back.grid_shape == (3, 4) and back.notes == []
    assert not back.dropout.any()


def _pyuff_file(path, scan, order, id2_vel="Vib  Geschwindigkeit", id2_ref="Ref1  Voltage",
                geometry=2411, ref_unit="V"):
    """A PSV-like file written by pyuff's public API (independent of our writer)."""
    import pyuff

    uff = pyuff.UFF(str(path))
    xyz = scan.coords_mm / 1000
    if geometry == 2411:
        geo = pyuff.prepare_2411(node_nums=scan.node_ids, def_cs=np.zeros(scan.n_points, int),
                                 disp_cs=np.zeros(scan.n_points, int), color=np.ones(scan.n_points, int),
                                 x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], return_full_dict=True)
    else:
        geo = pyuff.prepare_15(node_nums=scan.node_ids, def_cs=np.zeros(scan.n_points, int),
                               disp_cs=np.zeros(scan.n_points, int), color=np.ones(scan.n_points, int),
                               x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], return_full_dict=True)
    sets = [pyuff.prepare_151(model_name="psv", description="scan", db_app="PSV",
                              program="PSV", return_full_dict=True),
            pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=2, length=1.0, force=1.0,
                              temp=1.0, temp_offset=273.15, return_full_dict=True), geo]
    t = np.arange(scan.n_samples) / FS
    for i in order:
        for id1, id2, data, unit in (("Response Time Trace", id2_vel,
                                      scan.velocity_mm_s[i] / 1000, "m/s"),
                                     ("Reference Time Trace", id2_ref, scan.reference[i],
                                      ref_unit)):
            sets.append(pyuff.prepare_58(
                binary=1, id1=id1, id2=id2, id3="", id4="", id5="", func_type=1,
                rsp_node=int(scan.node_ids[i]), rsp_dir=3, ref_node=0, ref_dir=0,
                abscissa_spacing=1, abscissa_inc=1 / FS, data=data, x=t,
                ordinate_axis_units_lab=unit, orddenom_spec_data_type=0,
                abscissa_spec_data_type=17, ordinate_spec_data_type=11))
    uff.write_sets(sets, mode="add")
    return path


@pytest.mark.parametrize("geometry", [2411, 15])
def test_reader_matches_shuffled_records_to_geometry_by_node_number(tmp_path, geometry):
    scan = _scan(shuffle=True)
    order = np.random.default_rng(5).permutation(scan.n_points)
    path = _pyuff_file(tmp_path / "psv.uff", scan, order, geometry=geometry)
    back = read_ldv(path, expected_grid=(3, 4))
    o = _sorted(scan)
    assert np.array_equal(back.node_ids, scan.node_ids[o])
    digits = 1e-12 if geometry == 2411 else 1e-5    # dataset 15 is single precision
    assert np.allclose(back.coords_mm, scan.coords_mm[o], rtol=digits, atol=digits)
    assert np.allclose(back.velocity_mm_s, scan.velocity_mm_s[o], rtol=1e-14)
    assert np.allclose(back.reference, scan.reference[o], rtol=1e-14)
    assert back.reference_unit == "V"
    # each point's grid cell follows its coordinates, whatever the record order
    assert np.array_equal(back.grid_index[:, 1], np.round(back.coords_mm[:, 0] / 0.5))
    assert np.array_equal(back.grid_index[:, 0], np.round(back.coords_mm[:, 1] / 0.4))


def test_configurable_channel_labels(tmp_path):
    scan = _scan()
    path = _pyuff_file(tmp_path / "psv.uff", scan, range(scan.n_points), id2_vel="Vib  Speed",
                       id2_ref="Ref2  Pressure", ref_unit="Pa")
    with pytest.raises(InputDataError, match="velocity and reference|no velocity"):
        read_ldv(path, channels=LdvChannels(velocity_id2=r"^Laser"))
    back = read_ldv(path, channels=LdvChannels(reference_id2=r"^\s*Ref2"),
                    expected_grid=(3, 4))
    assert back.reference is not None and back.reference_unit == "Pa"
    only_vel = read_ldv(path, expected_grid=(3, 4))   # default Ref1 pattern finds nothing
    assert only_vel.reference is None and "no reference records" in only_vel.notes


def test_full_psv_scan_written_is_read_exactly_by_pyuff(tmp_path):
    import pyuff

    scan = _scan(rows=17, cols=22, n_s=10_000, seed=2)
    path = write_ldv_uff(tmp_path / "full.uff", scan)  # its time: bench/bench_unit_timings.py
    sets = pyuff.UFF(str(path)).read_sets()
    assert len(sets) == 3 + 2 * 374
    k = 3 + 2 * 200
    assert np.array_equal(sets[k]["data"], scan.velocity_mm_s[200] / 1000)
    back = read_ldv(path)
    assert back.grid_shape == (17, 22) and back.notes == []


def test_uff_in_mm_per_s_with_units_label(tmp_path):
    scan = _scan()
    path = write_ldv_uff(tmp_path / "mm.uff", scan, velocity_unit="mm/s", length_unit="mm")
    back = read_ldv(path, expected_grid=(3, 4))
    o = _sorted(scan)
    assert np.array_equal(back.velocity_mm_s, scan.velocity_mm_s[o])
    assert np.array_equal(back.coords_mm, scan.coords_mm[o])


# --------------------------------------------------------------------------- CSV / MAT

@pytest.mark.parametrize("writer,ext", [(write_ldv_csv, "csv"), (write_ldv_mat, "mat")])
def test_csv_and_mat_round_trips_are_exact(tmp_path, writer, ext):
    scan = _scan()
    back = read_ldv(writer(tmp_path / f"s.{ext}", scan), expected_grid=(3, 4))
    o = _sorted(scan)
    assert np.array_equal(back.node_ids, scan.node_ids[o])
    assert np.array_equal(back.velocity_mm_s, scan.velocity_mm_s[o])
    assert np.array_equal(back.reference, scan.reference[o])
    assert np.array_equal(back.coords_mm, scan.coords_mm[o])
    assert np.array_equal(back.t0, scan.t0[o])
    assert back.fs == FS


def test_writers_refuse_nan(tmp_path):
    scan = _scan()
    scan.velocity_mm_s[1, 7] = np.nan
    for writer in (write_ldv_uff, write_ldv_csv, write_ldv_mat):
        with pytest.raises(ConfigError, match="NaN"):
            writer(tmp_path / "x.uff", scan)


# --------------------------------------------------------------------------- bad input

def _expect(path, match, **kw):
    with pytest.raises(InputDataError, match=match) as exc:
        read_ldv(path, **kw)
    assert path.name in str(exc.value)


def test_uff_without_geometry(tmp_path):
    scan = _scan()
    path = write_ldv_uff(tmp_path / "nogeo.uff", scan)
    text = path.read_bytes()
    i0 = text.index(b"  2411")
    start = text.rindex(b"    -1", 0, i0)
    end = text.index(b"    -1", i0) + 7
    path.write_bytes(text[:start] + text[end:])
    _expect(path, "no geometry dataset")


def test_node_without_geometry(tmp_path):
    scan = _scan()
    path = _pyuff_file(tmp_path / "n.uff", scan, range(scan.n_points))
    text = path.read_bytes()
    node = int(scan.node_ids[0])
    path.write_bytes(text.replace(b"%10i         0         0         1" % node,
                                  b"%10i         0         0         1" % 9999, 1))
    _expect(path, "have no geometry")


def test_text_file_named_uff_and_empty_file(tmp_path):
    txt = tmp_path / "notes.uff"
    txt.write_text("scan notes\n")
    _expect(txt, "not a UFF file")
    empty = tmp_path / "empty.unv"
    empty.write_bytes(b"")
    _expect(empty, "empty")


def test_wrong_channel_labels_list_what_the_file_has(tmp_path):
    scan = _scan()
    path = write_ldv_uff(tmp_path / "s.uff", scan)
    _expect(path, "no velocity records.*Response Time Trace",
            channels=LdvChannels(velocity_id1="Velocity Trace"))


def test_csv_with_nan_and_without_fs(tmp_path):
    scan = _scan()
    path = write_ldv_csv(tmp_path / "n.csv", scan)
    lines = path.read_text().splitlines()
    lines[6] = lines[6].rsplit(",", 1)[0] + ",nan"
    path.write_text("\n".join(lines) + "\n")
    _expect(path, "NaN/Inf")
    path.write_text("\n".join(lines[1:]) + "\n")
    _expect(path, "missing '# fs")


def test_unknown_velocity_unit(tmp_path):
    scan = _scan()
    path = write_ldv_uff(tmp_path / "u.uff", scan)
    path.write_bytes(path.read_bytes().replace(b"m/s                 ", b"furlong/s           "))
    _expect(path, "velocity unit 'furlong/s' not understood")


def test_mat_missing_variable(tmp_path):
    from scipy.io import savemat

    path = tmp_path / "bad.mat"
    savemat(path, {"coords": np.zeros((2, 3)), "fs": 1000.0})
    _expect(path, "'velocity' missing")


def test_mat_with_its_variables_in_a_struct_or_time_along_rows_says_how_to_save_it(tmp_path):
    """MATLAB's save('scan.mat', 'scan') nests the variables in a struct, and a scan exported with time along
    the rows has velocity (S, P): both were refused without a word of the cause ("variable 'coords' missing",
    "velocity has shape (400, 6), expected (6, S >= 2))."""
    from scipy.io import savemat

    rng = np.random.default_rng(0)
    coords, vel = rng.uniform(0, 10, (6, 3)), rng.normal(0, 100, (6, 400))
    nested = tmp_path / "nested.mat"
    savemat(nested, {"scan": {"coords": coords, "velocity": vel, "fs": 50_000.0}})
    _expect(nested, "'coords' missing .* a field of the struct 'scan'")
    along_rows = tmp_path / "rows.mat"
    savemat(along_rows, {"coords": coords, "velocity": vel.T, "fs": 50_000.0})
    _expect(along_rows, "velocity has shape \\(400, 6\\) and coords \\(6, 3\\).*save velocity transposed")


# --------------------------------------------------------------------------- grid

def test_infer_grid_on_a_rotated_jittered_grid_with_the_expected_shape():
    rng = np.random.default_rng(0)
    rr, cc = np.meshgrid(np.arange(17), np.arange(22), indexing="ij")
    pts = np.column_stack([cc.ravel() * 0.3, rr.ravel() * 0.3]) + rng.normal(0, 0.02, (374, 2))
    a = np.radians(12.0)
    rot = pts @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    perm = rng.permutation(374)
    fit = infer_grid(rot[perm] + [5.0, -3.0])
    assert fit.shape == (17, 22) and fit.complete and fit.message == ""
    assert fit.angle_deg == pytest.approx(12.0, abs=1.0)
    assert np.array_equal(fit.index, np.column_stack([rr.ravel(), cc.ravel()])[perm])


def test_a_grid_with_points_left_out_keeps_its_shape_and_cells_and_shared_cells_are_named():
    rng = np.random.default_rng(2)
    rr, cc = np.meshgrid(np.arange(17), np.arange(22), indexing="ij")
    pts = np.column_stack([cc.ravel() * 0.3, rr.ravel() * 0.3]) + rng.normal(0, 0.02, (374, 2))
    keep = np.ones(374, bool)
    keep[[0, 21, 200, 373]] = False                        # three corners and an inner point
    fit = infer_grid(pts[keep])
    assert fit.shape == (17, 22) and not fit.complete and fit.message == ""
    assert np.array_equal(fit.index, np.column_stack([rr.ravel(), cc.ravel()])[keep])
    shared = pts.copy()
    shared[201] = shared[200] + 0.03
    fit = infer_grid(shared)
    assert fit.shape == (17, 22) and not fit.complete
    assert fit.message == "scan grid 17 x 22 has shared cells (374 points, 373 distinct cells)"


@pytest.mark.parametrize("angle", [90.0, -90.0, 60.0, -120.0, 150.0, 170.0])
def test_a_grid_turned_by_more_than_45_deg_reads_in_the_expected_shape_as_a_rotation(angle):
    # a 17 x 22 scan registered to a camera turned about its axis: modulo 90 deg its rows are the columns
    rng = np.random.default_rng(1)
    rr, cc = np.meshgrid(np.arange(17), np.arange(22), indexing="ij")
    pts = np.column_stack([cc.ravel() * 0.3, rr.ravel() * 0.3]) + rng.normal(0, 0.02, (374, 2))
    a = np.radians(angle)
    rot = pts @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    fit = infer_grid(rot)
    assert fit.shape == (17, 22) and fit.complete and fit.message == ""
    assert fit.turned == (45.0 < angle % 180.0 < 135.0)
    # each found (row, col) is the drawn one turned by a multiple of 180 deg within the grid
    idx = np.column_stack([rr.ravel(), cc.ravel()])
    same = np.array_equal(fit.index, idx)
    half = np.array_equal(fit.index, [16, 21] - idx)
    assert same or half
    # orientation kept: neighbours along a row are one column apart, along the drawn row direction
    step = rot[1] - rot[0]                                   # drawn col 0 -> col 1 of row 0
    found = np.radians(fit.angle_deg)
    along = np.array([np.cos(found), np.sin(found)]) @ step
    assert abs(abs(along) - 0.3) < 0.06


def test_only_the_expected_shape_transposed_is_turned_not_a_square_or_other_grid():
    rr, cc = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    fit = infer_grid(np.column_stack([cc.ravel(), rr.ravel()]).astype(float), expected=(10, 12))
    assert fit.turned and fit.shape == (10, 12)
    rr, cc = np.meshgrid(np.arange(11), np.arange(10), indexing="ij")
    fit = infer_grid(np.column_stack([cc.ravel(), rr.ravel()]).astype(float), expected=(10, 12))
    assert not fit.turned and fit.shape == (11, 10) and "expected 10 x 12" in fit.message
    rr, cc = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    fit = infer_grid(np.column_stack([cc.ravel(), rr.ravel()]).astype(float), expected=(6, 6))
    assert not fit.turned and fit.shape == (6, 6) and fit.message == ""


def test_infer_grid_reports_an_unexpected_shape():
    rr, cc = np.meshgrid(np.arange(10), np.arange(12), indexing="ij")
    fit = infer_grid(np.column_stack([cc.ravel(), rr.ravel()]).astype(float))
    assert fit.shape == (10, 12)
    assert "10 rows x 12 cols (120 points), expected 17 x 22 = 374" in fit.message


def test_grid_mismatch_is_noted_when_reading(tmp_path):
    back = read_ldv(write_ldv_mat(tmp_path / "s.mat", _scan()))
    assert any("expected 17 x 22" in n for n in back.notes)


# --------------------------------------------------------------------------- dropouts

def _clean(p=40, n_s=20_000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n_s) / FS
    f0 = rng.uniform(80, 300, (p, 1))
    amp = rng.uniform(1, 200, (p, 1))
    v = amp * (np.sin(2 * np.pi * f0 * t) + 0.3 * np.sin(4 * np.pi * f0 * t + 1))
    return v + rng.normal(0, 1, (p, 1)) * 0.02 * amp * rng.standard_normal((p, n_s))


def test_clean_signals_are_not_flagged_at_any_scale():
    v = _clean()
    for scale in (1e-3, 1.0, 1e3):
        flags, reasons = detect_dropouts(v * scale, FS)
        assert not flags.any(), reasons


def test_noise_only_points_are_not_flagged():
    v = np.random.default_rng(1).normal(0, 1, (30, 50_000))
    assert not detect_dropouts(v, FS)[0].any()


def test_spikes_flat_runs_and_dead_points_are_flagged_with_reasons():
    v = _clean(p=6)
    v[1, 5000] += 40 * np.std(v[1])                 # one dropout spike
    v[2, 8000:8100] = v[2, 8000]                    # held output, 2 ms
    v[3, 100:400] = 0.0                             # zeroed output, 6 ms
    v[4] = 0.0                                      # dead point
    flags, reasons = detect_dropouts(v, FS)
    assert flags.tolist() == [False, True, True, True, True, False]
    assert "spike" in reasons[1] and "t = 0.1 s" in reasons[1]
    assert "flat run of 100 samples" in reasons[2]
    assert "flat run" in reasons[3] and "dead" in reasons[4]
    assert reasons[0] == reasons[5] == ""


# --------------------------------------------------------------------------- fuzz

@pytest.fixture(scope="module")
def small_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("ldvfuzz")
    scan = _scan(rows=2, cols=2, n_s=16)
    return {
        "uff_b": write_ldv_uff(d / "b.uff", scan).read_bytes(),
        "uff_a": write_ldv_uff(d / "a.uff", scan, binary=False).read_bytes(),
        "csv": write_ldv_csv(d / "c.csv", scan).read_bytes(),
        "mat": write_ldv_mat(d / "m.mat", scan).read_bytes(),
    }


_FUZZ = fuzz(500)


@_FUZZ
@given(which=st.sampled_from(["uff_b", "uff_a", "csv", "mat"]), cut=st.integers(0, 400),
       flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 7)), max_size=6))
def test_fuzzed_ldv_files_raise_only_input_errors(tmp_path, small_files, which, cut, flips):
    b = bytearray(small_files[which])
    b = b[: max(0, len(b) - cut)]
    for pos, bit in flips:
        if b:
            b[pos % len(b)] ^= 1 << bit
    path = fresh(tmp_path / ("f." + which.split("_")[0]))
    path.write_bytes(bytes(b))
    try:
        scan = read_ldv(path, expected_grid=None)
        assert np.isfinite(scan.velocity_mm_s).all()
    except InputDataError:
        pass


@fuzz(300)
@given(data=st.binary(max_size=500), ext=st.sampled_from(["uff", "unv", "csv", "mat"]))
def test_random_bytes_raise_only_input_errors(tmp_path, data, ext):
    path = fresh(tmp_path / f"r.{ext}")
    path.write_bytes(data)
    try:
        read_ldv(path)
    except InputDataError:
        pass


def test_mat_with_a_corrupt_element_tag_is_an_input_error_not_a_crash(tmp_path):
    # scipy.io.loadmat segfaults on this file (small element of unknown type 0x30);
    # the structural check must stop it first.
    path = write_ldv_mat(tmp_path / "crash.mat", _scan())
    raw = path.read_bytes()
    tag = raw.index(b"\x10\x00\x04\x00")          # a small miUTF8 element ('mm/s')
    path.write_bytes(raw[:tag] + b"\x30" + raw[tag + 1:])
    _expect(path, "corrupt .mat file")
