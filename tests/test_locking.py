"""File systems without locks (NFS without lockd, Lustre without -o flock): the failing lock
is simulated in a real `vfcli` subprocess, and vfcli must say in one line what to do (exit 4),
leave the store byte for byte as it was, and never hang."""
from __future__ import annotations

import errno
import os
import subprocess
import textwrap
from pathlib import Path

import pytest

from conftest import ROOT, VFCLI
from vfcli.store import Store
from vfcli.store.locking import lock_unsupported

# A libc shim: flock() fails as on a file system without locks, with the errno in FAKE_FLOCK_ERRNO.
# It stands for the NFS/Lustre mount for vfcli's own lock (Python's fcntl.flock calls libc's
# flock) and for libhdf5's lock of the HDF5 file alike.
SHIM_C = r"""
#include <errno.h>
#include <stdlib.h>
int flock(int fd, int op) { (void)fd; (void)op; errno = atoi(getenv("FAKE_FLOCK_ERRNO")); return -1; }
"""


@pytest.fixture(scope="module")
def shim(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("shim")
    (d / "shim.c").write_text(SHIM_C)
    subprocess.run(["cc", "-shared", "-fPIC", "-o", str(d / "noflock.so"), str(d / "shim.c")], check=True)
    return d / "noflock.so"


@pytest.fixture
def store(tmp_path) -> Path:
    path = tmp_path / "rec.h5"
    with Store(path).write("test"):
        pass
    return path


def _run(args, env_extra, timeout=120):
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env_extra}
    return subprocess.run([*VFCLI, *map(str, args)], capture_output=True, text=True, env=env, timeout=timeout)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")}


@pytest.mark.parametrize("code", [errno.ENOLCK, 524])
def test_python_flock_failing_says_what_to_do_and_leaves_the_store(tmp_path, store, code):
    """fcntl.flock raising OSError(37 / 524) (a sitecustomize in the subprocess): vfcli's own lock."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(textwrap.dedent(f"""
        import fcntl
        def _flock(fd, op):
            raise OSError({code}, "No locks available")
        fcntl.flock = _flock
    """))
    before = _files(store.parent)
    res = _run(["config", store, "--set", "camera.px_per_mm=12"], {"PYTHONPATH": f"{site}{os.pathsep}{ROOT}"})
    assert res.returncode == 4, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"errno {code}" in lines[0] and "node-local disk" in lines[0] and str(store) in lines[0]
    assert _files(store.parent) == before  # nothing written, no temporary file left


@pytest.mark.parametrize("code", [errno.ENOLCK, 524])
def test_libc_flock_failing_stops_a_writer_in_one_line(store, shim, code):
    """With libhdf5's lock off (as the HDF5 message advises), vfcli's own flock fails next."""
    before = _files(store.parent)
    env = {"LD_PRELOAD": str(shim), "FAKE_FLOCK_ERRNO": str(code), "HDF5_USE_FILE_LOCKING": "FALSE"}
    res = _run(["config", store, "--set", "camera.px_per_mm=12"], env)
    assert res.returncode == 4, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"errno {code}" in res.stderr and "cannot keep two writers apart" in res.stderr
    assert _files(store.parent) == before


def test_hdf5_file_lock_failing_names_the_environment_variable(store, shim):
    """A reader: libhdf5 locks the file it opens; its failure is not "another program holds it"."""
    env = {"LD_PRELOAD": str(shim), "FAKE_FLOCK_ERRNO": str(errno.ENOLCK)}
    res = _run(["info", store], env)
    assert res.returncode == 4, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "HDF5_USE_FILE_LOCKING=FALSE" in res.stderr and "errno 37" in res.stderr
    assert "another program" not in res.stderr
    # a writer stops at the same point, before writing anything
    before = _files(store.parent)
    res = _run(["config", store, "--set", "camera.px_per_mm=12"], env)
    assert res.returncode == 4 and "HDF5_USE_FILE_LOCKING=FALSE" in res.stderr, res.stderr
    assert _files(store.parent) == before
    # ... and what the message says works: the same read without libhdf5's lock
    res = _run(["info", store], {**env, "HDF5_USE_FILE_LOCKING": "FALSE"})
    assert res.returncode == 0, res.stderr


def test_lock_held_by_another_process_is_not_taken_for_a_missing_lock():
    assert lock_unsupported(OSError(errno.EWOULDBLOCK, "Resource temporarily unavailable")) is None
    assert lock_unsupported(OSError(errno.ENOLCK, "No locks available")) == errno.ENOLCK
    h5_text = "Unable to synchronously open file (unable to lock file, errno = 524, error message = 'Unknown error 524')"
    assert lock_unsupported(OSError(h5_text)) == 524
    h5_held = "Unable to synchronously open file (unable to lock file, errno = 11, error message = 'Resource temporarily unavailable')"
    assert lock_unsupported(OSError(h5_held)) is None

