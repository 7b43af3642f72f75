"""The store: round trips, provenance, idempotence, staleness, crash safety and locking."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from vfcli.errors import MissingStageError, StoreFormatError, StoreLockedError
from vfcli.store import Store

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from store_writer_proc import frames_for  # noqa: E402

WRITER = [sys.executable, str(HERE / "store_writer_proc.py")]


def _write_mesh(store: Store, value: float = 1.0) -> None:
    with store.write("test") as w:
        with w.stage("mesh", config_json=json.dumps({"v": value})) as s:
            s.put("nodes", np.full((5, 3), value))


def test_put_and_read_round_trip_with_units_and_dimension_scales(tmp_path):
    store = Store(tmp_path / "r.h5")
    frames = np.arange(3 * 4 * 5, dtype=np.uint16).reshape(3, 4, 5)
    with store.write("test") as w:
        with w.stage("hsc", config_json="{}") as s:
            s.put("frames", frames)
            s.put("frame_time", np.array([0.0, 1e-4, 2e-4]))
    with store.read() as r:
        np.testing.assert_array_equal(r.read("hsc", "frames"), frames)
        ds = r.dataset("hsc", "frames")
        assert ds.attrs["units"] == "counts"
        assert ds.chunks == (1, 4, 5) and ds.compression == "gzip"
    with h5py.File(store.path, "r") as f:  # what HDFView and xarray see
        scale = f["/hsc/frames"].dims[0][0]
        assert scale.name == "/hsc/frame_time"
        np.testing.assert_allclose(scale[()], [0.0, 1e-4, 2e-4])
        assert f["/hsc/frame_time"].attrs["units"] == "s"


def test_undeclared_dataset_is_refused(tmp_path):
    store = Store(tmp_path / "r.h5")
    with pytest.raises(KeyError, match="declares no dataset"):
        with store.write("test") as w:
            with w.stage("mesh", config_json="{}") as s:
                s.put("not_in_layout", np.zeros(3))
    assert not store.exists()  # the failed transaction left nothing


def test_provenance_records_config_inputs_and_upstream(tmp_path):
    raw = tmp_path / "raw.bin"
    raw.write_bytes(b"abc")
    store = Store(tmp_path / "r.h5")
    from vfcli.provenance import describe_inputs

    _write_mesh(store)
    with store.write("vfcli sync r.h5") as w:
        with w.stage("sync", config_json='{"a": 1}', inputs=describe_inputs([raw]), upstream=[("mesh", None)]) as s:
            s.put("ok", np.ones(3, bool))
    with store.read() as r:
        st = r.status("/sync").to_json()
    prov = st["provenance"]
    assert prov["command"] == "vfcli sync r.h5"
    assert prov["config"] == {"a": 1}
    (meta,) = prov["inputs"].values()
    assert meta["sha256"] == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    assert list(prov["upstream"]) == ["/mesh"]
    assert st["complete"] and not st["stale"]


def test_is_current_tracks_config_inputs_and_upstream(tmp_path):
    raw = tmp_path / "raw.bin"
    raw.write_bytes(b"one")
    store = Store(tmp_path / "r.h5")
    from vfcli.provenance import describe_inputs

    _write_mesh(store)
    with store.write("t") as w:
        with w.stage("sync", config_json="{}", inputs=describe_inputs([raw]), upstream=[("mesh", None)]) as s:
            s.put("ok", np.ones(2, bool))
    with store.read() as r:
        assert r.is_current("sync", "{}", describe_inputs([raw]), [("mesh", None)])
        assert not r.is_current("sync", '{"x": 1}', describe_inputs([raw]), [("mesh", None)])
    raw.write_bytes(b"two")
    with store.read() as r:
        assert not r.is_current("sync", "{}", describe_inputs([raw]), [("mesh", None)])
    raw.write_bytes(b"one")
    _write_mesh(store, 2.0)  # upstream rewritten: sync is now stale
    with store.read() as r:
        status = r.status("/sync")
        assert status.stale and "/mesh was rewritten" in status.stale_because[0]
        assert not r.is_current("sync", "{}", describe_inputs([raw]), [("mesh", None)])


def test_rewriting_a_stage_reuses_its_space(tmp_path):
    store = Store(tmp_path / "r.h5")
    big = np.random.default_rng(0).random((200, 200, 20))
    for _ in range(4):
        with store.write("t") as w:
            with w.stage("mesh", config_json="{}") as s:
                s.put("nodes", big)
    assert os.path.getsize(store.path) < 1.5 * big.nbytes


def test_missing_stage_names_the_command_to_run(tmp_path):
    store = Store(tmp_path / "r.h5")
    _write_mesh(store)
    with store.read() as r:
        with pytest.raises(MissingStageError, match="vfcli ingest-hsc"):
            r.read("hsc", "frames")


def test_a_file_that_is_not_a_store_is_refused(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = 1
    with pytest.raises(StoreFormatError, match="not a vfcli store"):
        with Store(other).read():
            pass
    text = tmp_path / "text.h5"
    text.write_text("hello")
    with pytest.raises(StoreFormatError, match="cannot open"):
        with Store(text).write("t"):
            pass
    assert text.read_text() == "hello"


def _stage_state(path: Path) -> tuple[bool, int | None]:
    """(mesh intact, seed of a complete /hsc or None); asserts /hsc is whole when present."""
    with Store(path).read() as r:
        np.testing.assert_array_equal(r.read("mesh", "nodes"), np.full((5, 3), 1.0))
        if not r.has_stage("hsc", complete=False):
            return True, None
        assert r.has_stage("hsc"), "an incomplete /hsc reached the store"
        seed = int(r.attrs("hsc")["seed"])
        frames = r.read("hsc", "frames")
        np.testing.assert_array_equal(frames, frames_for(seed, frames.shape[0]))
        return True, seed


@pytest.mark.slow
def test_sigkill_at_random_moments_never_damages_the_store(tmp_path):
    """Kill a real writing process 30 times at random moments: the store always opens,
    the earlier stage is intact, the interrupted stage is absent or the previous complete one."""
    path = tmp_path / "r.h5"
    store = Store(path)
    _write_mesh(store)
    rng = np.random.default_rng(1)
    n_frames = 300
    # time one uninterrupted transaction (from "writing" to exit) to spread the kills over it
    proc = subprocess.Popen([*WRITER, str(path), "0", str(n_frames)], stdout=subprocess.PIPE)
    proc.stdout.readline()
    t0 = time.perf_counter()
    assert proc.wait() == 0
    full = time.perf_counter() - t0
    assert _stage_state(path) == (True, 0)
    last_complete = 0
    outcomes = {"killed": 0, "finished": 0}
    seed = 0
    while outcomes["killed"] < 30:  # 30 kills that landed while the stage was being written
        seed += 1
        assert seed <= 90, outcomes
        proc = subprocess.Popen([*WRITER, str(path), str(seed), str(n_frames)], stdout=subprocess.PIPE)
        assert proc.stdout.readline().strip() == b"writing"
        time.sleep(rng.uniform(0.0, full))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        ok, seen = _stage_state(path)
        assert seen in (last_complete, seed), f"kill {seed}: /hsc holds seed {seen}"
        outcomes["finished" if seen == seed else "killed"] += 1
        last_complete = seen
    print("kill outcomes:", outcomes)
    # the next writer cleans up what the killed ones left
    subprocess.run([*WRITER, str(path), "99", "5"], check=True)
    assert store.interrupted_writes() == []
    assert _stage_state(path) == (True, 99)


def test_second_writer_fails_at_once_and_corrupts_nothing(tmp_path, vfcli):
    path = tmp_path / "r.h5"
    _write_mesh(Store(path))
    holder = subprocess.Popen([*WRITER, str(path), "5", "3", "30"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "writing"
        t0 = time.perf_counter()
        with pytest.raises(StoreLockedError, match="another vfcli process is writing"):
            with Store(path).write("second"):
                pass
        cfg = tmp_path / "rec.toml"
        cfg.write_text("[camera]\npx_per_mm = 30\n")
        res = vfcli("config", path, "--config", cfg)
        assert time.perf_counter() - t0 < 10
        assert res.returncode == 4, res.stderr
        assert res.stderr.count("\n") == 1 and "another vfcli process is writing" in res.stderr
        # readers are not blocked and see the old, complete store
        assert _stage_state(path) == (True, None)
    finally:
        holder.kill()
        holder.wait()
    assert _stage_state(path) == (True, None)


def test_reader_never_sees_a_half_written_stage(tmp_path):
    path = tmp_path / "r.h5"
    _write_mesh(Store(path))
    proc = subprocess.Popen([*WRITER, str(path), "7", "400"], stdout=subprocess.PIPE)
    seen = set()
    while proc.poll() is None:
        seen.add(_stage_state(path)[1])
    proc.wait()
    seen.add(_stage_state(path)[1])
    assert seen <= {None, 7} and 7 in seen
