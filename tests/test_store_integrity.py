"""A corrupted or hand-edited store (issue 20): one line, exit 4, the store unchanged, never a traceback
and never exit 0 carrying the damage forward. See docs/input-checks.md, "Store integrity".

The store is written by the real stages on a short phantom (`vfcli synth`), damaged the way the
attacker did (a flipped byte at the object headers of /hsc/frames, /mesh, /sync and the root
group, in the data of a dataset; attributes edited and objects deleted with h5py), and every
command runs as a real subprocess.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from _small_phantom import SMALL_160, shared_raw
from tests.conftest import ROOT, run_vfcli
from vfcli.store.provenance import describe_inputs
from vfcli.store.parts import copy_store, parts_dir


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    """(raw folder, store with /hsc /ldv /sync /mesh) written by the real commands."""
    # `vfcli synth`'s, shared with tests/test_hostile_rate.py and test_diagnose_refit_phantom.py's null
    raw = shared_raw(tmp_path_factory, 34, SMALL_160)
    store = tmp_path_factory.mktemp("integrity") / "rec.h5"
    steps = [
        ["ingest-hsc", "-q", store, raw / "video.cihx", "--pressure", raw / "video_pressure.csv", "--config", raw / "recording.toml"],
        ["ingest-ldv", "-q", store, raw / "scan.uff"],
        ["sync", "-q", store],
        ["mesh", "-q", store],
    ]
    for args in steps:
        r = run_vfcli(*args)
        assert r.returncode == 0, (args[0], r.stderr[-2000:])
    return raw, store


@pytest.fixture
def store(built, tmp_path) -> Path:
    copy = tmp_path / "rec.h5"
    copy_store(built[1], copy)
    return copy


def _one_line_exit_4(r: subprocess.CompletedProcess, *needles: str) -> None:
    assert r.returncode == 4, r.stderr[-3000:]
    assert "Traceback" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "damaged store" in last or "another program" in last, last
    for n in needles:
        assert n in last, last


def _header_address(path: Path, name: str) -> int:
    with h5py.File(path, "r") as f:
        return h5py.h5o.get_info(f[name].id).addr


def _holder(store: Path, name: str) -> Path:
    """The file that holds object ``name``: the store file, or the part file of its stage."""
    with h5py.File(store, "r") as f:
        return Path(f[name].file.filename)


def _snapshot(store: Path) -> dict[str, bytes]:
    """The bytes of the store file and of every part file."""
    return {p.name: p.read_bytes() for p in [store, *sorted(parts_dir(store).glob("*"))]}


def _flip(store: Path, name: str, offset: int) -> dict[str, bytes]:
    """Flip one byte at ``offset`` in the file holding ``name``; the store's bytes after."""
    path = _holder(store, name)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
    return _snapshot(store)


def test_a_store_written_by_the_stages_passes_every_check(store):
    r = run_vfcli("info", "--verify", store)
    assert r.returncode == 0, r.stderr
    for stage in ("/hsc", "/ldv", "/sync", "/mesh"):
        assert any(line.split()[:1] == [stage] and line.rstrip().endswith("ok") for line in r.stdout.splitlines()), r.stdout


# ------------------------------------------------------------------ flipped bytes

@pytest.mark.parametrize("obj, delta", [("/hsc/frames", 0), ("/hsc/frames", 9), ("/hsc/frames", 23),
                                        ("/mesh", 0), ("/mesh", 17), ("/mesh/nodes", 30),
                                        ("/sync", 15), ("/sync/aligned_w", 40), ("/", 11), ("/", 40)])
def test_a_flipped_byte_in_an_object_header_is_exit_4_and_never_carried_forward(store, obj, delta):
    damaged = _flip(store, obj, _header_address(_holder(store, obj), obj) + delta)
    _one_line_exit_4(run_vfcli("info", store))
    for args in (["mesh", "-q", "--force", store], ["sync", "-q", "--force", store], ["sync", "-q", store]):
        r = run_vfcli(*args)
        if obj.startswith("/sync/") and args[0] == "sync":
            # a dataset of /sync damaged in /sync's part file: `sync` writes the stage anew into a new
            # part file (it reads nothing of the old one) and the damaged file is no longer linked
            assert r.returncode == 0, r.stderr
            assert run_vfcli("info", "--verify", store).returncode == 0
            return
        _one_line_exit_4(r)
        assert _snapshot(store) == damaged, args


def _data_offset(path: Path, name: str, chunk: int | None = None) -> tuple[int, int]:
    """(file offset, size) of a contiguous dataset's data, or of one chunk of a chunked one."""
    with h5py.File(_holder(path, name), "r") as f:
        ds = f[name]
        if chunk is None:
            return ds.id.get_offset(), ds.id.get_storage_size()
        info = ds.id.get_chunk_info(chunk)
        return info.byte_offset, info.size


def test_a_flipped_byte_in_a_dataset_read_whole_is_exit_4_naming_it(store):
    off, size = _data_offset(store, "/hsc/pressure")
    damaged = _flip(store, "/hsc/pressure", off + size // 2)
    r = run_vfcli("sync", "-q", "--force", store)
    _one_line_exit_4(r, "/hsc/pressure", "SHA-256")
    assert _snapshot(store) == damaged


def test_a_flipped_bit_in_a_video_frame_is_found_by_info_verify(store):
    """N-bit frame chunks are read without a checksum on the hot path; `info --verify` checks them."""
    off, size = _data_offset(store, "/hsc/frames", chunk=7)
    damaged = _flip(store, "/hsc/frames", off + size // 3)
    assert run_vfcli("info", store).returncode == 0  # documented: structure only
    _one_line_exit_4(run_vfcli("info", "--verify", store), "/hsc/frames", "SHA-256")
    assert _snapshot(store) == damaged


# ------------------------------------------------------------------ hand edits

def _edit(store: Path, how, stage: str = "/") -> dict[str, bytes]:
    """Edit with h5py the file holding ``stage`` (the paths inside a part file are the store's)."""
    with h5py.File(_holder(store, stage), "r+") as f:
        how(f)
    return _snapshot(store)


def test_a_dataset_deleted_by_hand_is_damaged_not_up_to_date(store):
    edited = _edit(store, lambda f: f.__delitem__("/hsc/frames"), "/hsc")
    r = run_vfcli("info", store)
    _one_line_exit_4(r, "/hsc/frames is missing")
    assert "DAMAGED" in r.stdout and "/ldv" in r.stdout
    _one_line_exit_4(run_vfcli("sync", "-q", store), "/hsc/frames is missing", "vfcli ingest-hsc")
    assert _snapshot(store) == edited


def test_a_deleted_digest_is_exit_4(store):
    edited = _edit(store, lambda f: f["/hsc"].attrs.__delitem__("digest"), "/hsc")
    _one_line_exit_4(run_vfcli("info", store), "/hsc", "'digest'")
    _one_line_exit_4(run_vfcli("sync", "-q", "--force", store), "/hsc", "'digest'")
    assert _snapshot(store) == edited


def test_a_broken_recording_config_is_exit_4(store):
    edited = _edit(store, lambda f: f.attrs.__setitem__("recording_config_json", '{"camera": '))
    for args in (["info", store], ["sync", "-q", store], ["mesh", "-q", "--force", store]):
        _one_line_exit_4(run_vfcli(*args), "recording_config_json")
    assert _snapshot(store) == edited


def test_a_broken_upstream_json_is_damaged_and_rewriting_the_stage_repairs_it(store):
    edited = _edit(store, lambda f: f["/sync"].attrs.__setitem__("upstream_json", "{not json"), "/sync")
    r = run_vfcli("info", store)
    _one_line_exit_4(r, "/sync", "upstream_json")
    assert "DAMAGED" in r.stdout
    _one_line_exit_4(run_vfcli("mesh", "-q", "--force", store), "/sync", "upstream_json")  # not carried forward
    assert _snapshot(store) == edited
    assert run_vfcli("sync", "-q", store).returncode == 0  # the damaged stage itself is rewritten
    assert run_vfcli("info", "--verify", store).returncode == 0


def test_an_edited_stage_attribute_is_exit_4(store):
    def edit(f):
        name = next(k for k, v in f["/hsc"].attrs.items() if isinstance(v, float) or getattr(v, "dtype", None) == float)
        f["/hsc"].attrs[name] = f["/hsc"].attrs[name] * 2
    edited = _edit(store, edit, "/hsc")
    _one_line_exit_4(run_vfcli("sync", "-q", "--force", store), "/hsc", "attributes")
    assert _snapshot(store) == edited


# ------------------------------------------------------------------ raw inputs, locks

def test_a_changed_input_with_its_mtime_restored_is_hashed_again(tmp_path):
    raw = tmp_path / "p.csv"
    raw.write_text("t,p\n0,100\n1,200\n")
    before = describe_inputs([raw])
    st = raw.stat()
    time.sleep(0.01)
    raw.write_text("t,p\n0,100\n1,900\n")  # same size
    os.utime(raw, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert raw.stat().st_mtime_ns == st.st_mtime_ns and raw.stat().st_size == st.st_size
    after = describe_inputs([raw], previous=before)
    assert after[str(raw.resolve())]["sha256"] != before[str(raw.resolve())]["sha256"]
    assert describe_inputs([raw], previous=after) == after  # untouched: the cached hash is reused


def test_ingest_reruns_when_an_input_changed_under_a_restored_mtime(built, tmp_path):
    raw, _ = built
    pressure = tmp_path / "p.csv"
    shutil.copy2(raw / "video_pressure.csv", pressure)
    store = tmp_path / "rec.h5"
    args = ["ingest-hsc", "--json", store, raw / "video.cihx", "--pressure", pressure, "--config", raw / "recording.toml"]
    assert run_vfcli(*args).returncode == 0
    assert json.loads(run_vfcli(*args).stdout)["status"] == "up-to-date"
    st = pressure.stat()
    lines = pressure.read_text().splitlines(keepends=True)
    i = next(k for k, line in enumerate(lines) if line[:1].isdigit() and "1" in line)
    lines[i] = lines[i].replace("1", "2", 1)  # a digit changed, the size kept
    pressure.write_text("".join(lines))
    os.utime(pressure, ns=(st.st_atime_ns, st.st_mtime_ns))
    r = run_vfcli(*args)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["status"] == "written"


def test_a_store_held_open_by_another_program_names_it(store):
    holder = subprocess.Popen([sys.executable, "-c", "import h5py, sys, time\nf = h5py.File(sys.argv[1], 'r+')\n"
                               "print('open', flush=True)\ntime.sleep(60)", str(store)],
                              stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "open"
        before = store.read_bytes()
        for args in (["info", store], ["sync", "-q", "--force", store]):
            r = run_vfcli(*args)
            _one_line_exit_4(r, "another program holds the store open", f"process {holder.pid}")
        assert store.read_bytes() == before
    finally:
        holder.kill()
        holder.wait()


def test_a_flipped_byte_in_a_gzip_frame_chunk_is_a_damaged_store_not_a_traceback(built, tmp_path):
    """gzip frame chunks are not checksummed by vfcli on read; zlib's own check refuses the damage."""
    from vfcli.errors import StoreDamagedError
    from vfcli.store import Store

    raw, _ = built
    store = tmp_path / "rec.h5"
    r = run_vfcli("ingest-hsc", "-q", store, raw / "video.cihx", "--pressure", raw / "video_pressure.csv",
                  "--config", raw / "recording.toml", "--set", "ingest_hsc.compression=gzip")
    assert r.returncode == 0, r.stderr
    off, size = _data_offset(store, "/hsc/frames", chunk=7)
    _flip(store, "/hsc/frames", off + size // 2)
    with Store(store).read() as rd:
        frames = rd.frames("hsc", "frames")
        assert frames[6].shape == frames.shape[1:]  # the other chunks read
    with pytest.raises(StoreDamagedError, match="damaged store"):
        with Store(store).read() as rd:
            rd.frames("hsc", "frames")[7]
