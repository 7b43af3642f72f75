"""`vfcli batch`: manifests, the ledger, outcomes, and a worker killed mid-batch.

The batch runs are real: phantom recordings (tiny), a real Dask LocalCluster of worker
processes, a real SIGKILL, and every store checked afterwards with `vfcli info --verify`.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from _batch_phantoms import tiny_raw
from conftest import ROOT, run_vfcli
from vfcli.batch.ledger import Ledger
from vfcli.batch.manifest import parse_manifest, read_manifest
from vfcli.errors import ConfigError, StoreLockedError
from vfcli.store import Store
from vfcli.store.locking import LockUnsupportedError

SEEDS = (41, 42, 43)


@pytest.fixture(scope="module")
def raws(tmp_path_factory) -> list[Path]:
    """The raw folders rec41, rec42, rec43 of three tiny phantoms (shared with other files: read-only)."""
    return [tiny_raw(tmp_path_factory, s) for s in SEEDS]


# ---------------------------------------------------------------- manifests

def test_toml_manifest_resolves_paths_defaults_and_overrides(tmp_path):
    text = """
[batch]
until = "sync"
workers = 3
set = { "optimize.max_iterations" = 5, flow = { median_px = 3 } }
[batch.slurm]
queue = "short"
jobs = 4

[[recording]]
raw = "raw/a"

[[recording]]
name = "b2"
raw = "/data/b"
store = "out/b.h5"
until = "flow"
config = "lab.toml"
set = { "flow.median_px" = 5 }
"""
    m = parse_manifest(tmp_path / "batch.toml", text)
    a, b = m.recordings
    assert (a.name, a.raw, a.store, a.until) == ("a", tmp_path / "raw/a", tmp_path / "work/a.h5", "sync")
    assert a.overrides == {"optimize.max_iterations": 5, "flow.median_px": 3}
    assert (b.name, b.raw, b.store, b.until, b.config) == ("b2", Path("/data/b"), tmp_path / "out/b.h5", "flow",
                                                           tmp_path / "lab.toml")
    assert b.overrides == {"optimize.max_iterations": 5, "flow.median_px": 5}
    assert m.workers == 3 and m.slurm == {"queue": "short", "jobs": 4}
    assert m.ledger_path == tmp_path / "batch.toml.ledger.json"


def test_csv_manifest_reads_the_same_fields(tmp_path):
    text = "name,raw,store,until,set\nx,raw/x,,sync,flow.median_px=3;optimize.loads=\"free\"\n,raw/y,y.h5,,\n"
    x, y = parse_manifest(tmp_path / "b.csv", text).recordings
    assert (x.name, x.store, x.until, x.overrides) == ("x", tmp_path / "work/x.h5", "sync",
                                                       {"flow.median_px": 3, "optimize.loads": "free"})
    assert (y.name, y.store, y.until, y.overrides) == ("y", tmp_path / "y.h5", None, {})


@pytest.mark.parametrize("text, says", [
    ('[[recording]]\nraw = "a"\n[[recording]]\nraw = "b"\nstore = "work/a.h5"\n', "same store file"),
    ('[[recording]]\nraw = "x/a"\n[[recording]]\nraw = "y/a"\n', "same name"),
    ('[[recording]]\nraw = "a"\nspeed = 3\n', "unknown field(s) speed"),
    ('[[recording]]\nname = "a"\n', "'raw'"),
    ('[batch]\nworkers = 0\n[[recording]]\nraw = "a"\n', "workers = 0"),
    ('[[recording]]\nraw = "a"\nset = { median_px = 3 }\n', "section.field"),
    ("[batch]\n", "no recording"),
    ('[batch]\nuntil = "fields"\n[[recording]]\nraw = "a"\n', "until = 'fields' is not a step"),
    ("[[recording]\n", "not valid TOML"),
])
def test_bad_manifests_are_one_config_error_naming_the_problem(tmp_path, text, says):
    with pytest.raises(ConfigError, match=None) as err:
        parse_manifest(tmp_path / "b.toml", text)
    assert says in str(err.value)


def test_manifest_of_another_kind_or_missing_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="toml or a .csv"):
        parse_manifest(tmp_path / "b.yaml", "")
    with pytest.raises(ConfigError, match="cannot read"):
        read_manifest(tmp_path / "none.toml")


# ---------------------------------------------------------------- ledger

def test_ledger_resumes_only_what_is_unchanged(tmp_path):
    raw = tmp_path / "raw" / "a"
    raw.mkdir(parents=True)
    (raw / "video.cihx").write_text("v")
    store = tmp_path / "work" / "a.h5"
    store.parent.mkdir()
    store.write_bytes(b"store")
    m = parse_manifest(tmp_path / "b.toml", '[[recording]]\nraw = "raw/a"\n')
    (entry,) = m.recordings
    ledger = Ledger(m.ledger_path, m.path)
    ledger.record(entry, {"name": "a", "status": "done"})
    again = Ledger.load(m.ledger_path, m.path)
    assert again.is_finished(entry)
    other = parse_manifest(tmp_path / "b.toml", '[[recording]]\nraw = "raw/a"\nuntil = "sync"\n').recordings[0]
    assert not again.is_finished(other)  # another task
    os.utime(raw / "video.cihx", ns=(1, 1))
    assert not again.is_finished(entry)  # a raw file touched
    ledger.record(entry, {"name": "a", "status": "failed"})
    assert not Ledger.load(m.ledger_path, m.path).is_finished(entry)  # failed: run again
    m.ledger_path.write_text("{not json")
    assert Ledger.load(m.ledger_path, m.path).recordings == {}  # a broken ledger costs a rerun only
    assert [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name] == []


def test_a_held_ledger_refuses_a_second_holder_and_says_who_holds_it(tmp_path):
    ledger = Ledger(tmp_path / "b.toml.ledger.json", tmp_path / "b.toml")
    with ledger.hold():
        with pytest.raises(StoreLockedError, match=rf"another `vfcli batch` of this manifest is running \(pid {os.getpid()} on "):
            with Ledger(tmp_path / "b.toml.ledger.json", tmp_path / "b.toml").hold():
                pass
    with Ledger(tmp_path / "b.toml.ledger.json", tmp_path / "b.toml").hold():  # released at the end of the block
        pass


@pytest.mark.parametrize("code", [37, 524])
def test_a_file_system_without_locks_stops_the_batch_with_what_to_do(tmp_path, monkeypatch, code):
    """flock failing as on NFS without a lock daemon (errno 37) or Lustre (524): one error (exit 4)
    saying where to keep the manifest; nothing waits."""
    import fcntl

    def no_locks(fd, op):
        raise OSError(code, os.strerror(code) if code == 37 else "Unknown error 524")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with pytest.raises(LockUnsupportedError, match=f"errno {code}.*keep the manifest") as err:
        with Ledger(tmp_path / "b.toml.ledger.json", tmp_path / "b.toml").hold():
            pass
    assert err.value.exit_code == 4


# ---------------------------------------------------------------- runs

def _manifest(tmp_path: Path, raws: list[Path], until: str, extra: str = "") -> Path:
    rows = "".join(f'\n[[recording]]\nraw = "{r}"\nstore = "work/{r.name}.h5"\n' for r in raws)
    path = tmp_path / "batch.toml"
    path.write_text(f'[batch]\nuntil = "{until}"\nworkers = 2\n{extra}{rows}')
    return path


def _verify(store: Path) -> None:
    res = run_vfcli("info", "--verify", store)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "DAMAGED" not in res.stdout and "interrupted write" not in res.stdout, res.stdout


@pytest.mark.slow
def test_a_manifests_set_values_are_the_recordings_config_after_the_batch(tmp_path, raws):
    """A manifest entry with `set = { "flow.median_px" = 3 }` (docs/cluster.md's example): right after the batch
    `vfcli info` called /flow, /fields and the fit STALE ("config changed: flow.median_px 3 -> 5"), and a plain
    `vfcli run` would have undone the value. The values are now stored with the recording, as `vfcli config --set`."""
    from vfcli.batch.manifest import RecordingEntry
    from vfcli.batch.task import run_entry
    from vfcli.stages.run import run_recording

    store = tmp_path / "a.h5"
    entry = RecordingEntry(name="a", raw=raws[0], store=store, until="flow", overrides={"flow.median_px": 3})
    out = run_entry(entry.to_json())
    assert out["status"] == "done", out
    info = json.loads(run_vfcli("info", "--json", store).stdout)
    assert not [st["path"] for st in info["stages"] if st["stale"]], info
    with Store(store).read() as r:
        assert json.loads(r.recording_config_json())["flow"]["median_px"] == 3
        assert json.loads(r.group("flow").attrs["config_json"])["flow"]["median_px"] == 3
    plain = run_recording(store, raws[0], until="flow", dry_run=True)
    assert {s.action for s in plain.stages if s.name != "diagnose"} <= {"up to date", "skipped"}, plain


def test_cli_batch_runs_resumes_and_reports_a_failed_recording(tmp_path, raws):
    manifest = _manifest(tmp_path, raws[:2], "ingest-ldv")
    with manifest.open("a") as fh:
        fh.write('\n[[recording]]\nname = "broken"\nraw = "no/such/folder"\n')
    res = run_vfcli("batch", manifest, "--json")
    assert res.returncode == 3, res.stderr  # the broken recording's exit code (bad input)
    out = json.loads(res.stdout)
    status = {r["name"]: r["status"] for r in out["recordings"]}
    assert status == {raws[0].name: "done", raws[1].name: "done", "broken": "failed"}
    assert out["counts"] == {"done": 2, "up to date": 0, "failed": 1}
    broken = out["recordings"][2]
    assert "raw folder not found" in broken["error"] and broken["exit_code"] == 3
    ledger = json.loads((tmp_path / "batch.toml.ledger.json").read_text())
    assert set(ledger["recordings"]) == {raws[0].name, raws[1].name, "broken"}
    for r in raws[:2]:
        _verify(tmp_path / "work" / f"{r.name}.h5")
    # a rerun: the finished recordings come from the ledger, the failed one runs again
    res = run_vfcli("batch", manifest)
    assert res.returncode == 3
    lines = res.stdout.splitlines()
    assert any(line.startswith(raws[0].name) and "done (ledger)" in line for line in lines), res.stdout
    assert lines[-1].startswith("3 recordings: 2 done, 0 up to date, 1 failed")
    # --fresh ignores the ledger; vfcli run finds every stage current
    res = run_vfcli("batch", manifest, "--fresh", "--json")
    status = {r["name"]: r["status"] for r in json.loads(res.stdout)["recordings"]}
    assert status == {raws[0].name: "up to date", raws[1].name: "up to date", "broken": "failed"}


@pytest.mark.slow
def test_a_second_batch_of_the_same_manifest_stops_and_the_first_runs_each_recording_once(tmp_path, raws):
    """Two real `vfcli batch` processes on one manifest: the second starts while the first
    holds the ledger, exits 4 with one line naming the first (no cluster started, no recording
    run); the first runs every recording once and leaves a whole ledger and sound stores."""
    manifest = _manifest(tmp_path, raws, "sync")
    lock = tmp_path / ".batch.toml.ledger.json.lock"
    cmd = [sys.executable, "-m", "vfcli.cli.main", "batch", str(manifest), "--json"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    while not (lock.exists() and lock.read_text().strip()) and time.monotonic() < deadline:
        assert first.poll() is None, first.communicate()
        time.sleep(0.1)
    second = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    first_running = first.poll() is None
    out, err = first.communicate(timeout=900)
    assert first_running, "the first batch ended before the second started: the test proves nothing"
    assert second.returncode == 4, second.stderr
    (line,) = second.stderr.strip().splitlines()
    assert second.stdout == "" and line.startswith(
        f"vfcli batch: error: {manifest}: another `vfcli batch` of this manifest is running "
        f"(pid {first.pid} on {socket.gethostname()}, since "), line
    assert first.returncode == 0, err
    status = {r["name"]: r["status"] for r in json.loads(out)["recordings"]}
    assert status == {r.name: "done" for r in raws}
    ledger = json.loads((tmp_path / "batch.toml.ledger.json").read_text())
    assert {k: v["status"] for k, v in ledger["recordings"].items()} == status
    for r in raws:
        store = tmp_path / "work" / f"{r.name}.h5"
        _verify(store)
        with Store(store).read() as reader:
            assert reader.has_stage("sync")


@pytest.mark.slow
def test_a_worker_killed_mid_batch_loses_no_recording_and_damages_no_store(tmp_path, raws):
    """Three recordings on two worker processes; one worker is SIGKILLed while it runs a
    recording. The scheduler reruns that recording elsewhere; all three end done, and each
    store passes `vfcli info --verify` (structure and every dataset's SHA-256)."""
    from vfcli.batch.cluster import open_client
    from vfcli.batch.engine import run_batch

    manifest = read_manifest(_manifest(tmp_path, raws, "flow"))
    result: dict = {}
    with open_client(workers=2, allowed_failures=2) as client:
        pids = client.run(os.getpid)  # worker address -> pid
        thread = threading.Thread(target=lambda: result.update(summary=run_batch(manifest, client)))
        thread.start()
        victim = None
        deadline = time.monotonic() + 120
        while victim is None and time.monotonic() < deadline:
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                time.sleep(4.0)  # inside the recording (ingest, sync, flow of the tiny phantom: 7 s alone)
                busy = [w for w, keys in client.processing().items() if keys]
                if busy:
                    victim = busy[0]
                    os.kill(pids[victim], signal.SIGKILL)
            else:
                time.sleep(0.2)
        assert victim is not None, "no worker ever ran a recording"
        thread.join(timeout=600)
        assert not thread.is_alive()
    summary = result["summary"]
    assert [o["status"] for o in summary.outcomes] == ["done"] * 3, summary.table()
    assert all(o["pid"] != pids[victim] for o in summary.outcomes)  # the killed run left no outcome
    for r in raws:
        store = tmp_path / "work" / f"{r.name}.h5"
        _verify(store)
        assert not list(store.parent.glob(f"{store.name}.tmp-*"))


def test_without_dask_batch_says_what_to_install(tmp_path):
    """dask not installed (a sitecustomize makes its import fail): one line, exit 2."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "import sys\n"
        "class _NoDask:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('dask', 'distributed', 'dask_jobqueue'):\n"
        "            raise ImportError(f'No module named {name!r}')\n"
        "sys.meta_path.insert(0, _NoDask())\n")
    manifest = tmp_path / "b.toml"
    manifest.write_text('[[recording]]\nraw = "raw/a"\n')
    env = {**os.environ, "PYTHONPATH": f"{site}{os.pathsep}{ROOT}"}
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", "batch", str(manifest)], capture_output=True,
                         text=True, env=env, timeout=120)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == ["vfcli batch: error: `vfcli batch` needs dask[distributed]: "
                                               "pip install 'vfcli[batch]'"]
