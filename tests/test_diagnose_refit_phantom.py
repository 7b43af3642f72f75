"""`vfcli diagnose --refit` on phantoms, as a user runs it: one with a hidden left-right stiffness
asymmetry, one with none (seeds 31, 34: outside the reserved panels), short recordings, the
pressure load model (under which asymmetry is identifiable).

With the effect the refit finds the softening within 25 % of the phantom's truth (truth.h5, read
by the test only) and the held-out error drops; on the null the softening's interval covers 0 (or
the estimate is negligible) and the held-out error does not improve beyond its spread.  Each run
is stored as /optimize/<run>+asymmetry with the history and the stated uncertainty.
"""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from _diagnose_phantom import PHANTOM, fitted_phantom
from _small_phantom import shared_raw
from conftest import run_vfcli
from vfcli.store import Store

# two phantom pipelines and two diagnoses with a refit (40 frames, 4 iterations on a 0.02 s phantom):
# 45 s each alone, 70-95 s beside the other worker
pytestmark = [pytest.mark.slow, pytest.mark.timeout(3600)]

FIT = ["--set", "optimize.loads=pressure", "--set", "optimize.n_frames=40", "--set", "optimize.first_frame=120",
       "--set", "mesh.target_edge_mm=2.5", "--set", "optimize.max_iterations=4", "--run", "fit"]


def _pipeline(d, seed: int, effect: str, strength: float, maps: bool = True, raw=None):
    """The phantom's store fitted, diagnosed with the asymmetry refit (with its residual maps and velocity
    plots when ``maps``: 7 of the diagnosis' 27 s on this phantom, session 33); ``raw``: its raw folder made
    already (read-only), else `vfcli synth` writes it into d / "raw"."""
    store = fitted_phantom(d, seed, FIT, ("--effect", effect, "--strength", str(strength)), raw=raw)
    raw = raw if raw is not None else d / "raw"
    res = run_vfcli("diagnose", store, "--run", "fit", "--refit", "asymmetry", "--json",
                    *(("--map", d / "map.png") if maps else ()), timeout=1800)
    assert res.returncode == 0, res.stderr
    with h5py.File(raw / "truth.h5", "r") as t:
        truth = float(t.attrs["strength"])
    return store, json.loads(res.stdout), truth, d


@pytest.fixture(scope="module")
def effect(tmp_path_factory):
    return _pipeline(tmp_path_factory.mktemp("asym"), 31, "asymmetry", 0.25)


@pytest.fixture(scope="module")
def null(tmp_path_factory):
    """Seed 34 with no effect: the raw folder `vfcli synth --seed 34` writes with PHANTOM (shared with
    tests/test_store_integrity.py and tests/test_hostile_rate.py; the same files as with `--effect none
    --strength 0` but for phantom.json's "strength": null, and the scan's time stamp)."""
    raw = shared_raw(tmp_path_factory, 34, PHANTOM)
    return _pipeline(tmp_path_factory.mktemp("none"), 34, "none", 0.0, maps=False, raw=raw)  # no test looks at its maps


def test_refit_recovers_the_hidden_softening_and_predicts_better(effect):
    store, out, truth, d = effect
    ref = out["refit"]
    par = ref["parameters"]["left_softening"]
    print(json.dumps(ref, indent=1))
    assert abs(par["estimate"] - truth) < 0.25 * truth and ref["moved"] is True
    # the sandwich with what the held-out fits say apart (vfcli.diagnose.confirmation.heldout_sd)
    assert par["sd"] > 0 and ref["uncertainty"].startswith("sandwich") and "jackknife" in ref["uncertainty"]
    lo, hi = par["interval"]
    print(f"left_softening {par['estimate']:.4f} ({lo:.4f} .. {hi:.4f}), truth {truth}")
    kinds = {h["kind"]: h for h in ref["heldout"]}
    assert "cycles" in kinds
    assert kinds["cycles"]["reduction"] > 0.1
    assert all(e < b for e, b in zip(kinds["cycles"]["extended"], kinds["cycles"]["baseline"]))
    assert any(line.startswith("refit with asymmetry (run fit+asymmetry): left_softening = ") for line in out["lines"])
    assert any(line.startswith("held-out error leaving frames out (by cycle, or by block in a short window): ") for line in out["lines"])
    for name in ("map_refit.png", "map_points.png", "map.png"):
        assert (d / name).stat().st_size > 10_000


def test_refit_is_stored_as_its_own_run_with_history_and_uncertainty(effect):
    store, out, truth, _ = effect
    with Store(store).read() as r:
        attrs = r.attrs("optimize", "fit+asymmetry")
        hist = r.read("optimize", "history_total", "fit+asymmetry")
        theta_hist = r.read("optimize", "history_theta", "fit+asymmetry")
        theta = r.read("optimize", "refit_theta", "fit+asymmetry")
        sd = r.read("optimize", "refit_theta_sd", "fit+asymmetry")
        disp = r.read("optimize", "displacements", "fit+asymmetry")
        base_disp = r.read("optimize", "displacements", "fit")
        base_e = r.read("optimize", "history_total", "fit")[-1]
        diag = r.attrs("diagnose", "fit")
        held_b = r.read("diagnose", "heldout_cycles_baseline", "fit")
    assert attrs["refit_of"] == "fit" and attrs["refit_candidate"] == "asymmetry" and attrs["pixel_stride"] == 1
    assert "left_softening" in attrs["message"]
    assert hist[-1] < hist[0] and hist[-1] < base_e
    assert theta_hist.shape == (len(hist), 1) and theta_hist[0, 0] == 0.0
    assert theta[0] == pytest.approx(out["refit"]["parameters"]["left_softening"]["estimate"])
    assert sd[0] == pytest.approx(out["refit"]["parameters"]["left_softening"]["sd"])
    assert disp.shape == base_disp.shape
    assert diag["refit_candidate"] == "asymmetry" and diag["refit_run"] == "fit+asymmetry"
    assert len(held_b) == len(out["refit"]["heldout"][0]["baseline"])


def test_on_a_null_phantom_the_refit_finds_nothing_to_add(null):
    _, out, _, _ = null
    ref = out["refit"]
    print(json.dumps(ref, indent=1))
    par = ref["parameters"]["left_softening"]
    lo, hi = par["interval"]
    assert lo <= 0 <= hi or abs(par["estimate"]) < 0.05
    assert not any(h["beyond_spread"] and h["reduction"] > 0.1 for h in ref["heldout"])


def test_an_unknown_refit_name_is_one_line_and_leaves_the_store_alone(null):
    store, _, _, _ = null
    before = Store(store).path.stat().st_mtime_ns
    res = run_vfcli("diagnose", store, "--run", "fit", "--refit", "gravity")
    assert res.returncode == 2
    assert "--refit 'gravity': choose one of auto, none, inertia, damping, asymmetry, offset, contact" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert Store(store).path.stat().st_mtime_ns == before


def _gradient_left(base, problem, keep, x) -> float:
    """|grad E(x)| / |grad E(base.x)| of ``problem``'s E on the ``keep`` frames, raster frozen at the baseline's fit."""
    from vfcli.diagnose.refit import _blocks, _Extended

    ext = _Extended(problem, None, base.f0_hz, base.model, keep)
    start = ext.state(np.asarray(base.x, float), np.zeros(0))
    ext.frames = start.frames
    g0 = _blocks(ext, start, loads_only=True)[0]
    g1 = _blocks(ext, ext.state(np.asarray(x, float), np.zeros(0)), loads_only=True)[0]
    return float(np.linalg.norm(g1) / np.linalg.norm(g0))


def test_a_leave_cycles_out_fit_leaves_its_start_and_predicts_frames_it_did_not_see(effect):
    """Each split's baseline refit starts at the whole window's fit.  With the raster refrozen at each
    trial none of them moved (E rose along every load step), so its "held-out" error was the whole
    window's fit's own on those frames; with the raster frozen at the start (``frozen``) it reaches the
    minimum of its own frames' E, and predicts the left-out frames differently."""
    from vfcli.config import RecordingConfig
    from vfcli.diagnose.heldout import cycle_groups, prediction_error
    from vfcli.diagnose.refit import joint_fit
    from vfcli.stages.diagnose import read_inputs

    store, _, _, _ = effect
    with Store(store).read() as r:
        base = read_inputs(r, RecordingConfig(), "fit").baseline
    n = base.problem.n_frames
    groups = cycle_groups(np.zeros(n))            # one "cycle": six blocks, the four inner ones held out
    assert list(np.unique(groups)) == [-1, 0, 1, 2, 3]
    for g in (0, 2):
        held = np.flatnonzero(groups == g)
        keep = groups != g
        fit = joint_fit(base.problem, base.x, None, base.f0_hz, keep=keep, max_iterations=3, model=base.model,
                        stated=False, frozen=True)
        start, end = fit.history["total"][0], fit.history["total"][-1]
        print(f"split {g}: E of the kept frames {start:.5g} -> {end:.5g}, |dx| / |x| "
              f"{np.linalg.norm(fit.x - base.x) / np.linalg.norm(base.x):.3g}")
        assert end < (1 - 1e-4) * start
        # at its end the gradient of the kept frames' E (raster frozen at the start) is gone
        assert _gradient_left(base, base.problem, keep, fit.x) < 1e-3
        # and the frames left out are predicted by a fit that did not see them
        seen = prediction_error(base, base.displacements, held)
        unseen = prediction_error(base, fit.displacements, held)
        print(f"  held-out frames: error of the whole window's fit {seen:.4g} mm/s, of the split's fit {unseen:.4g}")
        assert abs(unseen - seen) > 1e-4 * seen


def test_the_camera_only_fit_reaches_its_own_minimum_and_predicts_the_vibrometer_afresh(effect):
    """The across-instruments check fits the camera, gap and pressure from the whole window's fit, which saw
    the vibrometer, and predicts the vertical velocity.  A fit that stayed near that start would predict the
    vibrometer with loads fitted to it; with the raster frozen at the start it reaches the minimum of the
    camera's own E (the gradient gone, as the leave-cycles-out fits), and its vertical velocity is its own."""
    from vfcli.config import RecordingConfig
    from vfcli.diagnose.heldout import CAMERA_ONLY, prediction_error
    from vfcli.diagnose.refit import joint_fit
    from vfcli.stages.diagnose import read_inputs

    store, _, _, _ = effect
    with Store(store).read() as r:
        base = read_inputs(r, RecordingConfig(), "fit").baseline
    camera = base.problem.with_weights(component_weights=CAMERA_ONLY)
    fit = joint_fit(camera, base.x, None, base.f0_hz, max_iterations=4, model=base.model, stated=False, frozen=True)
    start, end = fit.history["total"][0], fit.history["total"][-1]
    left = _gradient_left(base, camera, None, fit.x)
    frames = np.arange(base.problem.n_frames)
    seen = prediction_error(base, base.displacements, frames, (2,))
    unseen = prediction_error(base, fit.displacements, frames, (2,))
    print(f"camera-only fit: E {start:.5g} -> {end:.5g} in {len(fit.history['total']) - 1} steps, gradient left {left:.2e}; "
          f"vertical velocity error {seen:.4g} mm/s (whole fit) -> {unseen:.4g} (camera only)")
    assert end < 0.99 * start
    assert left < 1e-3
    assert unseen > seen      # the vibrometer's own data, fitted by the whole window's loads only


def test_a_refit_run_is_not_diagnosed_again_and_the_line_says_which_run_to_diagnose(effect):
    """`vfcli diagnose --run fit+asymmetry` said the refit's displacements differ from its model rebuilt from the store
    ("/mesh ... changed since the run") and advised `vfcli optimize --run fit+asymmetry`, a name optimize refuses."""
    store, _, _, _ = effect
    before = {p.name: p.stat().st_mtime_ns for p in [store, *sorted(store.parent.glob("rec.h5.parts/*"))]}
    res = run_vfcli("diagnose", store, "--run", "fit+asymmetry")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    line = res.stderr.strip().splitlines()[-1]
    assert "is diagnose's refit of run 'fit' with asymmetry" in line and "diagnose run 'fit'" in line, line
    assert {p.name: p.stat().st_mtime_ns for p in [store, *sorted(store.parent.glob("rec.h5.parts/*"))]} == before


def test_the_report_says_what_a_refit_run_states(effect, tmp_path):
    """The report said "Run fit+asymmetry states no uncertainty (optimize.uncertainty = false)": a refit states its
    parameter's interval (optimize.uncertainty was on)."""
    store, _, _, _ = effect
    res = run_vfcli("report", store, "--out", tmp_path / "r.html")
    assert res.returncode == 0, res.stderr
    page = (tmp_path / "r.html").read_text()
    assert "Run fit+asymmetry states no uncertainty" not in page
    assert ("Run fit+asymmetry is the diagnosis' refit of run fit with asymmetry: it states the uncertainty of "
            "its parameter, left_softening = ") in page
