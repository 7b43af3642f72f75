"""The commit (issue 18, "Writes that cost what they change"): a write costs what it writes, not the
store; symlinks, permissions and a user's files survive; SIGTERM, Ctrl-C and a full disk abort
cleanly; part files no index links to are collected; `vfcli share` makes one self-contained file.

Signals and the full disk are real: subprocesses killed with real signals, and a real file-size
limit (RLIMIT_FSIZE, the kernel refuses the write with EFBIG as a full disk does with ENOSPC).
"""
from __future__ import annotations

import json
import os
import resource
import signal
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import run_vfcli, sigint_default
from store_writer_proc import frames_for
from vfcli.errors import StoreAccessError, StoreLockedError
from vfcli.store import Store
from vfcli.store.parts import copy_store, own_parts, parts_dir

HERE = Path(__file__).resolve().parent

#: A writer that prints "writing" once the /hsc part file has frames in it, then holds the
#: transaction open for HOLD seconds (inside the stage), then commits.
#: usage: python -c WRITER STORE SEED N_FRAMES HOLD
WRITER = """
import sys
import numpy as np
from store_writer_proc import frames_for, hold
from vfcli.errors import VfcliError
from vfcli.store import Store
path, seed, n, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
frames = frames_for(seed, n)
try:
    with Store(path).write(f"writer {seed}") as w:
        with w.stage("hsc", config_json='{"seed": %d}' % seed) as s:
            s.write_frames("frames", frames.shape, np.uint16, (frames[a:a + 16] for a in range(0, n, 16)))
            s.put("frame_time", np.arange(n) / 10000.0)
            s.set_attrs(seed=seed)
            print("writing", flush=True)
            hold(seconds)
except VfcliError as exc:
    print(exc, file=sys.stderr)
    sys.exit(exc.exit_code)
"""


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parent), str(HERE)])}


def _writer(path: Path, seed: int, n: int, hold: float = 0.0, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(seed), str(n), str(hold)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            preexec_fn=sigint_default, **kw)


def _write_mesh(path: Path, value: float = 1.0) -> None:
    with Store(path).write("t") as w:
        with w.stage("mesh", config_json="{}") as s:
            s.put("nodes", np.full((5, 3), value))


def _write_hsc(path: Path, seed: int, n: int) -> None:
    proc = _writer(path, seed, n)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err


def _store_with_video(tmp_path: Path, seed: int, n: int) -> Path:
    """``tmp_path/r.h5`` with /mesh (in the store file) and /hsc (in its part file)."""
    path = tmp_path / "r.h5"
    _write_mesh(path)
    _write_hsc(path, seed, n)
    return path


def _hsc_seed(path: Path) -> int | None:
    with Store(path).read() as r:
        if not r.has_stage("hsc"):
            return None
        seed = int(r.attrs("hsc")["seed"])
        frames = r.read("hsc", "frames")  # checked against the stage's SHA-256
        np.testing.assert_array_equal(frames, frames_for(seed, len(frames)))
        return seed


def _snapshot(path: Path) -> dict[str, bytes]:
    """Every file of the store (its file, its parts) and of its folder, by name."""
    files = [p for p in path.parent.iterdir() if p.is_file()] + own_parts(path)
    return {str(p.relative_to(path.parent)): p.read_bytes() for p in sorted(files)}


def _temporaries(path: Path) -> list[str]:
    return sorted(p.name for p in path.parent.iterdir() if ".vfcli-" in p.name or ".tmp" in p.name)


# ------------------------------------------------------------------ cost

def test_a_small_write_copies_only_the_small_index_and_never_touches_the_video(tmp_path):
    """The video lives in its part file; a mesh write copies the store file (kilobytes) and
    leaves the video's file as it was (same inode, same bytes): the cost of a write does not
    grow with the video."""
    path = tmp_path / "r.h5"
    _write_mesh(path)
    _write_hsc(path, 1, 400)
    (video,) = own_parts(path)
    before = video.stat()
    assert path.stat().st_size < 64_000 < 20 * 64_000 < before.st_size
    _write_mesh(path, 2.0)
    after = video.stat()
    assert (after.st_ino, after.st_mtime_ns, after.st_size) == (before.st_ino, before.st_mtime_ns, before.st_size)
    assert path.stat().st_size < 64_000
    assert _hsc_seed(path) == 1
    with Store(path).read() as r:
        assert r.read("mesh", "nodes")[0, 0] == 2.0


def test_a_rewritten_stage_leaves_one_part_file_and_a_reader_keeps_the_version_it_opened(tmp_path):
    path = tmp_path / "r.h5"
    _write_hsc(path, 1, 40)
    with Store(path).read() as r:  # opened before the rewrite, read after it
        _write_hsc(path, 2, 40)
        np.testing.assert_array_equal(r.read("hsc", "frames"), frames_for(1, 40))
    assert len(own_parts(path)) == 2  # the reader's version was kept while it was open
    _write_mesh(path)  # the next writer collects it
    assert len(own_parts(path)) == 1
    assert _hsc_seed(path) == 2


# ------------------------------------------------------------------ links, permissions, a user's files

def test_a_symlinked_store_stays_a_symlink_and_shares_its_targets_lock(tmp_path):
    target_dir, link_dir = tmp_path / "data", tmp_path / "work"
    target_dir.mkdir()
    link_dir.mkdir()
    target, link = target_dir / "r.h5", link_dir / "r.h5"
    _write_mesh(target)
    link.symlink_to(target)
    _write_hsc(link, 3, 20)
    assert link.is_symlink() and os.path.realpath(link) == str(target)
    assert _hsc_seed(target) == 3 and _hsc_seed(link) == 3
    assert own_parts(target) and not parts_dir(link).exists()
    holder = _writer(link, 4, 20, hold=30)
    try:
        assert holder.stdout.readline().strip() == "writing"
        with pytest.raises(StoreLockedError):
            with Store(target).write("second"):
                pass
    finally:
        holder.kill()
        holder.wait()


def test_a_private_store_stays_private_and_a_read_only_one_is_refused(tmp_path):
    path = tmp_path / "r.h5"
    _write_mesh(path)
    os.chmod(path, 0o600)
    _write_hsc(path, 1, 20)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert [stat.S_IMODE(p.stat().st_mode) for p in own_parts(path)] == [0o600]
    os.chmod(path, 0o444)
    before = _snapshot(path)
    res = run_vfcli("mesh", path, "--force")
    assert res.returncode == 4, res.stderr
    assert res.stderr.count("\n") == 1 and "read-only" in res.stderr and "Traceback" not in res.stderr
    assert _snapshot(path) == before
    with pytest.raises(StoreAccessError, match="read-only"):
        with Store(path).write("t"):
            pass


def test_only_vfclis_own_temporary_files_are_removed(tmp_path):
    path = tmp_path / "rec.h5"
    _write_mesh(path)
    mine = [tmp_path / ".rec.h5.vfcli-123-0a1b2c3d.tmp", tmp_path / "rec.h5.tmp-4567"]
    users = [tmp_path / "rec.h5.tmp-notes.txt", tmp_path / ".rec.h5.vfcli-notes.tmp", tmp_path / "rec.h5.tmp-12.bak"]
    for p in mine + users:
        p.write_text("x")
    assert sorted(Store(path).interrupted_writes()) == sorted(mine)
    _write_mesh(path, 2.0)
    assert [p.exists() for p in mine] == [False, False]
    assert all(p.read_text() == "x" for p in users)


# ------------------------------------------------------------------ aborts

def test_a_write_that_fails_leaves_no_empty_parts_folder(tmp_path):
    """`vfcli ingest-hsc` into a store that does not exist yet, of a video it refuses: exit 3, and the folder
    holds what it held (the lock file aside, which every write makes); before session 34 an empty
    ``new.h5.parts/`` was left behind, a parts folder without its store. An aborted write to a store with no
    part files leaves none either; a store's parts folder that holds its parts stays as it was."""
    (tmp_path / "v.avi").write_text("not a video\n")
    res = run_vfcli("ingest-hsc", tmp_path / "new.h5", tmp_path / "v.avi", "--set", "camera.fps_hz=250")
    assert res.returncode == 3 and "not an AVI file" in res.stderr, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [".new.h5.lock", "v.avi"]

    def aborted_write(path: Path) -> None:
        with pytest.raises(RuntimeError):
            with Store(path).write("test") as w:
                with w.stage("sync", config_json="{}") as s:
                    s.put("offset_s", np.arange(3.0))
                    raise RuntimeError("abort")

    path = tmp_path / "r.h5"
    _write_mesh(path, 1.0)                       # /mesh lives in the store file itself
    aborted_write(path)
    assert not parts_dir(path).exists()
    (tmp_path / "v").mkdir()
    video = _store_with_video(tmp_path / "v", 1, 5)
    before = sorted(p.name for p in parts_dir(video).iterdir())
    aborted_write(video)
    assert sorted(p.name for p in parts_dir(video).iterdir()) == before and len(before) == 1



@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 128 + signal.SIGTERM), (signal.SIGINT, None)])
def test_sigterm_and_sigint_abort_the_write_and_remove_its_temporary_data(tmp_path, sig, code):
    path = tmp_path / "r.h5"
    _write_hsc(path, 1, 40)
    before = _snapshot(path)
    proc = _writer(path, 2, 200, hold=30)
    assert proc.stdout.readline().strip() == "writing"  # the new part file holds 200 frames now
    assert len(own_parts(path)) == 2
    proc.send_signal(sig)
    proc.wait(timeout=20)
    if code is not None:
        assert proc.returncode == code
    else:
        assert proc.returncode != 0
    assert _snapshot(path) == before
    assert _temporaries(path) == [] and len(own_parts(path)) == 1
    assert _hsc_seed(path) == 1


def _no_room_writer(path: Path, seed: int, n: int, limit: int) -> subprocess.CompletedProcess:
    """The writer under a real file-size limit: the kernel refuses writes past ``limit`` bytes
    with EFBIG (SIGXFSZ ignored), as a full disk refuses them with ENOSPC."""
    def limited() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run([sys.executable, "-c", WRITER, str(path), str(seed), str(n), "0"], capture_output=True,
                          text=True, env=_env(), preexec_fn=limited, timeout=120)


@pytest.mark.parametrize("n_frames", [400, 3000])
def test_a_write_that_finds_no_room_is_one_line_exit_4_and_leaves_nothing(tmp_path, n_frames):
    path = _store_with_video(tmp_path, 1, 20)
    before = _snapshot(path)
    res = _no_room_writer(path, 2, n_frames, limit=3_000_000)  # 400 frames: 6.5 MB; 3000 frames: 49 MB
    assert res.returncode == 4, res.stderr[-3000:]
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
    assert "not enough disk space" in res.stderr and "needs at least" in res.stderr and "MB" in res.stderr
    assert "file-size limit" in res.stderr
    assert _snapshot(path) == before
    assert _temporaries(path) == [] and len(own_parts(path)) == 1
    assert _hsc_seed(path) == 1


# ------------------------------------------------------------------ copies

def _all_links(g: h5py.Group, prefix: str = "") -> list[tuple[str, object]]:
    out = []
    for key in g:
        link = g.get(key, getlink=True)
        out.append((prefix + key, link))
        if isinstance(link, h5py.HardLink) and isinstance(g[key], h5py.Group):
            out += _all_links(g[key], prefix + key + "/")
    return out


def test_share_makes_one_self_contained_file_and_copy_store_a_working_copy(tmp_path):
    path = _store_with_video(tmp_path, 5, 30)
    out = tmp_path / "shared" / "alone.h5"
    out.parent.mkdir()
    res = run_vfcli("share", path, out)
    assert res.returncode == 0, res.stderr
    with h5py.File(out, "r") as f:
        links = [name for name, link in _all_links(f) if isinstance(link, h5py.ExternalLink)]
        np.testing.assert_array_equal(f["hsc/frames"][()], frames_for(5, 30))
    assert links == [] and not parts_dir(out).exists()
    assert _hsc_seed(out) == 5
    copy = tmp_path / "elsewhere" / "renamed.h5"
    copy.parent.mkdir()
    copy_store(path, copy)
    assert _hsc_seed(copy) == 5
    _write_hsc(copy, 6, 10)  # a write to the copy leaves the original alone
    assert _hsc_seed(path) == 5 and _hsc_seed(copy) == 6


def test_info_says_a_store_is_a_file_plus_its_parts_folder(tmp_path):
    path = tmp_path / "r.h5"
    _write_hsc(path, 1, 20)
    res = run_vfcli("info", path)
    assert res.returncode == 0, res.stderr
    assert str(parts_dir(path).name) in res.stdout and "vfcli share" in res.stdout
    info = json.loads(run_vfcli("info", path, "--json").stdout)
    assert info["parts_folder"] == str(parts_dir(path)) and info["parts_bytes"] > info["size_bytes"]


# ------------------------------------------------------------------ flow: one transaction

def test_flow_commits_flow_and_fields_together_or_neither(tmp_path):
    """/fields fails after /flow was computed (no LDV point on the frames: exit 3): /flow is not
    committed either, the store is unchanged."""
    from test_flow_stage import SlitPhantom, run_flow_cli, write_store

    ph = SlitPhantom(height=64, width=64, midline_row=31.3, glottis_cols=(4, 60), lam_px=11.0)
    path = tmp_path / "r.h5"
    write_store(path, np.stack([ph.render(ph.frame_time(k)) for k in range(4, 28, 2)]), ph.fps, ph.px_per_mm)
    with Store(path).read() as r:
        coords, dropout = r.read("ldv", "coords_mm"), r.read("ldv", "dropout")
    with Store(path).write("scan moved off the image") as w:
        with w.stage("ldv", config_json="{}") as s:
            s.put("coords_mm", coords + [1000.0, 1000.0, 0.0])
            s.put("dropout", dropout)
    before = _snapshot(path)
    res = run_flow_cli(path, "--set", "flow.subpixel_edges=false")
    assert res.returncode == 3, res.stderr[-2000:]
    assert "none of the" in res.stderr and "LDV points" in res.stderr
    assert _snapshot(path) == before and _temporaries(path) == []
    with Store(path).read() as r:
        assert not r.has_stage("flow", complete=False) and not r.has_stage("fields", complete=False)


def test_a_store_file_copied_without_its_parts_folder_is_one_clear_line(tmp_path):
    path = _store_with_video(tmp_path, 1, 20)
    alone = tmp_path / "alone" / "r.h5"
    alone.parent.mkdir()
    alone.write_bytes(path.read_bytes())
    for args in (["info", alone], ["mesh", "--force", alone]):
        res = run_vfcli(*args)
        assert res.returncode == 4, res.stderr
        assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
        assert "stage data folder r.h5.parts is missing" in res.stderr and "vfcli share" in res.stderr


def test_a_store_of_an_earlier_vfcli_moves_its_stages_to_part_files_on_the_first_write(tmp_path):
    """A store with every stage inside its file (as vfcli wrote them before part files; `vfcli
    share` still writes one): the first write moves them out and shrinks the file; the values,
    digests and checks are unchanged, nothing becomes stale."""
    path = _store_with_video(tmp_path, 4, 200)
    old = tmp_path / "old" / "r.h5"
    old.parent.mkdir()
    assert run_vfcli("share", path, old, "--compression", "nbit").returncode == 0
    with h5py.File(old, "r") as f:
        assert isinstance(f.get("hsc", getlink=True), h5py.HardLink)
    size_before = old.stat().st_size
    before = json.loads(run_vfcli("info", old, "--json").stdout)
    _write_mesh(old, 3.0)
    assert old.stat().st_size < 64_000 < size_before / 20
    assert [p.name.split("-")[0] for p in own_parts(old)] == ["hsc"]
    assert _hsc_seed(old) == 4
    res = run_vfcli("info", old, "--verify", "--json")
    assert res.returncode == 0, res.stderr
    after = {s["path"]: s for s in json.loads(res.stdout)["stages"]}
    assert after["/hsc"]["provenance"]["digest"] == {s["path"]: s for s in before["stages"]}["/hsc"]["provenance"]["digest"]
    assert not after["/hsc"]["stale"] and not after["/hsc"]["damaged"]


# ------------------------------------------------------------------ flow on a full disk

@pytest.fixture(scope="module")
def flow_ready(tmp_path_factory) -> Path:
    """A store with /hsc, /ldv and /sync (tests/test_flow_stage.py's slit phantom, 24 frames of
    256 x 256, shared with it: read-only): `vfcli flow` writes about 9 MB of /flow and 7.4 MB of /fields."""
    from test_flow_stage import slit_store

    return slit_store(tmp_path_factory)[0]


def test_synth_that_finds_no_room_is_one_line_exit_4_and_leaves_nothing(tmp_path):
    """`vfcli synth` under a real file-size limit below the size of its truth.h5: it printed libhdf5's
    traceback and crashed at exit (SIGSEGV, flushing the truth file whose close had failed), as it did on
    session 21's full /tmp.  Now: one line naming the folder and the limit, exit 4, no folder, no temporary."""
    out = tmp_path / "raw"

    def limited() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2_000_000, 2_000_000))

    # a small phantom (3 s to make, 19 s at the synth's default size): its truth.h5 (12 MB) and scan.uff
    # (10 MB) are still far above the limit
    small = ["synth.duration_s=0.01", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
             "synth.width_px=112", "synth.height_px=112", "synth.px_per_mm=6", "synth.supersample=1"]
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", "synth", str(out), "--seed", "3",
                          *sum((["--set", s_] for s_ in small), [])], capture_output=True, text=True, env=_env(),
                         preexec_fn=limited, timeout=600)
    assert res.returncode == 4, res.stderr[-3000:]
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert "not enough disk space" in res.stderr and "file-size limit" in res.stderr and str(out) in res.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("limit", [300_000, 3_000_000, 8_000_000])
def test_flow_that_finds_no_room_is_one_line_exit_4_and_leaves_nothing(flow_ready, tmp_path, limit):
    """`vfcli flow` under a real file-size limit (EFBIG, as ENOSPC on a full disk) below the size
    of its /flow part file: it crashed (SIGSEGV, exit 139: libhdf5 flushing at exit a part file
    whose close had failed) after printing its error, or blamed a damaged store."""
    path = tmp_path / "r.h5"
    copy_store(flow_ready, path)
    for lock in (".r.h5.lock", ".r.h5.readers"):  # made by the first write (empty)
        (tmp_path / lock).touch()
    before = _snapshot(path)

    def limited() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", "flow", str(path)], capture_output=True, text=True,
                         env=_env(), preexec_fn=limited, timeout=600)
    assert res.returncode == 4, res.stderr[-3000:]
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr and "Exception ignored" not in res.stderr, \
        res.stderr[-3000:]
    assert "not enough disk space" in res.stderr and "file-size limit" in res.stderr
    assert _snapshot(path) == before
    assert _temporaries(path) == [] and len(own_parts(path)) == 3
    if limit == 3_000_000:
        res = run_vfcli("flow", path)  # room again: the same store takes the write
        assert res.returncode == 0, res.stderr[-2000:]
