"""The command line as a user meets it: help, exit codes, info on a real store."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from vfcli.store import Store

SUBCOMMANDS = ["ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize", "export",
               "synth", "diagnose", "report", "batch", "info"]


def test_help_lists_every_subcommand(vfcli):
    res = vfcli("--help")
    assert res.returncode == 0
    for name in SUBCOMMANDS:
        assert re.search(rf"^\s+{name}\s", res.stdout, re.M), name
    assert "Exit codes" in res.stdout


@pytest.mark.parametrize("name", ["ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize"])
def test_stage_help_says_what_it_reads_and_writes(vfcli, name):
    res = vfcli(name, "--help")
    assert res.returncode == 0 and "Reads:" in res.stdout and "Writes:" in res.stdout


def test_unbuilt_commands_say_so_and_exit_6(vfcli, tmp_path):
    import click

    from vfcli.cli.main import cli

    ctx = click.Context(cli)
    for name in cli.list_commands(ctx):
        cmd = cli.get_command(ctx, name)
        if "NOT IMPLEMENTED YET" in (cmd.help or ""):
            res = vfcli(name, tmp_path / "r.h5")
            assert res.returncode == 6 and "not implemented yet" in res.stderr, name
            assert not (tmp_path / "r.h5").exists()


def _store_with_two_stages(path):
    store = Store(path)
    with store.write("vfcli mesh r.h5") as w:
        with w.stage("mesh", config_json='{"target_edge_mm": 0.8}') as s:
            s.put("nodes", np.zeros((4, 3)))
    with store.write("vfcli sync r.h5") as w:
        with w.stage("sync", config_json="{}", upstream=[("mesh", None)]) as s:
            s.put("ok", np.ones(3, bool))
    return store


def test_info_shows_stages_provenance_and_staleness(vfcli, tmp_path):
    path = tmp_path / "r.h5"
    store = _store_with_two_stages(path)
    res = vfcli("info", path)
    assert res.returncode == 0
    assert "/mesh" in res.stdout and "vfcli mesh r.h5" in res.stdout and "ok" in res.stdout
    data = json.loads(vfcli("info", path, "--json").stdout)
    paths = {s["path"]: s for s in data["stages"]}
    assert set(paths) == {"/mesh", "/sync"}
    assert paths["/mesh"]["provenance"]["config"] == {"target_edge_mm": 0.8}
    assert not paths["/sync"]["stale"]
    with store.write("vfcli mesh r.h5 --force") as w:
        with w.stage("mesh", config_json="{}") as s:
            s.put("nodes", np.ones((4, 3)))
    res = vfcli("info", path)
    assert "STALE: /mesh was rewritten" in res.stdout


def test_a_run_fitted_by_an_older_method_is_stale_with_what_changed(vfcli, tmp_path):
    """optimize's method version 2 (the model's velocity at the frame times): a run written before
    vfcli recorded the version (no attribute, i.e. method 1) is stale and says why, and so is the
    diagnosis of it; the store is not damaged, and a fresh run is current."""
    import h5py

    from vfcli.store import layout

    path = tmp_path / "r.h5"
    store = _store_with_two_stages(path)
    with store.write("vfcli optimize r.h5") as w:
        with w.stage("optimize", run="default", config_json="{}", upstream=[("mesh", None)]) as s:
            s.put("controls", np.ones(3))
    with store.write("vfcli diagnose r.h5") as w:
        with w.stage("diagnose", run="default", config_json="{}", upstream=[("optimize", "default")]) as s:
            s.put("frame_time", np.arange(3.0))
    with store.read() as r:
        assert r.group("optimize", "default").attrs[layout.METHOD_ATTR] == layout.stage("optimize").method == 9
        assert r.group("mesh").attrs[layout.METHOD_ATTR] == 1
        assert not any(st.stale for st in r.statuses())
        assert r.is_current("optimize", "{}", upstream=[("mesh", None)], run="default")
    with h5py.File(path, "r") as f:   # the run's part file, as a vfcli before the method version wrote it
        part = path.parent / f.get("/optimize/default", getlink=True).filename
    with h5py.File(part, "r+") as f:
        del f["/optimize/default"].attrs[layout.METHOD_ATTR]
    res = vfcli("info", path, "--verify")
    assert res.returncode == 0, res.stderr   # not damaged: the version is not part of the checksums
    assert ("STALE: method changed: optimize method 1 -> 9 (the model's velocity at the frame times "
            "(central differences)") in res.stdout
    assert "; the L-curve scans 16 decades" in res.stdout           # every change since the run's version
    assert "; the stated uncertainty's instrument part compares" in res.stdout
    assert "; the estimated pose places mid-length by the motion's symmetry" in res.stdout
    assert "; a ray the camera sees closed asks a simulated gap on it to close where it stands" in res.stdout
    assert "; the estimated pose searches mid-length by the motion's symmetry wherever the glottis" in res.stdout
    assert "; the stated uncertainty adds how far the fit moves across the width of the L-curve's corner" in res.stdout
    assert "STALE: /optimize/default is stale" in res.stdout
    with store.read() as r:
        status = {st.path: st for st in r.statuses()}
        assert not status["/mesh"].stale and not status["/sync"].stale
        assert not r.is_current("optimize", "{}", upstream=[("mesh", None)], run="default")


def test_info_reports_an_interrupted_write(vfcli, tmp_path):
    path = tmp_path / "r.h5"
    _store_with_two_stages(path)
    (tmp_path / "r.h5.tmp-12345").write_bytes(b"partial")
    res = vfcli("info", path)
    assert "interrupted write" in res.stdout


@pytest.mark.parametrize("content, code", [(None, 2), (b"not hdf5 at all", 4)])
def test_info_on_a_missing_or_foreign_file_is_one_clear_line(vfcli, tmp_path, content, code):
    path = tmp_path / "r.h5"
    if content is not None:
        path.write_bytes(content)
    res = vfcli("info", path)
    assert res.returncode == code
    assert res.stderr.count("\n") == 1 and str(path) in res.stderr and "Traceback" not in res.stderr


def test_a_stage_stores_its_figures_and_warnings_and_info_shows_them(vfcli, tmp_path):
    """The summary a command prints is in the store (info, info --json) with the warnings it
    logged, even when --quiet kept them off the terminal."""
    path = tmp_path / "r.h5"
    res = vfcli("mesh", path, "--json", "--quiet", "--set", "mesh.target_edge_mm=2.5")
    assert res.returncode == 0, res.stderr
    printed = json.loads(res.stdout)
    info = json.loads(vfcli("info", path, "--json").stdout)
    summary = {s["path"]: s for s in info["stages"]}["/mesh"]["summary"]
    assert summary["figures"] == {k: v for k, v in printed.items() if k not in ("stage", "status")}
    text = vfcli("info", path).stdout
    assert f"nodes={printed['nodes']}" in text and f"tets={printed['tets']}" in text
    again = json.loads(vfcli("mesh", path, "--json", "--set", "mesh.target_edge_mm=2.5").stdout)
    assert again == {**printed, "status": "up-to-date"}       # an up-to-date stage reports its stored figures


def test_warnings_logged_by_a_stage_are_stored_whatever_the_verbosity(tmp_path):
    import logging

    from vfcli.stages.base import RunContext, run_stage

    logging.getLogger("vfcli").setLevel(logging.ERROR)      # as --quiet leaves it
    try:
        ctx = RunContext.open(tmp_path / "r.h5")

        def body(_reader, s):
            s.put("nodes", np.zeros((2, 3)))
            logging.getLogger("vfcli.stages.test").warning("the gap never opens in %d frames", 12)
            logging.getLogger("vfcli.stages.test").info("not a warning")
            return {"nodes": 2}

        run_stage(ctx, "mesh", config_json="{}", body=body)
    finally:
        logging.getLogger("vfcli").setLevel(logging.NOTSET)
    assert logging.getLogger("vfcli").level == logging.NOTSET and logging.getLogger("vfcli").propagate
    with Store(tmp_path / "r.h5").read() as r:
        assert r.summary("mesh") == {"figures": {"nodes": 2},
                                     "warnings": ["WARNING vfcli.stages.test: the gap never opens in 12 frames"]}


def test_click_choices_and_the_core_names_come_from_the_config_literals():
    """One source for the names a user can choose: the config's Literal fields. Every name
    the CLI offers is one the core knows (and vice versa)."""
    from vfcli.cli.optimize import optimize_cmd
    from vfcli.cli.synth import synth_cmd
    from vfcli.config import OptimizeConfig, SynthConfig, literal_choices
    from vfcli.inverse.setup import DEFAULT_RIDGE
    from vfcli.model.loads.force_field import ForceFieldSpec
    from vfcli.synth import effects

    offered = {p.name: list(p.type.choices) for cmd in (optimize_cmd, synth_cmd) for p in cmd.params
               if hasattr(p.type, "choices")}
    assert offered["setup"] == list(literal_choices(OptimizeConfig, "setup"))
    assert offered["loads"] == list(literal_choices(OptimizeConfig, "loads"))
    assert offered["method"] == list(literal_choices(OptimizeConfig, "method"))
    assert offered["effect"] == list(literal_choices(SynthConfig, "effect"))
    assert set(DEFAULT_RIDGE) == set(offered["loads"])
    assert set(effects.EFFECTS) == set(offered["effect"]) - {"random"} == set(effects.DEFAULT_STRENGTH)
    for name in offered["setup"]:
        ForceFieldSpec.from_name(name)
    with pytest.raises(TypeError):
        literal_choices(OptimizeConfig, "max_iterations")
