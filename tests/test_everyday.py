"""Everyday use (issue 18): a lean install whose dependencies match the imports, a light
`vfcli --help`, --quiet, `config --set` that persists, nearest-key suggestions, a loud
default calibration, `schemas` that writes only what it is asked, Ctrl-C as exit 130.
Real subprocesses wherever the claim is about the command line."""
from __future__ import annotations

import ast
import functools
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, VFCLI, run_vfcli, sigint_default
from vfcli.store.transaction import Store

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


# --- a lean install: every hard dependency used, every import declared ------------------

def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _req_name(req: str) -> str:
    return _norm(re.match(r"[A-Za-z0-9._-]+", req).group(0))


def _imports(folder: Path, top_level_only: bool = False) -> dict[str, set[str]]:
    """Top-level third-party module -> files importing it (relative imports and stdlib skipped)."""
    local = {p.stem for p in folder.glob("*.py")} | {"vfcli", "tests", "bench"}
    found: dict[str, set[str]] = {}
    for path in folder.rglob("*.py"):
        tree = ast.parse(path.read_text())
        nodes = tree.body if top_level_only else ast.walk(tree)
        for node in nodes:
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local:
                    found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


@functools.lru_cache(maxsize=None)
def _module_owners() -> dict[str, list[str]]:
    """importlib.metadata's module -> distributions map, read once: each call scans every installed
    distribution's files (0.3-0.4 s here, beside a running suite; these tests asked it once per imported module)."""
    return metadata.packages_distributions()


def _distributions(module: str) -> set[str]:
    """The distributions that install ``module`` (not installed here: the one named like it)."""
    return {_norm(d) for d in _module_owners().get(module, [module])}


def _closure(names: set[str] | frozenset[str]) -> set[str]:
    """The distributions ``names`` install, with their own (non-extra) requirements."""
    return set(_closure_of(frozenset(names)))


@functools.lru_cache(maxsize=None)
def _closure_of(names: frozenset[str]) -> frozenset[str]:
    from packaging.requirements import Requirement

    todo, seen = list(names), set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        for text in requires:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(_norm(req.name))
    return frozenset(seen)


HARD = {_req_name(r) for r in PYPROJECT["project"]["dependencies"]}
EXTRAS = {k: {_req_name(r) for r in v} for k, v in PYPROJECT["project"]["optional-dependencies"].items()}


def test_every_hard_dependency_is_imported_by_vfcli():
    used = set().union(*(_distributions(m) for m in _imports(ROOT / "vfcli")))
    unused = sorted(HARD - used)
    assert not unused, f"hard dependencies vfcli never imports (make them an extra or a test dependency): {unused}"


def test_vfcli_imports_only_declared_libraries_and_optional_ones_lazily():
    declared = HARD | set().union(*EXTRAS.values())
    for module, files in _imports(ROOT / "vfcli").items():
        dists = _distributions(module)
        assert dists & _closure(declared), f"{module} (imported by {sorted(files)}) is not a declared dependency"
    optional = set().union(*EXTRAS.values()) - _closure(HARD)
    for module, files in _imports(ROOT / "vfcli", top_level_only=True).items():
        assert not _distributions(module) & optional, f"{sorted(files)} import optional {module} at module level"


def test_the_test_extra_installs_everything_the_tests_import():
    installed = _closure(HARD | EXTRAS["test"])
    for module, files in _imports(ROOT / "tests").items():
        dists = _distributions(module)
        assert dists & installed, f"{module} (imported by {sorted(files)}) is not installed by `pip install .[test]`"


def test_license_and_citation_match_the_package():
    from vfcli import __version__

    assert (ROOT / "LICENSE").read_text().startswith("MIT License") and PYPROJECT["project"]["license"] == "MIT"
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r"^version: \"?([^\"\n]+)\"?$", cff, re.M).group(1) == __version__ == PYPROJECT["project"]["version"]
    assert re.search(r"^license: MIT$", cff, re.M)
    assert "Vocal Fold Reconstruction from Optical Velocity and Displacement Measurements" in cff  # the method's paper


def test_mesh_preview_without_pyvista_says_so_and_draws_with_matplotlib(tmp_path, monkeypatch, caplog):
    from vfcli.model.m5 import M5Params
    from vfcli.model.mesh import build_mesh
    from vfcli.model.preview import render_mesh_png

    monkeypatch.setitem(sys.modules, "pyvista", None)  # as in an install without the `viz` extra
    with caplog.at_level(logging.WARNING):
        used = render_mesh_png(build_mesh(M5Params(), target_edge_mm=2.5), tmp_path / "m.png")
    assert used == "matplotlib" and (tmp_path / "m.png").stat().st_size > 10_000
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "pyvista is not installed" in lines[0] and "vfcli[viz]" in lines[0]


# --- a light `vfcli --help` ------------------------------------------------------------

def test_help_imports_no_heavy_module():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-X", "importtime", *VFCLI[1:], "--help"], capture_output=True, text=True,
                         env=env, timeout=120)
    assert res.returncode == 0 and "Commands:" in res.stdout
    imported = {line.split("|")[-1].strip().split(".")[0] for line in res.stderr.splitlines() if "|" in line}
    assert "click" in imported  # the import log was read
    heavy = imported & {"numpy", "scipy", "h5py", "cv2", "matplotlib", "pydantic", "tqdm", "skfem", "tetgen"}
    assert not heavy, f"`vfcli --help` imports {sorted(heavy)}"


def test_every_listed_command_loads_under_its_name():
    import click

    from vfcli.cli.main import COMMANDS, cli

    ctx = click.Context(cli)
    for name in COMMANDS:
        assert cli.get_command(ctx, name).name == name


# --- --quiet, config --set, suggestions, the default calibration ---------------------------

@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 20-frame 8-bit TIFF stack (no frame rate in the file: camera.fps_hz must be set)."""
    import tifffile

    path = tmp_path_factory.mktemp("raw") / "video.tif"
    rng = np.random.default_rng(0)
    tifffile.imwrite(path, rng.integers(0, 255, (20, 24, 32), dtype=np.uint8))
    return path


def _stored_config(path: Path) -> dict:
    with Store(path).read() as r:
        return json.loads(r.recording_config_json())


def test_ingest_warns_loudly_when_px_per_mm_is_left_at_its_default(tmp_path, video):
    res = run_vfcli("ingest-hsc", tmp_path / "a.h5", video, "--set", "camera.fps_hz=1000")
    assert res.returncode == 0, res.stderr
    warning = [line for line in res.stderr.splitlines() if "camera.px_per_mm" in line]
    assert len(warning) == 1 and "WARNING" in warning[0] and "20 px/mm" in warning[0]
    assert f"vfcli config {tmp_path / 'a.h5'} --set camera.px_per_mm=" in warning[0]
    res = run_vfcli("ingest-hsc", tmp_path / "b.h5", video, "--set", "camera.fps_hz=1000", "--set", "camera.px_per_mm=12")
    assert res.returncode == 0 and "px_per_mm" not in res.stderr, res.stderr


def test_a_stage_written_before_a_setting_existed_stays_current(tmp_path, video):
    """A store written by a vfcli without a setting that a newer one has (session 38: ingest_hsc.pressure_unit,
    null) was STALE in every stage ("config changed: " with nothing after it) and `vfcli run` redid ingest, sync
    and flow (8.5 min on a 0.5 s recording) for a setting whose default does what the old vfcli did. A setting
    since removed from vfcli counts as gone. A real change is still named."""
    import h5py

    store = tmp_path / "r.h5"
    assert run_vfcli("config", store, "--set", "camera.fps_hz=1000", "--set", "camera.px_per_mm=12").returncode == 0
    args = ["ingest-hsc", store, video]
    assert run_vfcli(*args, "-q").returncode == 0
    with Store(store).read() as r:
        part, digest = r.dataset("hsc", "frames").file.filename, r.digest("hsc")
    with h5py.File(part, "r+") as f:                    # as an older vfcli recorded it
        g = f["hsc"]
        had = json.loads(g.attrs["config_json"])
        del had["ingest_hsc"]["pressure_unit"]
        had["ingest_hsc"]["a_setting_since_removed"] = 3
        g.attrs["config_json"] = json.dumps(had, sort_keys=True)
    info = json.loads(run_vfcli("info", "--json", store).stdout)
    assert {st["path"]: st["stale"] for st in info["stages"]} == {"/hsc": False}, info["stages"]
    res = run_vfcli(*args)
    assert res.returncode == 0 and "up to date" in res.stdout + res.stderr, res.stdout + res.stderr
    with Store(store).read() as r:
        assert r.digest("hsc") == digest
    res = run_vfcli("config", store, "--set", "ingest_hsc.pressure_unit=kPa")
    assert res.returncode == 0, res.stderr
    info = json.loads(run_vfcli("info", "--json", store).stdout)
    assert "config changed: ingest_hsc.pressure_unit None -> 'kPa'" in json.dumps(info["stages"]), info["stages"]


def test_settings_added_or_removed_since_a_stage_was_written_are_no_change_a_runs_own_key_stays():
    """vfcli.store.reader.settings_change on the settings JSON of stages: a key the record lacks is its default, a
    key since removed is gone, a key the template lacks but the stage records now too (a diagnose refit run's
    "refit" beside the optimize settings) is compared, not dropped (dropped, every refit run was never current)."""
    from vfcli.store.reader import settings_change

    defaults = json.dumps({"optimize": {"a": 1, "new": None}})
    want = {"optimize": {"a": 1, "new": None}, "refit": {"candidate": "inertia"}}
    assert settings_change(json.dumps({"optimize": {"a": 1, "gone": 2}, "refit": {"candidate": "inertia"}}),
                           json.dumps(want), defaults) is None
    assert settings_change(json.dumps({"optimize": {"a": 1}, "refit": {"candidate": "damping"}}), json.dumps(want),
                           defaults) == "refit.candidate 'damping' -> 'inertia'"
    assert settings_change(json.dumps({"optimize": {"a": 2}}), json.dumps({"optimize": {"a": 1, "new": None}}),
                           defaults) == "optimize.a 2 -> 1"


def test_quiet_prints_nothing_but_errors(tmp_path, video):
    store = tmp_path / "q.h5"
    res = run_vfcli("ingest-hsc", store, video, "--set", "camera.fps_hz=1000", "-q")  # would warn: px_per_mm
    assert res.returncode == 0 and res.stdout == "" and res.stderr == "", (res.stdout, res.stderr)
    assert Store(store).exists()
    res = run_vfcli("ingest-hsc", tmp_path / "missing.h5", tmp_path / "nope.tif", "-q")
    assert res.returncode == 2 and res.stdout == "" and "nope.tif" in res.stderr  # errors still print


def test_config_set_persists_into_the_stored_config_and_the_next_stage_uses_it(tmp_path, video):
    store = tmp_path / "r.h5"
    assert run_vfcli("config", store, "--set", "camera.px_per_mm=12").returncode == 0
    assert run_vfcli("config", store, "--set", "camera.fps_hz=1000").returncode == 0
    assert _stored_config(store) == {"camera": {"px_per_mm": 12.0, "fps_hz": 1000.0}}  # only what was set
    shown = json.loads(run_vfcli("config", store, "--show").stdout)
    assert shown["camera"]["px_per_mm"] == 12.0 and shown["flow"]["median_px"] == 5
    res = run_vfcli("ingest-hsc", store, video)
    assert res.returncode == 0 and "px_per_mm" not in res.stderr, res.stderr
    with Store(store).read() as r:
        assert r.attrs("hsc")["px_per_mm"] == 12.0 and r.attrs("hsc")["fps_hz"] == 1000.0
    # --set on a stage command stays for that run only
    res = run_vfcli("ingest-hsc", store, video, "--set", "camera.px_per_mm=30", "--force")
    assert res.returncode == 0 and _stored_config(store)["camera"]["px_per_mm"] == 12.0


@pytest.mark.parametrize("key, message", [
    ("camera.px_per_m", "camera.px_per_m: unknown setting (did you mean camera.px_per_mm?)"),
    ("camra.px_per_mm", "camra: unknown setting (did you mean camera?)"),
    ("flow.median", "flow.median: unknown setting (did you mean flow.median_px?)"),
    ("camera.zzz", "camera.zzz: unknown setting (known: camera.fps_hz, camera.px_per_mm, camera.rotation_deg, "
                   "camera.offset_px, camera.pose)"),
])
def test_an_unknown_key_suggests_the_nearest_one(tmp_path, key, message):
    store = tmp_path / "r.h5"
    assert run_vfcli("config", store, "--set", "camera.px_per_mm=12").returncode == 0
    before = store.read_bytes()
    res = run_vfcli("config", store, "--set", f"{key}=3")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert f"--set: invalid config: {message}" in res.stderr
    section, _, name = key.rpartition(".")
    (tmp_path / "r.toml").write_text(f"[{section}]\n{name} = 3\n")
    res = run_vfcli("config", store, "--config", tmp_path / "r.toml")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert f"r.toml: invalid config: {message}" in res.stderr
    assert store.read_bytes() == before


def test_schemas_writes_only_the_schemas_unless_asked(tmp_path):
    res = run_vfcli("schemas", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert written == sorted(f"schemas/{p.name}" for p in (ROOT / "schemas").glob("*.schema.json"))
    res = run_vfcli("schemas", "--out", "s", "--layout-doc", "d/layout.md", "--example", "e/r.toml", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "d/layout.md").read_text() == (ROOT / "docs/store-layout.md").read_text()
    assert (tmp_path / "e/r.toml").read_text() == (ROOT / "examples/recording.toml").read_text()


# --- Ctrl-C ------------------------------------------------------------------------------

def wait_until_blocked_in_read(pid: int, within_s: float = 20.0) -> None:
    """Return once process ``pid`` sleeps in a pipe's read (``pipe_read`` in its ``/proc/PID/wchan``), or after
    ``within_s`` where the kernel never says so (it shows "0" for a running process, and for every process where
    it hides the symbol).  A SIGINT sent while the command runs the C code between opening the FIFO and reading
    it sets Python's flag, and the read that follows blocks with nobody to look at it (CI, session 69: no output
    in 60 s); a user would press Ctrl-C again, the test must not depend on that microsecond."""
    wchan = Path(f"/proc/{pid}/wchan")
    end = time.monotonic() + within_s
    while time.monotonic() < end:
        try:
            if "pipe_read" in wchan.read_text():
                return
        except OSError:
            return
        time.sleep(0.01)


def test_ctrl_c_exits_130_with_one_line_and_leaves_the_store(tmp_path):
    """SIGINT while the command waits inside its own code (reading --config from a FIFO)."""
    store = tmp_path / "r.h5"
    assert run_vfcli("config", store, "--set", "camera.px_per_mm=12").returncode == 0
    before = store.read_bytes()
    fifo = tmp_path / "recording.toml"
    os.mkfifo(fifo)
    proc = subprocess.Popen([*VFCLI, "config", str(store), "--config", str(fifo)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            preexec_fn=sigint_default)
    deadline = time.monotonic() + 120
    while True:  # opening the FIFO's write end succeeds once the command has opened it to read
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            break
        except OSError:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "vfcli never opened the config"
            time.sleep(0.05)
    try:
        wait_until_blocked_in_read(proc.pid)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        os.close(fd)
    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines() == ["vfcli config: interrupted (Ctrl-C)"] and out == ""
    assert store.read_bytes() == before
