"""The command line as a user meets it: help, exit codes, info on a real store."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from vfcli.store.transaction import Store

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
