"""The batch examples run as a lab would run them: examples/Makefile with `make -j2` and
examples/Snakefile with `snakemake --cores 2` over two phantom recordings (a second run does
nothing; a touched raw file reruns only its recording), examples/slurm/ holding the job
script the code writes, and the Snakemake SLURM profile producing the sbatch call it documents.

Snakemake is not a test dependency (about 85 MB installed): its tests skip without it
(``pip install 'vfcli[workflow]'``)."""
from __future__ import annotations

import importlib.util
import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, run_vfcli
from _batch_phantoms import small_fit_raw
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


VFCLI = f"{shlex.quote(sys.executable)} -m vfcli.cli.main"
needs_snakemake = pytest.mark.skipif(importlib.util.find_spec("snakemake") is None,
                                     reason="snakemake is not installed (pip install 'vfcli[workflow]')")


@pytest.fixture(scope="module")
def raw_pair(tmp_path_factory) -> Path:
    """Two tiny phantoms raw/a, raw/b with a small fit (each test copies them): copies of the
    shared tiny phantoms 41 and 42 (tests/test_batch.py's), their recording.toml set for it."""
    raw = tmp_path_factory.mktemp("examples") / "raw"
    for name, seed in (("a", 41), ("b", 42)):
        small_fit_raw(tmp_path_factory, seed, raw / name)
    return raw


def _make(work: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = ["make", "-f", str(ROOT / "examples" / "Makefile"), f"VFCLI={VFCLI}", "EXPORT_FLAGS=--what tables", *args]
    return subprocess.run(cmd, cwd=work, capture_output=True, text=True, timeout=1200,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


def _snakemake(work: Path, *args: str, path: str | None = None, timeout: float = 1800) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(ROOT / "examples" / "Snakefile"), *args]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if path:
        env["PATH"] = path + os.pathsep + env["PATH"]
    return subprocess.run(cmd, cwd=work, capture_output=True, text=True, timeout=timeout, env=env)


def _check_outputs(work: Path) -> None:
    for rec in ("a", "b"):
        store = work / "work" / f"{rec}.h5"
        info = run_vfcli("info", "--verify", store)
        assert info.returncode == 0 and "/optimize/default" in info.stdout and "STALE" not in info.stdout, info.stdout
        assert (work / "work" / rec / "report.html").stat().st_size > 1000
        assert list((work / "work" / rec / "export").rglob("*.csv"))


def _times(work: Path, rec: str) -> dict[str, int]:
    paths = [work / "work" / f"{rec}.h5", work / "work" / rec / "export" / ".done", work / "work" / rec / "report.html"]
    return {p.name: p.stat().st_mtime_ns for p in paths}


@pytest.mark.slow
@pytest.mark.timeout(2400)  # two recordings through optimize, export and report, then two reruns
def test_makefile_runs_two_recordings_then_nothing_then_only_the_touched_one(tmp_path, raw_pair):
    raw = tmp_path / "raw"
    shutil.copytree(raw_pair, raw)
    res = _make(tmp_path, "-j2")
    assert res.returncode == 0, res.stdout + res.stderr
    _check_outputs(tmp_path)
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


def _smk_times(work: Path, rec: str) -> dict[str, int]:
    paths = [work / "work" / f"{rec}.run.json", work / "work" / f"{rec}.h5", work / "work" / rec / "export" / ".done",
             work / "work" / rec / "report.html"]
    return {p.name: p.stat().st_mtime_ns for p in paths}


@pytest.mark.slow
@pytest.mark.timeout(2400)
@needs_snakemake
def test_snakefile_runs_two_recordings_then_nothing_then_only_the_touched_one(tmp_path, raw_pair):
    raw = tmp_path / "raw"
    shutil.copytree(raw_pair, raw)
    config = ["--cores", "2", "--config", f"vfcli={VFCLI}", "export_flags=--what tables"]
    res = _snakemake(tmp_path, *config)
    assert res.returncode == 0, res.stdout + res.stderr
    _check_outputs(tmp_path)
    before = {rec: _smk_times(tmp_path, rec) for rec in ("a", "b")}
    res = _snakemake(tmp_path, *config)
    assert res.returncode == 0 and "Nothing to be done" in res.stdout + res.stderr, res.stdout + res.stderr
    assert {rec: _smk_times(tmp_path, rec) for rec in ("a", "b")} == before
    os.utime(raw / "a" / "scan.uff")  # touched, content unchanged
    dry = _snakemake(tmp_path, *config, "-n")
    text = dry.stdout + dry.stderr
    assert dry.returncode == 0 and "rec=a" in text and "rec=b" not in text, text
    res = _snakemake(tmp_path, *config)
    assert res.returncode == 0, res.stdout + res.stderr
    after = {rec: _smk_times(tmp_path, rec) for rec in ("a", "b")}
    assert after["b"] == before["b"]
    # a's summary, export and report are redone; its store is left as it was: vfcli run found
    # every stage current (inputs matched by content), so nothing was rewritten or refitted
    assert after["a"]["a.h5"] == before["a"]["a.h5"]
    assert all(after["a"][k] > before["a"][k] for k in before["a"] if k != "a.h5")
    summary = json.loads((tmp_path / "work" / "a.run.json").read_text())
    # every stage current; diagnose is skipped (these short phantoms hold too few whole cycles)
    assert {s["action"] for s in summary["stages"] if s["name"] != "diagnose"} == {"up to date"}, summary
    assert {s["action"] for s in summary["stages"] if s["name"] == "diagnose"} <= {"skipped", "up to date"}, summary


@pytest.mark.slow
@needs_snakemake
@pytest.mark.skipif(importlib.util.find_spec("snakemake_executor_plugin_slurm") is None,
                    reason="snakemake-executor-plugin-slurm is not installed")
def test_snakemake_slurm_profile_submits_one_job_per_rule_with_its_resources(tmp_path):
    """examples/slurm/snakemake as the SLURM executor plugin reads it, with stand-ins for the
    SLURM commands (no cluster here): the sbatch call carries the profile's account and
    partition and the rule's memory and run time, and runs the job's own snakemake."""
    (tmp_path / "raw" / "a").mkdir(parents=True)
    (tmp_path / "raw" / "a" / "recording.toml").write_text("")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "calls.log"
    for cmd, out in (("sbatch", ""), ("sacctmgr", "vocal-lab"), ("scontrol", ""), ("sshare", ""), ("sacct", ""),
                     ("squeue", ""), ("sinfo", "")):
        (bin_dir / cmd).write_text(f'#!/bin/sh\necho "{cmd} $*" >> {log}\necho {out}\n'
                                   + ("exit 1\n" if cmd == "sbatch" else ""))
        (bin_dir / cmd).chmod(0o755)
    # the plugin waits 40 s before its first status check; nothing runs here, so 1 s
    res = _snakemake(tmp_path, "--profile", str(ROOT / "examples" / "slurm" / "snakemake"), "--jobs", "1",
                     "--retries", "0", "--slurm-init-seconds-before-status-checks", "1", path=str(bin_dir), timeout=600)
    assert res.returncode != 0  # the stand-in sbatch refuses the job
    (sbatch,) = [line for line in log.read_text().splitlines() if line.startswith("sbatch ")]
    for part in ("-A vocal-lab", "-p normal", "-t 120", "--mem 4000", "--cpus-per-task=1",
                 "--target-jobs run:rec=a", "--executor slurm-jobstep"):
        assert part in sbatch.replace("'", ""), sbatch
