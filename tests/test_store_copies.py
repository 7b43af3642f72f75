"""Copies of a store made by hand, a store file without its folder, and the index's size (issue 18).

A hand copy ``cp rec.h5 rec2.h5`` links into ``rec.h5.parts/`` (the links are relative): the
first write to the copy gives it its own parts (hard links, else copies), and a write to
``rec.h5`` never deletes a part file another store file beside it still links to. A store
file whose parts folder is missing is one line from every command. Each commit writes a
fresh compact index, so the store file does not grow from write to write.

Real files and real `vfcli` subprocesses throughout.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import run_vfcli
from test_store_commit import _hsc_seed, _store_with_video, _temporaries, _write_hsc, _write_mesh
from vfcli.errors import EXIT_STORE
from vfcli.store import Store
from vfcli.store.parts import own_parts, parts_dir, referenced_parts


def _links(path: Path) -> set[str]:
    with h5py.File(path, "r") as f:
        return referenced_parts(f)


def _hand_copy(path: Path, name: str = "r2.h5") -> Path:
    """``cp r.h5 r2.h5``: the store file alone, in the same folder."""
    copy = path.with_name(name)
    shutil.copy2(path, copy)
    return copy


# ------------------------------------------------------------------ hand copies in one folder

def test_a_write_to_the_original_spares_the_parts_a_hand_copy_still_links_to(tmp_path):
    path = _store_with_video(tmp_path, 1, 20)
    copy = _hand_copy(path)
    shared = own_parts(path)
    assert [p.name for p in shared] == [Path(t).name for t in _links(copy)]
    _write_hsc(path, 2, 10)  # replaces /hsc in r.h5: its old part is now used by r2.h5 only
    assert _hsc_seed(path) == 2
    assert all(p.is_file() for p in shared)
    assert _hsc_seed(copy) == 1  # the copy reads its video, checked against its SHA-256
    info = json.loads(run_vfcli("info", path, "--json").stdout)
    assert info["interrupted_writes"] == []  # a part another store file uses is no leftover
    info = json.loads(run_vfcli("info", copy, "--json").stdout)
    assert info["parts_folder"] == str(parts_dir(path)) and info["parts_bytes"] == shared[0].stat().st_size


def test_the_first_write_to_a_hand_copy_gives_it_its_own_parts(tmp_path):
    path = _store_with_video(tmp_path, 3, 20)
    copy = _hand_copy(path)
    original_part = own_parts(path)[0]
    _write_mesh(copy, 2.0)  # a write that does not touch /hsc
    links = _links(copy)
    assert all(Path(t).parent.name == parts_dir(copy).name for t in links), links
    mine = own_parts(copy)
    assert [p.name for p in mine] == [original_part.name]
    # a hard link on this file system: the same bytes, no copy of the data
    assert os.stat(mine[0]).st_ino == os.stat(original_part).st_ino
    _write_hsc(path, 4, 10)  # the original moves on and collects its old part ...
    assert not original_part.exists() and _hsc_seed(path) == 4
    assert _hsc_seed(copy) == 3  # ... the copy keeps its own
    _write_hsc(copy, 5, 10)
    assert _hsc_seed(copy) == 5 and _hsc_seed(path) == 4
    assert _temporaries(path) == []


def test_a_reader_of_a_hand_copy_keeps_the_version_it_opened(tmp_path):
    """A reader opens the copy while it still links into r.h5.parts/; the copy's first write gives
    it its own parts, then a write to r.h5 collects its old part: not while the reader is open."""
    path = _store_with_video(tmp_path, 9, 20)
    copy = _hand_copy(path)
    with Store(copy).read() as r:  # this version links to r.h5.parts/hsc-...
        _write_mesh(copy, 2.0)  # the copy takes its parts over
        _write_hsc(path, 10, 10)  # r.h5 moves on (another process)
        frames = r.read("hsc", "frames")  # opens the part file only now
    assert frames.shape == (20, 128, 128) and _hsc_seed(copy) == 9
    _write_hsc(path, 11, 10)  # no reader now: the original's old part is collected
    assert len(own_parts(path)) == 1 and _hsc_seed(path) == 11 and _hsc_seed(copy) == 9


def test_a_hand_copy_without_hard_links_gets_copies(tmp_path, monkeypatch):
    """Where the file system refuses hard links (FAT, some network shares) the parts are copied."""
    path = _store_with_video(tmp_path, 6, 20)
    copy = _hand_copy(path)

    def refuse(*_a, **_k):
        raise OSError(1, "Operation not permitted")

    monkeypatch.setattr(os, "link", refuse)
    _write_mesh(copy, 2.0)
    mine, theirs = own_parts(copy), own_parts(path)
    assert len(mine) == 1 and os.stat(mine[0]).st_ino != os.stat(theirs[0]).st_ino
    assert mine[0].read_bytes() == theirs[0].read_bytes()
    _write_hsc(path, 7, 10)
    assert _hsc_seed(copy) == 6


def test_an_aborted_write_to_a_hand_copy_leaves_it_linking_to_the_original(tmp_path):
    path = _store_with_video(tmp_path, 8, 20)
    copy = _hand_copy(path)
    before = copy.read_bytes()
    with pytest.raises(RuntimeError, match="abort"):
        with Store(copy).write("t") as w:
            with w.stage("mesh", config_json="{}") as s:
                s.put("nodes", np.zeros((5, 3)))
                raise RuntimeError("abort")
    assert copy.read_bytes() == before and own_parts(copy) == []
    assert _hsc_seed(copy) == 8


# ------------------------------------------------------------------ a store file without its folder

@pytest.mark.parametrize("args", [["info"], ["config", "--set", "camera.px_per_mm=12"], ["mesh", "--force"],
                                  ["sync"], ["flow"], ["share", "OUT"], ["export", "--to", "OUT"],
                                  ["report"]])
def test_a_store_file_without_its_parts_folder_is_one_line_from_every_command(tmp_path, args):
    path = _store_with_video(tmp_path, 1, 20)
    alone = tmp_path / "elsewhere" / "r.h5"
    alone.parent.mkdir()
    shutil.copy2(path, alone)
    before = alone.read_bytes()
    args = [a if a != "OUT" else str(tmp_path / "out.h5") for a in args]
    res = run_vfcli(args[0], alone, *args[1:])
    assert res.returncode == EXIT_STORE, (args, res.stderr[-2000:])
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
    assert (f"store {alone}'s stage data folder r.h5.parts is missing; copy the folder with the file, "
            "or use `vfcli share`") in res.stderr, res.stderr
    assert alone.read_bytes() == before and not (tmp_path / "out.h5").exists()
    assert sorted(p.name for p in alone.parent.iterdir()) == ["r.h5"]


def test_one_missing_part_file_is_named(tmp_path):
    path = _store_with_video(tmp_path, 1, 20)
    own_parts(path)[0].unlink()
    res = run_vfcli("info", path)
    assert res.returncode == EXIT_STORE and res.stderr.count("\n") == 1
    assert "part file r.h5.parts/hsc-" in res.stderr and "is missing" in res.stderr


# ------------------------------------------------------------------ the index does not grow

def _config_writes(path: Path, n: int) -> list[int]:
    sizes = []
    for i in range(n):
        with Store(path).write("config") as w:
            w.set_recording_config(json.dumps({"camera": {"px_per_mm": 9.0 + (i % 2) * 0.5}, "i": i}))
        sizes.append(path.stat().st_size)
    return sizes


def test_the_store_file_stays_the_same_size_over_50_config_writes(tmp_path):
    path = _store_with_video(tmp_path, 1, 20)
    sizes = _config_writes(path, 50)
    # the config JSON differs in length by one character between writes 9 and 10 (i: 9 -> 10)
    assert max(sizes[10:]) - min(sizes[10:]) <= 64, sizes
    assert max(sizes) < 40_000, sizes
    with Store(path).read() as r:
        assert json.loads(r.recording_config_json())["i"] == 49
    assert _hsc_seed(path) == 1
