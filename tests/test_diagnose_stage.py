"""`vfcli diagnose` on a small fitted phantom (the contact phantom tests/test_contact_phantom.py reads
too: fitted and diagnosed once for both), as a user runs it: /diagnose/<run> written with its
provenance, the findings printed in plain words, --json parses, a rerun is up to date, and a
missing run or a bad option is one line with its exit code."""
from __future__ import annotations

import json

import numpy as np
import pytest

from _diagnose_phantom import CONTACT_PHANTOM, ONE_SIDED_FIT, shared_diagnosed_phantom
from conftest import run_vfcli
from vfcli.store import Store
from vfcli.store.parts import copy_store

#: px: how near the stated centre of each fold lies to its true one (measured 2.0 and 2.3), and how far apart the
#: two stated centres lie (measured 69)
STATED_PX, LATERAL_PX = 3.0, 50.0


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """The folder of `vfcli diagnose FITTED --run fit --map maps/map.png` (rec.h5, maps/map.png, stdout.txt),
    shared with tests/test_contact_phantom.py (read-only)."""
    seed, synth = CONTACT_PHANTOM
    return shared_diagnosed_phantom(tmp_path_factory, seed, ONE_SIDED_FIT, synth)


@pytest.fixture(scope="module")
def fitted(diagnosed, tmp_path_factory):
    """This file's copy of the diagnosed store, for the commands that write."""
    return copy_store(diagnosed / "rec.h5", tmp_path_factory.mktemp("diagnosed") / "rec.h5")


def test_diagnose_says_where_its_left_and_right_folds_are_in_the_video(diagnosed):
    """The words name places and parameters by the model's folds; the line after the first says which fold of the
    video each is. Checked against the phantom's own camera and mesh (truth.h5): each stated centre lies within
    STATED_PX of the projection of that fold's true centre, and the two folds are told apart (their centres lie
    LATERAL_PX or more apart; measured on the default phantom's fit, the 2.5 mm mesh's centres against the
    truth's: 2.0 and 2.3 px off, the rounding to whole pixels included, 69 px apart)."""
    import re

    from vfcli.camera.camera import Camera
    from vfcli.store.truth import read_truth

    line = (diagnosed / "stdout.txt").read_text().splitlines()[1]
    assert line.startswith("left and right name the model's folds: in the video's pixels"), line
    stated = [np.array([float(c), float(r)]) for c, r in re.findall(r"centred at col (-?\d+), row (-?\d+)", line)]
    assert len(stated) == 2, line
    t, a = read_truth(diagnosed / "raw" / "truth.h5", ["mesh/nodes", "mesh/tets", "mesh/tet_fold"])
    cam = Camera(a["camera_px_per_mm"], a["camera_rotation_deg"], tuple(a["camera_offset_px"]), 1, 1)
    true = [cam.project(t["mesh/nodes"][np.unique(t["mesh/tets"][t["mesh/tet_fold"] == f])].mean(axis=0))
            for f in (0, 1)]
    print(line, "true centres", true)
    for f in (0, 1):
        assert np.linalg.norm(stated[f] - true[f]) <= STATED_PX, (f, stated[f], true[f])
    assert np.linalg.norm(stated[0] - stated[1]) >= LATERAL_PX


def test_diagnose_writes_the_run_group_and_says_what_it_located(diagnosed):
    png, fitted = diagnosed / "maps" / "map.png", diagnosed / "rec.h5"
    stdout = (diagnosed / "stdout.txt").read_text()
    lines = stdout.splitlines()
    print(stdout)
    assert lines[0].startswith("f0 ") and "whole glottal cycles" in lines[0]
    assert any(line.startswith("the residual sits on the ") or line.startswith("no part of the residual")
               for line in lines)
    assert "candidate screening: 5 candidates screened" in lines
    assert png.stat().st_size > 10_000
    with Store(fitted).read() as r:
        assert r.has_stage("diagnose", "fit")
        attrs = r.attrs("diagnose", "fit")
        p = r.read("diagnose", "hotspot_p", "fit")
        adj = r.read("diagnose", "hotspot_p_adjusted", "fit")
        names = r.read("diagnose", "region_name", "fit")
        mean = r.read("diagnose", "motion_phase_mean", "fit")
        sd = r.read("diagnose", "motion_phase_sd", "fit")
        f0_truthless = float(attrs["f0_hz"])
        frame_time = r.read("diagnose", "frame_time", "fit")
        ds = r.dataset("diagnose", "motion_harmonic_amplitude", "fit")
        assert ds.attrs["units"] == "mm/s"
        assert [d.label for d in ds.dims] == ["region", "component", "harmonic"]
    assert attrs["stage"] == "/diagnose/fit" and attrs["screening"] == "5 candidates screened"
    assert json.loads(attrs["words_json"])[0] == lines[0]
    assert len(names) == 18 and mean.shape == (18, 3, 4) and frame_time.shape == (60,)
    assert np.all((p[np.isfinite(p)] >= 0) & (p[np.isfinite(p)] <= 1)) and np.all(adj >= p - 1e-12)
    assert np.all(sd[np.isfinite(sd)] > 0)
    # the phantom's f0 is drawn near 120 Hz; the gap area's cycle gives it (no truth read here)
    assert 80 < f0_truthless < 250
    # where the time went, phase by phase in the order run (the progress bar's steps)
    phases = json.loads(attrs["phase_seconds_json"])
    assert list(phases)[:3] == ["read", "locate", "screen"] and list(phases)[-1] == "write"
    assert {"calibrate", "map"} <= set(phases) and all(v >= 0 for v in phases.values())


def test_diagnose_json_parses_and_a_rerun_is_up_to_date(fitted):
    first = run_vfcli("diagnose", fitted, "--run", "fit", "--json")
    assert first.returncode == 0, first.stderr
    out = json.loads(first.stdout)
    assert out["stage"] == "/diagnose/fit"
    assert out["screening"] == "5 candidates screened" and isinstance(out["lines"], list) and out["hotspots"]
    assert {"region", "component", "ratio", "p", "p_adjusted"} <= set(out["hotspots"][0])
    with Store(fitted).read() as r:      # the smallest of all (it was the first hotspot's, ranked by ratio)
        adjusted = r.read("diagnose", "hotspot_p_adjusted", "fit")
    assert out["smallest_p_adjusted"] == float(f"{adjusted.min():.4g}")
    # the decision as a field of its own (a batch script read it off the last line): this short phantom's says
    # why it could not be calibrated, as its printed line does; `vfcli info` shows it on a line of its own
    said = next(x for x in out["lines"] if x.startswith("decision: "))
    assert out["decision"] == said[len("decision: "):] and out["decision"].startswith("not calibrated")
    assert out["findings"] == [] and out["leads"] == []
    info = run_vfcli("info", fitted)
    shown = info.stdout.split("/diagnose/fit", 1)[1]
    assert f"\n      decision: {out['decision']}\n" in shown and "decision=" not in shown, info.stdout
    again = run_vfcli("diagnose", fitted, "--run", "fit")
    assert again.returncode == 0 and "up to date" in again.stdout
    assert "candidate screening: 5 candidates screened" in again.stdout


def test_an_up_to_date_diagnosis_over_a_stale_stage_says_so(fitted, tmp_path):
    """After `vfcli config --set flow.median_px=3` a second `vfcli diagnose` printed the old verdict as "up to
    date" while `vfcli info` called the diagnosis STALE (the config change upstream not applied yet)."""
    store = copy_store(fitted, tmp_path / "rec.h5")
    res = run_vfcli("config", store, "--set", "flow.median_px=3")
    assert res.returncode == 0, res.stderr
    res = run_vfcli("diagnose", store, "--run", "fit")
    assert res.returncode == 0 and "up to date" in res.stdout, res.stderr
    hit = [x for x in res.stderr.splitlines() if "is up to date with what it read, but" in x]
    assert len(hit) == 1 and "but /optimize/fit is STALE (" in hit[0] and "/flow is stale" in hit[0], res.stderr
    assert "`vfcli run` redoes the stages in order" in hit[0]


def test_diagnose_user_errors_are_one_line(fitted):
    missing = run_vfcli("diagnose", fitted, "--run", "nope")
    assert missing.returncode == 5, missing.stderr
    assert "Traceback" not in missing.stderr and len(missing.stderr.strip().splitlines()) == 1
    # the command that writes that run and the runs there are ("run `vfcli optimize` first" writes "default")
    assert "run `vfcli optimize --run nope` first, or choose one of its runs: fit" in missing.stderr, missing.stderr
    with Store(fitted).read() as r:
        assert not r.has_stage("diagnose", "nope")
    bad = run_vfcli("diagnose", fitted, "--run", "fit", "--alpha", "2")
    assert bad.returncode == 2 and "alpha" in bad.stderr and "Traceback" not in bad.stderr


def test_a_run_stored_before_the_pressure_band_is_rebuilt_with_the_pressure_as_recorded():
    """A run whose stored [optimize] predates optimize.pressure_band_harmonics was fitted on the pressure as recorded;
    rebuilt with today's default (10 harmonics) its model differed from its stored displacements by 0.03 mm and
    `diagnose` refused it (panel stores 2005 and 2030).  A run that states the band keeps it."""
    from vfcli.config import RecordingConfig
    from vfcli.stages.diagnose import run_recording_config

    attrs = {"ridge_weight": 13.5, "camera_offset_px": [120.0, 130.0], "camera_rotation_deg": 30.0}
    config = RecordingConfig()
    old = config.model_dump(mode="json")["optimize"]
    del old["pressure_band_harmonics"]
    assert run_recording_config(config, {"optimize": old}, attrs, np.zeros(2)).optimize.pressure_band_harmonics is None
    new = {**old, "pressure_band_harmonics": 6.0}
    cfg = run_recording_config(config, {"optimize": new}, attrs, np.zeros(2))
    assert cfg.optimize.pressure_band_harmonics == 6.0 and cfg.optimize.ridge_weight == 13.5
    assert config.optimize.pressure_band_harmonics == 10.0                          # today's default, unchanged


def test_a_run_stored_before_the_closed_rays_rule_is_diagnosed_with_the_rule_it_was_fitted_under():
    """Before session 47 every closed ray asked the simulated edges to meet (optimize.gap_closed_rays = 'meet');
    such a run's residual is rebuilt with that rule, a run that states its rule keeps it."""
    from vfcli.config import RecordingConfig
    from vfcli.stages.diagnose import run_recording_config

    attrs = {"ridge_weight": 13.5, "camera_offset_px": [120.0, 130.0], "camera_rotation_deg": 30.0}
    config = RecordingConfig()
    old = config.model_dump(mode="json")["optimize"]
    del old["gap_closed_rays"]
    assert run_recording_config(config, {"optimize": old}, attrs, np.zeros(2)).optimize.gap_closed_rays == "meet"
    new = {**old, "gap_closed_rays": "overlap-allowed"}
    assert run_recording_config(config, {"optimize": new}, attrs, np.zeros(2)).optimize.gap_closed_rays == \
        "overlap-allowed"
    assert config.optimize.gap_closed_rays == "overlap-allowed"                     # today's default
    # a run stored before session 51 followed the material points in its gradient: it is rebuilt without the slide
    del old["motion_slide"]
    slid = run_recording_config(config, {"optimize": {**old, "motion_slide": True}}, attrs, np.zeros(2))
    assert run_recording_config(config, {"optimize": old}, attrs, np.zeros(2)).optimize.motion_slide is False
    assert slid.optimize.motion_slide is True


def test_a_window_over_the_row_budget_is_diagnosed_on_a_coarser_grid_with_the_same_verdict(diagnosed, fitted):
    """diagnose.max_motion_rows below the window's rows: the motion is compared on every 2nd pixel of every 2nd row
    (a quarter of the rows), the diagnosis says so on its second line and stores the stride, the RMS map is whole
    where the full one is, and the verdict is the full diagnosis' (this phantom's window: 60 frames)."""
    with Store(fitted).read() as r:
        valid = np.asarray(r.read("fields", "valid")[120:180], bool)
        full_rms = r.read("diagnose", "rms_residual", "fit")
    rows = 3 * int(valid.sum())
    res = run_vfcli("diagnose", fitted, "--run", "fit", "--json", "--refit", "none",
                    "--set", f"diagnose.max_motion_rows={rows // 3}")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["lines"][1].startswith("the window's motion was compared on every 2nd pixel of every 2nd row")
    with Store(fitted).read() as r:
        attrs = r.attrs("diagnose", "fit")
        rms = r.read("diagnose", "rms_residual", "fit")
    assert int(attrs["pixel_stride"]) == 2
    seen_full = np.isfinite(full_rms).all(axis=-1)
    seen = np.isfinite(rms).all(axis=-1)
    assert (seen & seen_full).sum() > 0.9 * seen_full.sum()
    # the same decision and the same identifiability per candidate (this short free-load fit: none, uncalibrated)
    full = (diagnosed / "stdout.txt").read_text().splitlines()

    def said(lines):
        return sorted(line.split(";")[0] for line in lines
                      if line.startswith(("decision:", "no missing physics", "missing physics:"))
                      or "not identifiable" in line)

    assert said(full) and said(out["lines"]) == said(full)


def test_the_diagnosis_reads_flows_edge_readings_and_says_when_the_gap_is_doubtful(fitted):
    """read_inputs carries /flow's edge_disagreement; the lines after the first say which fold is which and, when that
    figure is above flow's line, that the gap is doubtful (this phantom's gap is not: measured 4.3 %)."""
    import dataclasses

    from vfcli.config import RecordingConfig
    from vfcli.diagnose.words import GAP_DOUBT_START
    from vfcli.stages.diagnose import context_lines, read_inputs

    with Store(fitted).read() as r:
        stored = float(r.attrs("flow")["edge_disagreement"])
        inputs = read_inputs(r, RecordingConfig(), "fit")
    assert inputs.gap_edge_disagreement == stored and 0.0 <= stored < 0.05
    context = context_lines(inputs, 10**9)
    lines = context.lines
    assert len(lines) == 1 and lines[0].startswith("left and right name the model's folds")
    assert context.stride == "" and context.doubt == ""
    doubtful = context_lines(dataclasses.replace(inputs, gap_edge_disagreement=0.2), 10**9)
    assert doubtful.lines[:1] == lines and doubtful.lines[1] == doubtful.doubt
    assert doubtful.doubt.startswith(GAP_DOUBT_START) and "differ by 20 %" in doubtful.doubt
