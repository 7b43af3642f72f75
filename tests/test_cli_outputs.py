"""Output paths on the command line are checked before any work (vfcli/cli/outputs.py).

A picture option with an extension its writer cannot write, or an output in a folder that cannot be
written, failed when the file was written: exit 1 with a traceback, after the fit or the diagnosis
(thrown away), after `vfcli mesh` had committed /mesh, after `vfcli run` had run every stage. Now it
is one line naming the option and the path, exit 2, and the store unchanged. Found by a new-user
walk-through (session 35). The folder checks run the real command without root's capabilities
(`setpriv`), so that permissions apply as they do for a lab's user account.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys

import pytest

from _export_store import meshed_store, optimised_store
from conftest import ROOT, run_vfcli
from vfcli.cli.outputs import PICTURE_FORMATS, PREVIEW_FORMATS, check_output_file, check_output_folder
from vfcli.errors import ConfigError
from vfcli.store.parts import copy_store

SETPRIV = shutil.which("setpriv")
UNPRIVILEGED = [SETPRIV, "--inh-caps=-all", "--ambient-caps=-all", "--bounding-set=-all"] if SETPRIV else []


def _state(store) -> tuple[str, int]:
    return hashlib.sha256(store.read_bytes()).hexdigest(), store.stat().st_mtime_ns


def _one_line_exit_2(res, *words: str) -> None:
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    for w in words:
        assert w in res.stderr, (w, res.stderr)


def test_every_picture_format_accepted_is_one_matplotlib_writes(tmp_path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(1, 1))
    FigureCanvasAgg(fig)
    fig.add_subplot().plot([0, 1])
    for fmt in PICTURE_FORMATS:
        out = tmp_path / f"f{fmt}"
        fig.savefig(out)
        assert out.stat().st_size > 100, fmt
    assert set(PREVIEW_FORMATS) <= set(PICTURE_FORMATS)


def test_output_checks_name_the_option_and_what_is_wrong(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "f").write_text("")
    check_output_file(tmp_path / "new" / "deeper" / "c.PNG", "--plot", PICTURE_FORMATS)   # made when written
    check_output_folder(tmp_path / "new" / "out", "--to")
    for call, words in [
        (lambda: check_output_file(tmp_path / "c.txt", "--plot", PICTURE_FORMATS), "--plot"),
        (lambda: check_output_file(tmp_path / "c", "--plot", PICTURE_FORMATS), "none is not one of .png"),
        (lambda: check_output_file(tmp_path / "d", "--out"), "is a folder"),
        (lambda: check_output_folder(tmp_path / "f", "--to"), "is a file, not a folder"),
        (lambda: check_output_folder(tmp_path / "f" / "sub", "--to"), "is a file, so no folder can be made there"),
    ]:
        with pytest.raises(ConfigError, match=words):
            call()


@pytest.mark.parametrize("command, option, name", [("optimize", "--plot", "conv.txt"),
                                                   ("optimize", "--uncertainty-map", "u.txt"),
                                                   ("mesh", "--preview", "m.svg")])
def test_a_picture_format_no_writer_writes_is_refused_before_the_work(tmp_path_factory, tmp_path, command, option,
                                                                      name):
    """`vfcli mesh --preview m.svg --force` committed /mesh and then failed (exit 1, the store changed); the fit
    behind `optimize --plot conv.txt` was thrown away."""
    store = copy_store(meshed_store(tmp_path_factory)[0], tmp_path / "rec.h5")
    before = _state(store)
    res = run_vfcli(command, store, option, tmp_path / name, "--force", "--set", "mesh.target_edge_mm=2.5")
    _one_line_exit_2(res, f"{option} {tmp_path / name}", "is not one of .png")
    assert _state(store) == before


def test_export_times_outside_the_run_are_refused(tmp_path_factory, tmp_path):
    """--time-ms nan, -5 or 1e6 was moved to the nearest end of the run without a word (a NaN went into
    export.json); the run 'pressure' spans 2.0-2.5 ms."""
    store = optimised_store(tmp_path_factory)
    for t in ("nan", "-5", "1e6"):
        res = run_vfcli("export", store, "--to", tmp_path / "e", "--what", "video", "--run", "pressure",
                        "--time-ms", t)
        _one_line_exit_2(res, f"--time-ms {float(t):g}: outside run pressure's window")
    assert not (tmp_path / "e").exists()


def _unprivileged(*args, cwd):
    # the suite's environment (make's PYTHONPYCACHEPREFIX: no bytecode written into the source tree)
    return subprocess.run([*UNPRIVILEGED, sys.executable, "-m", "vfcli.cli.main", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.mark.skipif(not SETPRIV, reason="setpriv (util-linux) is not installed")
def test_outputs_in_a_folder_that_cannot_be_written_are_one_line_and_nothing_runs(tmp_path_factory, tmp_path):
    store = copy_store(optimised_store(tmp_path_factory), tmp_path / "rec.h5")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    before = _state(store)
    try:
        for args, words in [
            (("report", store, "--out", ro / "r.html"), "--out"),
            (("report", store, "--out", ro / "sub" / "r.html"), "cannot write a folder in"),
            (("export", store, "--to", ro / "exp"), "--to"),
            (("share", store, ro / "s.h5"), "OUT"),
            (("synth", ro / "syn"), "OUTDIR"),
            (("run", store, "--report", ro / "r.html"), "--report"),
            (("run", store, "--export", ro / "exp"), "--export"),
        ]:
            res = _unprivileged(*args, cwd=tmp_path)
            _one_line_exit_2(res, words, str(ro), "permission denied")
        assert list(ro.iterdir()) == [] and _state(store) == before
    finally:
        ro.chmod(0o755)
