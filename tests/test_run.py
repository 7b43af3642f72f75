"""`vfcli run` on a small phantom, as a user runs it (real CLI, real files): to the end (diagnose
included), a second run that does nothing, a changed raw file that reruns exactly the stages that
depend on it, a dry run that writes nothing and names its reasons, --until; the diagnose step
skipped with its reason when the recording holds too few whole cycles; finding the raw files."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, VFCLI, run_vfcli, sigint_default
from vfcli.errors import ConfigError, InputDataError
from vfcli.io.ldv.read import read_ldv
from vfcli.io.ldv.write import write_ldv_uff
from vfcli.io.raw_folder import FILES_MANIFEST, find_raw_files
from vfcli.diagnose.calibrate_run import uncalibrated_reason
from vfcli.stages.run import STEPS, run_recording
from vfcli.store import Store

#: f0 250 Hz: 20 ms hold 5 glottal cycles, enough for the diagnose step
PHANTOM = [
    "synth.f0_hz=250", "synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
    "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1",
]
#: a small fit: a coarse mesh (3 mm edges: diagnose's complete modal expansion, a dense eigenproblem
#: of each fold, took 8 s of its 16 s at 2.5 mm and 2 s at 3 mm), 12 frames, 3 iterations
SETS = ["mesh.target_edge_mm=3.0", "optimize.n_frames=12", "optimize.first_frame=20", "optimize.max_iterations=3"]
RAW_FILES = ["video.cihx", "video.mraw", "video.tif", "video_pressure.tdms", "video_pressure.csv", "scan.uff",
             "scan.csv", "recording.toml"]


def _sets(items):
    return sum((["--set", s] for s in items), [])


def _run(store, raw, *args):
    res = run_vfcli("run", store, "--raw", raw, *_sets(SETS), "--json", *args)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    return {s["name"]: s for s in out["stages"]}, out


def _copy_store(src: Path, dst: Path) -> None:
    """A copy of the store under the same file name, with the folder of part files beside it when
    the store has one (``<name>.parts/``, whose links are relative to the store's folder)."""
    assert src.name == dst.name
    shutil.copy(src, dst)
    parts = src.with_name(src.name + ".parts")
    if parts.is_dir():
        shutil.copytree(parts, dst.with_name(dst.name + ".parts"))


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _digests(store: Path) -> dict[str, str]:
    with Store(store).read() as r:
        return {p: r.digest(p[1:].partition("/")[0], p[1:].partition("/")[2] or None) for p in r.stage_paths()}


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    """The raw files of a small phantom (without its truth.h5) and a store `vfcli run` made from them."""
    d = tmp_path_factory.mktemp("run")
    res = run_vfcli("synth", d / "synth", "--seed", "7", *_sets(PHANTOM))
    assert res.returncode == 0, res.stderr
    raw = d / "raw"
    raw.mkdir()
    for name in RAW_FILES:
        shutil.copy(d / "synth" / name, raw / name)
    store = d / "rec.h5"
    stages, out = _run(store, raw)
    return raw, store, stages, out


def test_run_goes_to_the_end(phantom):
    raw, store, stages, out = phantom
    assert out["ok"] and list(stages) == list(STEPS)
    assert {n: s["action"] for n, s in stages.items()} == {n: "ran" for n in STEPS}
    assert all("missing" in s["reason"] for s in stages.values())
    assert any("dropout" in w for w in stages["ingest-ldv"]["warnings"])  # the phantom's dropouts, as logged
    with Store(store).read() as r:
        paths = sorted(r.stage_paths())
        refits = [p for p in paths if p.startswith("/optimize/default+")]
        assert [p for p in paths if p not in refits] == ["/diagnose/default", "/fields", "/flow", "/hsc", "/ldv",
                                                         "/mesh", "/optimize/default", "/sync"]
        # a lead's confirmation refit is kept as its own run, named after the candidate the diagnosis refitted
        refitted = r.attrs("diagnose", "default").get("refit_candidate")
        assert refits == ([f"/optimize/default+{refitted}"] if refitted else [])
        assert r.attrs("mesh")["youngs_modulus_pa"] > 0 and r.read("optimize", "controls", "default").size > 0
        assert r.attrs("diagnose", "default")["n_cycles"] >= 3
        assert r.attrs("hsc")["px_per_mm"] == 9.0  # from the raw folder's recording.toml


def test_a_second_run_does_nothing(phantom):
    raw, store, _, _ = phantom
    before = _sha(store)
    stages, out = _run(store, raw)
    assert {n: s["action"] for n, s in stages.items()} == {n: "up to date" for n in STEPS}
    assert _sha(store) == before


def test_a_changed_raw_file_reruns_exactly_what_depends_on_it(phantom, tmp_path):
    raw0, store0, _, _ = phantom
    # the recording moved (another folder, same bytes): nothing to do
    raw, store = tmp_path / "raw", tmp_path / "rec.h5"
    shutil.copytree(raw0, raw)
    _copy_store(store0, store)
    stages, _ = _run(store, raw, "--dry-run")
    assert {n: s["action"] for n, s in stages.items()} == {n: "up to date" for n in STEPS}
    # new bytes in the scan: /ldv and everything that uses it, not /hsc, /flow (video only) or /mesh
    scan = read_ldv(raw / "scan.uff")
    write_ldv_uff(raw / "scan.uff", replace(scan, velocity_mm_s=scan.velocity_mm_s * 1.01))
    before, digests = _sha(store), _digests(store)
    dry, _ = _run(store, raw, "--dry-run")
    assert _sha(store) == before  # a dry run writes nothing
    assert {n: s["action"] for n, s in dry.items()} == {
        "ingest-hsc": "up to date", "ingest-ldv": "would run", "sync": "would run", "flow": "would run",
        "mesh": "up to date", "optimize": "would run", "diagnose": "would run"}
    assert dry["ingest-ldv"]["reason"] == "input changed: scan.uff"
    assert dry["diagnose"]["reason"].startswith("/optimize/default is rewritten first")
    assert "/ldv is rewritten first" in dry["sync"]["reason"] and "/ldv is rewritten first" in dry["flow"]["reason"]
    assert "/fields is rewritten first" in dry["optimize"]["reason"]
    ran, _ = _run(store, raw)
    assert {n: s["action"] for n, s in ran.items()} == {
        "ingest-hsc": "up to date", "ingest-ldv": "ran", "sync": "ran", "flow": "ran", "mesh": "up to date",
        "optimize": "ran", "diagnose": "ran"}
    after = _digests(store)
    unchanged = {p for p in digests if digests[p] == after[p]}
    # a lead's refit that the first diagnosis made and this one did not make again (its screening raised no such
    # lead on the new data) stays as it was, and the store says it is stale: its baseline was rewritten
    old_refits = {p for p in unchanged if p.startswith("/optimize/default+")}
    assert unchanged - old_refits == {"/hsc", "/flow", "/mesh"}  # flow's /fields was rewritten, its /flow not
    with Store(store).read() as r:
        for p in old_refits:
            assert any("/optimize/default was rewritten" in why for why in r.status(p).stale_because), p


def test_a_value_set_with_vfcli_config_is_kept_by_the_next_run_of_the_raw_folder(phantom, tmp_path):
    """`vfcli config --set` (what ingest-hsc's px_per_mm warning advises), then `vfcli run --raw`: the raw folder's
    recording.toml, the file the stored config was read from, must not replace it (it did, silently: the value
    was undone and the dry run said "up to date"). A recording.toml changed since replaces it, and says so."""
    raw0, store0, _, _ = phantom
    raw, store = tmp_path / "raw", tmp_path / "rec.h5"
    shutil.copytree(raw0, raw)
    _copy_store(store0, store)
    res = run_vfcli("config", store, "--set", "sync.n_harmonics=8")
    assert res.returncode == 0, res.stderr
    dry, _ = _run(store, raw, "--dry-run")
    assert dry["sync"]["action"] == "would run" and "sync.n_harmonics 10 -> 8" in dry["sync"]["reason"], dry["sync"]
    assert dry["ingest-hsc"]["action"] == "up to date"
    ran, _ = _run(store, raw, "--until", "sync")
    assert ran["sync"]["action"] == "ran"

    def stored_n_harmonics() -> int:
        with Store(store).read() as r:
            return json.loads(r.recording_config_json())["sync"]["n_harmonics"]

    assert stored_n_harmonics() == 8
    info = json.loads(run_vfcli("info", "--json", store).stdout)
    assert {st["path"]: st["stale"] for st in info["stages"]}["/sync"] is False
    # the lab edits recording.toml: it is the newer word, and the run says it replaces the stored config
    toml = raw / "recording.toml"
    toml.write_text(toml.read_text() + "\n[sync]\nn_harmonics = 6\n")
    res = run_vfcli("run", store, "--raw", raw, *_sets(SETS), "--json", "--until", "sync")
    assert res.returncode == 0, res.stderr
    assert f"{toml} differs from the config file last stored with {store}: it replaces the stored" in res.stderr
    assert {s["name"]: s["action"] for s in json.loads(res.stdout)["stages"]}["sync"] == "ran"
    assert stored_n_harmonics() == 6
    # and is read from then on as the stored config's file: a second run has nothing to do or say
    res = run_vfcli("run", store, "--raw", raw, *_sets(SETS), "--json", "--until", "sync")
    assert res.returncode == 0 and "differs" not in res.stderr, res.stderr
    assert {s["name"]: s["action"] for s in json.loads(res.stdout)["stages"]}["sync"] == "up to date"


def test_info_calls_the_default_fit_stale_when_its_optimize_settings_change_as_run_does(phantom, tmp_path):
    """`vfcli config --set optimize.max_iterations=4`: `vfcli run --dry-run` said the default fit would rerun (config
    changed), `vfcli info` and the report called it ok (they compared no settings of an optimisation run)."""
    raw0, store0, _, _ = phantom
    store = tmp_path / "rec.h5"
    _copy_store(store0, store)

    def optimize_status() -> dict:
        info = json.loads(run_vfcli("info", "--json", store).stdout)
        return {st["path"]: st for st in info["stages"]}["/optimize/default"]

    # the fixture ran with --set values (not stored): stored, the fit is what the config makes
    res = run_vfcli("config", store, *_sets(SETS))
    assert res.returncode == 0, res.stderr
    assert optimize_status()["stale"] is False, optimize_status()
    res = run_vfcli("config", store, "--set", "optimize.max_iterations=4")
    assert res.returncode == 0, res.stderr
    st = optimize_status()
    assert st["stale"] is True and "optimize.max_iterations 3 -> 4" in json.dumps(st), st
    res = run_vfcli("run", store, "--raw", raw0, "--dry-run", "--json")      # the stored config alone
    assert res.returncode == 0, res.stderr
    dry = {s["name"]: s for s in json.loads(res.stdout)["stages"]}
    assert dry["optimize"]["action"] == "would run" and "optimize.max_iterations 3 -> 4" in dry["optimize"]["reason"]
    assert {dry[k]["action"] for k in ("sync", "flow", "mesh")} == {"up to date"}, dry


def test_a_run_that_fails_says_what_it_ran_before(phantom, tmp_path):
    """A step that fails (a scan cut short) stops the run with its one error line and exit code; the steps
    before it are committed, and the output said nothing of them (--json printed nothing at all)."""
    raw0, _, _, _ = phantom
    raw = tmp_path / "raw"
    shutil.copytree(raw0, raw)
    scan = (raw / "scan.uff").read_bytes()
    (raw / "scan.uff").write_bytes(scan[: len(scan) // 2])
    res = run_vfcli("run", tmp_path / "a.h5", "--raw", raw, *_sets(SETS), "--json")
    assert res.returncode == 3 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    out = json.loads(res.stdout)
    assert out["ok"] is False
    assert [(s["name"], s["action"]) for s in out["stages"]] == [("ingest-hsc", "ran"), ("ingest-ldv", "failed")]
    assert out["stages"][1]["reason"] in res.stderr
    res = run_vfcli("run", tmp_path / "b.h5", "--raw", raw, *_sets(SETS))
    assert res.returncode == 3 and res.stdout.startswith("ingest-hsc: ran (") and "ingest-ldv" not in res.stdout
    with Store(tmp_path / "b.h5").read() as r:
        assert r.stage_paths() == ["/hsc"]


def test_a_changed_config_reruns_from_the_stage_it_shapes(phantom, tmp_path):
    raw, store0, _, _ = phantom
    store = tmp_path / "rec.h5"
    _copy_store(store0, store)
    stages, _ = _run(store, raw, "--dry-run", "--set", "sync.n_harmonics=4")
    assert [n for n, s in stages.items() if s["action"] == "would run"] == ["sync", "flow", "optimize", "diagnose"]
    assert stages["sync"]["reason"].startswith("/sync: config changed") and "n_harmonics" in stages["sync"]["reason"]


#: a child that runs vfcli with a SIGINT raised inside h5py's attribute iteration, where h5py calls back into Python
#: (the first time a group's attributes are read): the signal is then handled inside compiled code
_SIGINT_IN_H5PY = """
import signal, sys
from h5py import h5a
from h5py._hl import attrs

original = attrs.AttributeManager.__iter__

def interrupted_once(self):
    def callback(name, *args):
        attrs.AttributeManager.__iter__ = original
        signal.raise_signal(signal.SIGINT)
    h5a.iterate(self._id, callback)
    yield from original(self)

attrs.AttributeManager.__iter__ = interrupted_once
from vfcli.cli.main import main
sys.argv = ["vfcli", *sys.argv[1:]]
main()
"""


@pytest.mark.parametrize("command", ["run", "info"])
def test_a_ctrl_c_that_h5py_wraps_in_another_error_is_still_an_interruption(phantom, tmp_path, command):
    """Ctrl-C while h5py iterates a group's attributes (a Cython loop calling back into Python) comes out as
    ``SystemError: <cyfunction FastRLock.__exit__> returned a result with an exception set`` with the
    KeyboardInterrupt as its cause: `vfcli run` exited 1 with a traceback (a bug's exit) instead of 130
    (test_ctrl_c_during_a_run_lists_the_steps_it_committed, one run in many). Here a real SIGINT is raised inside that
    callback: exit 130, the one line, no traceback, the store as it was."""
    _, store0, _, _ = phantom
    store = tmp_path / "rec.h5"
    _copy_store(store0, store)
    with Store(store).read() as r:
        before = {st.path: st.provenance.get("digest") for st in r.statuses()}
    args = ["run", str(store), "--force", *_sets(SETS)] if command == "run" else ["info", str(store)]
    res = subprocess.run([sys.executable, "-c", _SIGINT_IN_H5PY, *args], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, preexec_fn=sigint_default, timeout=300)
    assert res.returncode == 130, res.stderr
    assert res.stderr.strip().splitlines()[-1] == f"vfcli {command}: interrupted (Ctrl-C)", res.stderr
    assert "Traceback" not in res.stderr
    with Store(store).read() as r:
        assert {st.path: st.provenance.get("digest") for st in r.statuses()} == before


def test_ctrl_c_during_a_run_lists_the_steps_it_committed(phantom, tmp_path):
    """Ctrl-C in flow printed only "interrupted (Ctrl-C)", where a failed run lists the steps it committed first:
    SIGINT once flow's part file appears; the steps before it are listed as run, exit 130.

    flow's part file stays once flow has committed, so a test process starved of CPU can see it only then and
    interrupt a later step (mesh's tetgen ends at once, exit -2: session 40 saw one such failure in a loaded run).
    Such a try, told by /flow committed in the store, says nothing of Ctrl-C in flow and is made again."""
    raw, _, _, _ = phantom
    for attempt in range(3):
        store = tmp_path / f"rec{attempt}.h5"
        proc = subprocess.Popen([*VFCLI, "run", str(store), "--raw", str(raw), *_sets(SETS)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)},
                                preexec_fn=sigint_default)
        parts = store.parent / (store.name + ".parts")
        deadline = time.monotonic() + 300
        while not (parts.is_dir() and any(p.name.startswith("flow-") for p in parts.iterdir())):
            assert proc.poll() is None and time.monotonic() < deadline, "flow never started"
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
        with Store(store).read() as r:
            if not r.has_stage("flow"):
                break
    else:
        pytest.fail("flow had committed before the SIGINT in 3 tries: Ctrl-C in flow was never tested")
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "vfcli run: interrupted (Ctrl-C)" and "Traceback" not in err
    lines = {line.split(":")[0]: line for line in out.splitlines() if ":" in line}
    assert all(lines[s].startswith(f"{s}: ran") for s in ("ingest-hsc", "ingest-ldv", "sync")), out
    assert "flow" not in lines, out            # the interrupted step: its line is stderr's "interrupted (Ctrl-C)"
    with Store(store).read() as r:
        assert r.has_stage("sync") and not r.has_stage("flow")


def test_until_stops_and_the_library_entry_point(phantom, tmp_path):
    raw, _, _, _ = phantom
    store = tmp_path / "rec.h5"
    summary = run_recording(store, raw, until="ingest-ldv", overrides={"camera.px_per_mm": 9.5})
    assert summary.ok and [s.action for s in summary.stages] == ["ran", "ran"] + ["skipped"] * 5
    assert summary.stages[2].reason == "after --until ingest-ldv"
    payload = summary.to_json()
    assert json.loads(json.dumps(payload)) == payload and payload["store"] == str(store)
    with Store(store).read() as r:
        assert sorted(r.stage_paths()) == ["/hsc", "/ldv"] and r.attrs("hsc")["px_per_mm"] == 9.5
    res = run_vfcli("run", store, "--raw", raw, "--until", "nope")
    assert res.returncode == 2 and "nope" in res.stderr
    # --quiet: nothing but errors, although ingest-ldv warns about the phantom's dropouts
    res = run_vfcli("run", tmp_path / "quiet.h5", "--raw", raw, "--until", "ingest-ldv", "-q")
    assert res.returncode == 0 and res.stdout == "" and res.stderr == "", (res.stdout, res.stderr)
    with Store(tmp_path / "quiet.h5").read() as r:
        assert any("dropout" in w for w in r.summary("ldv")["warnings"])  # stored all the same


def test_the_run_skips_diagnose_by_diagnoses_own_rule_on_a_known_area():
    """`vfcli run` skipped diagnose with fewer than 3 whole cycles outside the window, where `vfcli diagnose` alone
    measured its floor and calibrated its decision (a 0.04 s phantom, window 120-159).  The gate is now diagnose's
    own checks: 2 whole cycles for the noise floor, 3 stretches of the window's length at whole cycles from it."""
    # 1 - cos: rises through half its range at frames 10, 50, 90, 130, 170: whole cycles 10-49, ..., 130-169;
    # the phase runs from -0.25 (frame 0) to 4.725 (frame 199)
    area = 1 - np.cos(2 * np.pi * np.arange(200) / 40)
    assert uncalibrated_reason(area, 1e-4, None, 20, 12) is None          # shifts +1 .. +4
    # across a cycle's end: 2 of the 4 whole cycles touched (the old gate skipped), shifts -1, +1, +2, +3
    assert uncalibrated_reason(area, 1e-4, None, 45, 10) is None
    assert uncalibrated_reason(area, 1e-4, None, 0, 84) == (
        "2 stretch(es) of the window's length at whole cycles from it inside the recording: the calibration needs "
        "at least 3")                                                    # +1, +2 only
    assert "no whole glottal cycle" in uncalibrated_reason(area[:45], 1e-4, None, 0, 12)
    assert uncalibrated_reason(np.ones(50), 1e-4, None, 0, 12) == "the glottal area is flat: no glottal cycle"


def test_diagnose_is_skipped_with_its_reason_when_the_window_leaves_too_few_cycles(phantom, tmp_path):
    raw, store0, _, _ = phantom
    store = tmp_path / "rec.h5"
    _copy_store(store0, store)
    before = _sha(store)
    stages, _ = _run(store, raw, "--dry-run", "--set", "optimize.n_frames=150")
    assert stages["optimize"]["action"] == "would run" and stages["diagnose"]["action"] == "skipped"
    reason = stages["diagnose"]["reason"]
    assert reason.startswith("its decision on the fitted window (frames 20-169) could not be calibrated: ") and \
        "the calibration needs at least 3" in reason, reason
    assert "record longer" in reason and "or fit one glottal cycle (the window holds " in reason
    # with flow to rerun too, the skip is judged on the /flow there (the dry run said "would run", the run skipped)
    stages, _ = _run(store, raw, "--dry-run", "--set", "optimize.n_frames=150", "--set", "flow.median_px=3")
    assert stages["flow"]["action"] == "would run" and stages["diagnose"]["action"] == "skipped"
    judged = " (judged on the /flow stored now, which this run would rewrite first)"
    assert stages["diagnose"]["reason"] == reason + judged
    # --until optimize leaves it out, saying so
    stages, _ = _run(store, raw, "--dry-run", "--until", "optimize")
    assert (stages["diagnose"]["action"], stages["diagnose"]["reason"]) == ("skipped", "after --until optimize")
    assert _sha(store) == before


def test_the_raw_files_are_found_by_extension_or_named_in_a_manifest(phantom, tmp_path):
    raw, _, _, _ = phantom
    found = find_raw_files(raw)
    assert (found.video.name, found.pressure.name, found.ldv.name, found.config.name) == (
        "video.cihx", "video_pressure.tdms", "scan.uff", "recording.toml")  # the instrument's format first
    d = tmp_path / "lab"
    shutil.copytree(raw, d)
    shutil.copy(d / "video.tif", d / "take2.tif")
    with pytest.raises(ConfigError, match="more than one video .*take2.tif.*" + FILES_MANIFEST):
        find_raw_files(d)
    res = run_vfcli("run", tmp_path / "x.h5", "--raw", d)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "take2.tif" in res.stderr
    assert not (tmp_path / "x.h5").exists()
    (d / FILES_MANIFEST).write_text('video = "take2.tif"\npressure = "video_pressure.csv"\n')
    found = find_raw_files(d)
    assert (found.video.name, found.pressure.name, found.ldv.name) == ("take2.tif", "video_pressure.csv", "scan.uff")
    (d / "scan.uff").unlink()
    with pytest.raises(InputDataError, match="no vibrometer scan"):
        find_raw_files(d)
    res = run_vfcli("run", tmp_path / "x.h5", "--raw", d)
    assert res.returncode == 3 and len(res.stderr.strip().splitlines()) == 1 and "vibrometer scan" in res.stderr
    (d / FILES_MANIFEST).write_text('vidoe = "take2.tif"\n')
    with pytest.raises(ConfigError, match="unknown key 'vidoe' \\(did you mean 'video'\\?\\)"):
        find_raw_files(d)
    (d / FILES_MANIFEST).write_text('video = "nothere.avi"\n')
    with pytest.raises(InputDataError, match="nothere.avi"):
        find_raw_files(d)


def test_a_folder_of_images_named_in_the_manifest_is_the_runs_video(phantom, tmp_path):
    """`vfcli run` could not take the folder of numbered images `vfcli ingest-hsc` reads (a camera's TIFF export):
    the manifest named only files.  Now `video = "frames"` is that folder; /hsc holds the video's frames as from
    the .cihx, and a changed image makes ingest-hsc rerun, naming the image."""
    import tifffile

    raw, store0, _, _ = phantom
    d = tmp_path / "lab"
    d.mkdir()
    for name in ("video_pressure.tdms", "scan.uff", "recording.toml"):
        shutil.copy(raw / name, d / name)
    frames = tifffile.imread(raw / "video.tif")
    (d / "frames").mkdir()
    for i, img in enumerate(frames):                       # one file per frame, as a camera's export writes them
        tifffile.imwrite(d / "frames" / f"img_{i:05d}.tif", img)
    (d / FILES_MANIFEST).write_text('video = "frames"\n')
    with Store(store0).read() as r:
        fps = r.attrs("hsc")["fps_hz"]
    store = tmp_path / "rec.h5"
    stages, _ = _run(store, d, "--until", "ingest-hsc", "--set", f"camera.fps_hz={fps}")
    assert stages["ingest-hsc"]["action"] == "ran"
    with Store(store).read() as r, Store(store0).read() as r0:
        np.testing.assert_array_equal(r.read("hsc", "frames"), r0.read("hsc", "frames"))
    stages, _ = _run(store, d, "--until", "ingest-hsc", "--set", f"camera.fps_hz={fps}", "--dry-run")
    assert stages["ingest-hsc"]["action"] == "up to date", stages["ingest-hsc"]
    tifffile.imwrite(d / "frames" / "img_00003.tif", frames[3] // 2)
    stages, _ = _run(store, d, "--until", "ingest-hsc", "--set", f"camera.fps_hz={fps}", "--dry-run")
    assert stages["ingest-hsc"]["action"] == "would run" and "input changed: img_00003.tif" in stages["ingest-hsc"]["reason"]
    (d / FILES_MANIFEST).write_text('video = "nothere"\n')
    with pytest.raises(InputDataError, match="'nothere', which is not a file or a folder of images"):
        find_raw_files(d)


def test_without_raw_the_ingest_steps_are_skipped_and_a_missing_stage_is_named(tmp_path):
    res = run_vfcli("run", tmp_path / "none.h5")
    assert res.returncode == 5 and len(res.stderr.strip().splitlines()) == 1 and "/hsc" in res.stderr, res.stderr
    dry = run_vfcli("run", tmp_path / "none.h5", "--dry-run", "--json")
    stages = {s["name"]: s for s in json.loads(dry.stdout)["stages"]}
    assert stages["ingest-hsc"]["action"] == "skipped" and stages["mesh"]["action"] == "would run"
    # the dry run said "would run" for the step the run then stopped at (exit 5)
    assert (stages["sync"]["action"], stages["sync"]["reason"]) == ("would fail", "/hsc missing (no raw folder given: --raw)")
    assert not (tmp_path / "none.h5").exists()


def _modules_imported(*args) -> tuple[subprocess.CompletedProcess, set[str]]:
    """Every module a `vfcli ARGS` run imports (`python -X importtime`)."""
    res = subprocess.run([sys.executable, "-X", "importtime", *VFCLI[1:], *map(str, args)], capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)
    return res, {line.split("|")[-1].strip() for line in res.stderr.splitlines() if line.startswith("import time:")}


def test_run_exports_and_reports_and_figures_redraw_without_refitting(phantom, tmp_path):
    raw, store0, _, _ = phantom
    store = tmp_path / "rec.h5"
    _copy_store(store0, store)
    before = _sha(store)
    outs = ["--export", tmp_path / "export", "--report", tmp_path / "report.html"]
    _, out = _run(store, raw, *outs)
    assert [(o["name"], o["action"]) for o in out["outputs"]] == [("export", "ran"), ("report", "ran")]
    assert all(o["seconds"] > 0 for o in out["outputs"])      # their time, as every stage's
    assert (tmp_path / "export/figures/fig7_convergence.png").stat().st_size > 1000
    assert (tmp_path / "report.html").read_text().startswith("<!DOCTYPE html>")
    _, out = _run(store, raw, *outs)
    assert [(o["name"], o["action"]) for o in out["outputs"]] == [("export", "up to date"), ("report", "up to date")]
    # the figures again, for another screen point: drawn from the stored fit, no optimiser loaded, store unchanged
    res, modules = _modules_imported("export", store, "--to", tmp_path / "redrawn", "--what", "figures",
                                     "--point", "80,70")
    assert res.returncode == 0, res.stderr
    assert "vfcli.stages.export_job" in modules and "vfcli.inverse.optimizers.base" not in modules
    assert not any(m.startswith(("vfcli.inverse.setup", "vfcli.stages.optimize")) for m in modules)
    drawn = sorted(p.name for p in (tmp_path / "redrawn/figures").iterdir())
    assert "fig7_convergence.png" in drawn and "fig8_velocities.png" in drawn
    assert (tmp_path / "redrawn/figures/fig8_velocities.png").read_bytes() != (
        tmp_path / "export/figures/fig8_velocities.png").read_bytes()  # redrawn for the new point
    assert _sha(store) == before
