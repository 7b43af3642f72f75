"""No silent failure (issue 15): each stage checks that its product is plausible, records a
one-line warning in its stored summary, and fails with exit 3 (store unchanged) where the
product is unusable. Real CLI runs on a small phantom."""
from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from _small_phantom import SMALL, shared_phantom_with_hsc
from conftest import run_vfcli
from vfcli.flow.plausibility import (area_f0, gap_length_share, image_chord_px, points_on_image,
                                    pressure_velocity_bound, scan_beyond_frames)
from vfcli.io.ldv.read import read_ldv
from vfcli.io.ldv.write import write_ldv_uff
from vfcli.store import Store, copy_store


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A phantom and a store with its /hsc (shared with tests/test_sync_short_video.py: the same
    seed and settings; read-only, the tests copy it)."""
    return shared_phantom_with_hsc(tmp_path_factory, 4, SMALL)


def _copy(store, tmp_path):
    return copy_store(store, tmp_path / "rec.h5")


def test_points_on_image_and_the_velocity_bound_by_hand():
    px = np.array([[0.0, 0.0], [-0.6, 3.0], [9.4, 4.0], [9.6, 4.0], [np.nan, 1.0]])
    np.testing.assert_array_equal(points_on_image(px, (5, 10)), [True, False, True, False, False])
    # 1 kPa peak, rho c = 1000 kg/m^3 x 0.5 m/s = 500 kg/m^2/s: 2 m/s
    assert pressure_velocity_bound(np.array([800.0, -1000.0, np.nan])) == pytest.approx(2000.0)


def test_scan_points_off_the_video_fail_ingest_ldv_with_advice(video, tmp_path):
    raw, hsc = video
    store = _copy(hsc, tmp_path)
    before = store.read_bytes()
    # a scan 1 m to the side (coordinates read in the wrong unit land as far off)
    res = run_vfcli("ingest-ldv", store, raw / "scan.uff", "--set", "ldv_frame.affine=[[1, 0, 1000], [0, 1, 0]]")
    assert res.returncode == 3, res.stderr
    lines = [x for x in res.stderr.splitlines() if "error" in x]
    assert len(lines) == 1 and "none of the 374 scan points lies on the video's frames" in lines[0]
    assert "ingest_ldv.length_unit" in lines[0] and "ldv_frame.affine" in lines[0]
    assert store.read_bytes() == before


def test_some_scan_points_off_the_video_are_a_stored_warning(video, tmp_path):
    raw, hsc = video
    store = _copy(hsc, tmp_path)
    res = run_vfcli("ingest-ldv", store, raw / "scan.uff", "--set", "ldv_frame.affine=[[1, 0, 6], [0, 1, 0]]")
    assert res.returncode == 0, res.stderr
    with Store(store).read() as r:
        warnings = r.summary("ldv")["warnings"]
    hit = [w for w in warnings if "scan points lie outside the video's frames" in w]
    assert len(hit) == 1 and "ldv_frame.affine" in hit[0] and "ingest_ldv.length_unit" in hit[0]
    # where the scan lies against the frames, in mm: the scan's own size (the synth's 17 x 22 grid) and the frames'
    spans = re.search(r"the scan spans ([\d.]+) x ([\d.]+) mm .*, the frames ([\d.]+) x ([\d.]+) mm", hit[0])
    scan = read_ldv(raw / "scan.uff")
    assert spans, hit[0]
    np.testing.assert_allclose([float(spans.group(1)), float(spans.group(2))], np.ptp(scan.coords_mm[:, :2], axis=0),
                               rtol=0.01)
    assert "expected where the camera sees only part of the scanned folds" in hit[0]
    info = run_vfcli("info", store)
    assert info.returncode == 0 and "outside the video's frames" in info.stdout


def test_the_words_for_a_scan_partly_off_the_frames_give_both_sizes_by_hand():
    """A zoomed camera (frames 10 x 8 mm at 20 px/mm) inside a 16 x 12 mm scan, and the same scan in metres read as
    millimetres (0.016 x 0.012 mm): the sizes side by side tell the two apart; no verdict either way."""
    grid = np.stack(np.meshgrid(np.linspace(-3.0, 13.0, 17), np.linspace(-2.0, 10.0, 22)), -1).reshape(-1, 2)
    words = scan_beyond_frames(grid * 20.0, (160, 200), 20.0)
    assert words.startswith("the scan spans 16 x 12 mm (columns -60..260, rows -40..200 px), "
                            "the frames 10.0 x 8.0 mm (200 x 160 px): expected where the camera sees only part")
    assert "ingest_ldv.length_unit" in words and "ldv_frame.affine" in words
    tiny = scan_beyond_frames(grid * 0.02 + 100.0, (160, 200), 20.0)
    assert tiny.startswith("the scan spans 0.016 x 0.012 mm")
    assert scan_beyond_frames(np.full((3, 2), np.nan), (160, 200), 20.0).startswith("the frames 10.0 x 8.0 mm")


def test_velocities_beyond_what_the_pressure_drives_are_a_stored_warning(video, tmp_path):
    """A vibrometer file whose velocities are 20 x too large (a mis-set velocity range): /fields warns.
    (Its dropout points, with their spikes, are left as they are: ingest-ldv's own limit would refuse them.)"""
    raw, hsc = video
    store = _copy(hsc, tmp_path)
    scan = read_ldv(raw / "scan.uff")
    gain = np.where(scan.dropout, 1.0, 20.0)[:, None]
    write_ldv_uff(tmp_path / "scan.uff", replace(scan, velocity_mm_s=scan.velocity_mm_s * gain))
    for args in (["ingest-ldv", store, tmp_path / "scan.uff"], ["sync", store], ["flow", store]):
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        warnings = r.summary("fields")["warnings"]
    hit = [w for w in warnings if "beyond the" in w and "the recorded pressure can drive" in w]
    assert len(hit) == 1, warnings
    with Store(store).read() as r:      # the video's own frame rate: its glottal area keeps the pressure's rhythm
        assert not [w for w in r.summary("flow")["warnings"] if "repeats at" in w]
        # the scan's own pressure beside it (its velocities scaled, not its reference): one operating point
        assert not [w for w in r.summary("sync")["warnings"] if "differs between the video and the scan" in w]


def test_a_scan_recorded_at_another_pressure_is_a_stored_warning_of_sync(video, tmp_path):
    """The video of one operating point with the scan of another (its pressure half as high again) aligned on
    every point and ran to an inferior surface about 50 % off with exit 0: the pressure beside each tells."""
    raw, hsc = video
    store = _copy(hsc, tmp_path)
    scan = read_ldv(raw / "scan.uff")
    assert scan.reference_unit == "Pa"
    write_ldv_uff(tmp_path / "scan.uff", replace(scan, reference=scan.reference * 1.5))
    for args in (["ingest-ldv", store, tmp_path / "scan.uff"], ["sync", store]):
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        warnings = r.summary("sync")["warnings"]
        assert int(r.read("sync", "ok").sum()) > 300                 # sync itself is content: the phases match
    hit = [w for w in warnings if "differs between the video and the scan" in w]
    assert len(hit) == 1, warnings
    mean = re.search(r"its mean is (\d+) Pa beside the video, (\d+) Pa beside the scan", hit[0])
    assert mean and float(mean.group(2)) == pytest.approx(1.5 * float(mean.group(1)), rel=0.01)
    assert "swing" in hit[0] and "operating points" in hit[0] and "different recordings" in hit[0]


def test_the_glottal_areas_rhythm_by_hand():
    """A pulse train of 120 Hz (the glottis closed 40 % of each cycle) sampled at 10 kHz: its f0 on the right
    time base, twice it on one twice too fast, nothing from a video of one opening or a constant area."""
    t = np.arange(300) / 10_000.0
    area = np.maximum(np.sin(2 * np.pi * 120.0 * t) - 0.3, 0.0)
    assert area_f0(area, 10_000.0, (50.0, 500.0), 120.0) == pytest.approx(120.0, rel=0.004)
    # 3.6 cycles read at 20 kHz: 1.8 cycles of the pressure, but 4 openings
    assert area_f0(area, 20_000.0, (50.0, 500.0), 120.0) == pytest.approx(240.0, rel=0.004)
    assert area_f0(area[:100], 10_000.0, (50.0, 500.0), 120.0) is None          # 1.2 cycles: one opening
    assert area_f0(np.ones(300), 10_000.0, (50.0, 500.0), 120.0) is None


def test_a_video_frame_rate_off_by_a_tenth_is_a_stored_warning(video, tmp_path):
    """A CIHX recordRate of 20000 for 10000 ran to an inferior surface 26 % off with exit 0 and no word about the
    frame rate: the glottal area repeats at another frequency than the pressure beside the video (/sync's f0),
    on a time base 10 % too fast here (the phantom's 2.4 cycles read as 2.2)."""
    raw, _ = video
    store = tmp_path / "fast.h5"
    for args in (("ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                  "--config", raw / "recording.toml"), ("ingest-ldv", store, raw / "scan.uff"), ("sync", store),
                 ("flow", store)):
        res = run_vfcli(*args, "--set", "camera.fps_hz=11000")
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        warnings = r.summary("flow")["warnings"]
        f0 = float(r.attrs("sync")["f0_video_hz"])
    hit = [w for w in warnings if "repeats at" in w]
    assert len(hit) == 1, warnings
    assert "(11000 frames/s)" in hit[0] and "frame rate" in hit[0] and "factor of 1.1:" in hit[0]
    assert f"at {f0:.4g} Hz (/sync's f0)" in hit[0]
    with Store(store).read() as r:     # the vibrometer's own unit: vertical and horizontal of one order
        assert not [w for w in r.summary("fields")["warnings"] if "times the video's horizontal velocity" in w]


def test_a_vibrometer_velocity_in_m_per_s_read_as_mm_per_s_is_a_stored_warning(video, tmp_path):
    """Velocities in m/s in a file that says mm/s ran to an inferior surface 124 % off with exit 0, with only the
    static-shape warning: the vibrometer's vertical velocity is then 1000 times smaller than the video's motion."""
    raw, hsc = video
    store = _copy(hsc, tmp_path)
    scan = read_ldv(raw / "scan.uff")
    write_ldv_uff(tmp_path / "scan.uff", replace(scan, velocity_mm_s=scan.velocity_mm_s * 1e-3))
    for args in (["ingest-ldv", store, tmp_path / "scan.uff"], ["sync", store], ["flow", store]):
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        warnings = r.summary("fields")["warnings"]
    hit = [w for w in warnings if "times the video's horizontal velocity" in w]
    assert len(hit) == 1, warnings
    ratio = float(re.search(r"is ([0-9.e-]+) times the video's", hit[0]).group(1))
    assert 1e-4 < ratio < 1 / 30 and "velocity unit" in hit[0]


def test_the_chord_of_the_frame_and_the_gaps_share_of_it_by_hand():
    # a 100 x 200 (H x W) frame: a row through the centre spans 199 px, a column 99, the diagonal 99 * sqrt(2)
    assert image_chord_px((100.0, 49.5), 0.0, (100, 200)) == pytest.approx(199.0)
    assert image_chord_px((100.0, 49.5), 90.0, (100, 200)) == pytest.approx(99.0)
    assert image_chord_px((100.0, 49.5), 45.0, (100, 200)) == pytest.approx(99.0 * np.sqrt(2))
    assert image_chord_px((20.0, 10.0), 0.0, (100, 200)) == pytest.approx(199.0)
    assert image_chord_px((-5.0, 10.0), 0.0, (100, 200)) == 0.0
    # a diagonal slit 1 px wide over 41 pixel centres of a 200 x 200 frame: found 41 px
    counts = np.zeros((200, 200))
    for i in range(80, 121):
        counts[i, i] = 5
        counts[i, i + 1] = 2
    found, in_view = gap_length_share(counts, length_px=150.0)
    assert found == pytest.approx(41 * np.sqrt(2), rel=0.03)
    assert in_view == 150.0                                       # the folds, shorter than the chord
    _, in_view = gap_length_share(counts, length_px=1000.0)
    assert in_view == pytest.approx(199 * np.sqrt(2) + 1, rel=0.02)  # the chord, where the folds run off the frame


def test_a_video_shorter_than_one_glottal_cycle_is_refused_by_flow(video, tmp_path):
    """A 2-frame video (a new user's cut file) ran through flow and optimize to a "converged" fit of 2 % of a
    glottal cycle with a stated uncertainty of 10 % (session 35). /sync's f0 is read from the pressure, which
    covers the whole recording: a video shorter than one period of it is now refused by flow, exit 3."""
    raw, _ = video
    store = tmp_path / "short.h5"
    for args in (("ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
                  "--config", raw / "recording.toml", "--set", "ingest_hsc.n_frames=20"),
                 ("ingest-ldv", store, raw / "scan.uff"), ("sync", store)):
        res = run_vfcli(*args)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        f0 = float(r.attrs("sync")["f0_video_hz"])
        fps = float(r.attrs("hsc")["fps_hz"])
    assert 20 / fps * f0 < 1.0                                   # the premise: 2 ms of a ~8 ms cycle
    before = store.read_bytes()
    res = run_vfcli("flow", store)
    assert res.returncode == 3 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "the video holds 20 frames (2 ms), less than one glottal cycle" in res.stderr
    assert store.read_bytes() == before
