"""The batch examples run as a lab would run them: examples/Makefile with `make -j2` over two
phantom recordings (a second make does nothing; a touched raw file reruns only its
recording), and examples/slurm/ holding the job script the code writes."""
from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, run_vfcli
from _batch_phantoms import SMALL_OPTIMIZE, synth
from vfcli.batch.cluster import job_script
from vfcli.batch.manifest import read_manifest


def test_slurm_example_holds_the_job_script_the_code_writes():
    manifest = read_manifest(ROOT / "examples" / "slurm" / "batch.toml")
    expected = job_script("slurm", manifest.slurm)
    assert (ROOT / "examples" / "slurm" / "vfcli-worker.sbatch").read_text() == expected
    assert "#SBATCH -p normal" in expected and "--nthreads 1" in expected and "--nanny" in expected
    res = run_vfcli("batch", ROOT / "examples" / "slurm" / "batch.toml", "--job-script", "--slurm", "queue=long")
    assert res.returncode == 0, res.stderr
    assert "#SBATCH -p long" in res.stdout and res.stdout.replace("-p long", "-p normal") == expected


def _make(work: Path, *args: str) -> subprocess.CompletedProcess:
    vfcli = f"{shlex.quote(sys.executable)} -m vfcli.cli.main"
    cmd = ["make", "-f", str(ROOT / "examples" / "Makefile"), f"VFCLI={vfcli}", "EXPORT_FLAGS=--what tables", *args]
    return subprocess.run(cmd, cwd=work, capture_output=True, text=True, timeout=1200,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


def _times(work: Path, rec: str) -> dict[str, int]:
    paths = [work / "work" / f"{rec}.h5", work / "work" / rec / "export" / ".done", work / "work" / rec / "report.html"]
    return {p.name: p.stat().st_mtime_ns for p in paths}


@pytest.mark.slow
def test_makefile_runs_two_recordings_then_nothing_then_only_the_touched_one(tmp_path):
    raw = tmp_path / "raw"
    procs = [synth(raw / name, seed) for name, seed in (("a", 51), ("b", 52))]
    for p in procs:
        assert p.wait() == 0, p.stderr.read()
    for name in ("a", "b"):
        with (raw / name / "recording.toml").open("a") as fh:
            fh.write(SMALL_OPTIMIZE)
    res = _make(tmp_path, "-j2")
    assert res.returncode == 0, res.stdout + res.stderr
    for rec in ("a", "b"):
        store = tmp_path / "work" / f"{rec}.h5"
        info = run_vfcli("info", "--verify", store)
        assert info.returncode == 0 and "/optimize/default" in info.stdout and "STALE" not in info.stdout, info.stdout
        assert (tmp_path / "work" / rec / "report.html").stat().st_size > 1000
        assert list((tmp_path / "work" / rec / "export").rglob("*.csv"))
    before = {rec: _times(tmp_path, rec) for rec in ("a", "b")}
    res = _make(tmp_path, "-j2")
    assert res.returncode == 0 and "Nothing to be done" in res.stdout, res.stdout
    assert {rec: _times(tmp_path, rec) for rec in ("a", "b")} == before
    os.utime(raw / "a" / "scan.uff")  # touched, content unchanged
    dry = _make(tmp_path, "-n").stdout
    assert "raw/a" in dry and " work/a.h5" in dry and "work/b" not in dry, dry
    res = _make(tmp_path, "-j2")
    assert res.returncode == 0, res.stdout + res.stderr
    after = {rec: _times(tmp_path, rec) for rec in ("a", "b")}
    assert after["b"] == before["b"]
    assert all(after["a"][k] > before["a"][k] for k in before["a"])
