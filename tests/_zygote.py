"""`vfcli` commands for the tests, each in its own process forked from one that imported vfcli once.

A fresh ``python -m vfcli.cli.main`` spends 0.3-1.5 s of CPU starting Python and importing numpy,
scipy, h5py, OpenCV, scikit-fem and vfcli's stages before it does anything; the suite starts
several hundred of them on small phantoms, and that start-up was a fifth of its CPU time
(docs/benchmarks.md, "The suite's time (session 29)"). Here one helper process per pytest worker
(:class:`Zygote`, started on first use) imports all of that once; each command is a child
``os.fork``-ed from it, so it is still a separate process with its own pid, working directory,
environment, exit code and file descriptors, which exits as Python exits (non-daemon threads
joined, ``atexit`` handlers run, streams flushed). Only the start-up is shared; a command's
module state is the freshly imported one, as the helper runs nothing of vfcli before it forks.

Tests that signal, kill or race a command (crash, lock and interrupt tests) start the real
interpreter with ``subprocess.Popen`` themselves, and ``VFCLI_TEST_FRESH=1`` in the environment
sends every command of :func:`conftest.run_vfcli` through a fresh interpreter as well.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

#: the helper process: imports, then serves one fork per request line (JSON) on stdin,
#: answering {"pid": ...} at once and {"status": ...} (os.waitpid's) when the child ends
_SERVER = r'''
import json, os, sys, importlib
for name in sys.argv[1].split(","):
    importlib.import_module(name)
requests, replies = sys.stdin.buffer, sys.stdout.buffer

def child(req):
    os.chdir(req["cwd"])
    os.environ.clear()
    os.environ.update(req["env"])
    null = os.open(os.devnull, os.O_RDONLY)
    out = os.open(req["stdout"], os.O_WRONLY | os.O_TRUNC)
    err = os.open(req["stderr"], os.O_WRONLY | os.O_TRUNC)
    for src, dst in ((null, 0), (out, 1), (err, 2)):
        os.dup2(src, dst)
        os.close(src)
    sys.argv = [req["argv0"], *req["args"]]
    code = 0
    try:
        from vfcli.cli.main import cli
        cli.main(req["args"], prog_name="vfcli")
    except SystemExit as exc:
        c = exc.code
        if c is None:
            code = 0
        elif isinstance(c, int):
            code = c & 0xFF
        else:
            print(c, file=sys.stderr)
            code = 1
    except BaseException:
        import traceback
        traceback.print_exc()
        code = 1
    # as the interpreter's own exit: threads joined, atexit handlers run, streams flushed
    import threading, atexit
    try:
        threading._shutdown()
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(code)

replies.write(b"ready\n"); replies.flush()
for line in requests:
    req = json.loads(line)
    sys.stdout.flush(); sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        child(req)
    replies.write(json.dumps({"pid": pid}).encode() + b"\n"); replies.flush()
    _, status = os.waitpid(pid, 0)
    replies.write(json.dumps({"status": status}).encode() + b"\n"); replies.flush()
'''

#: what the helper imports before it forks: the heavy libraries and every stage's command module
PRELOAD = ("numpy", "scipy.sparse.linalg", "scipy.optimize", "scipy.interpolate", "scipy.spatial", "scipy.signal",
           "scipy.ndimage", "h5py", "cv2", "skfem", "pydantic", "click", "matplotlib", "matplotlib.pyplot",
           "vfcli.cli.main", "vfcli.diagnose.run", "vfcli.stages.export_job",
           *(f"vfcli.cli.{c}" for c in ("ingest", "sync", "flow", "mesh", "optimize", "export", "run", "synth",
                                        "diagnose", "report", "config", "info")),
           *(f"vfcli.stages.{s}" for s in ("ingest", "sync", "flow", "mesh", "optimize", "export", "run", "synth",
                                           "diagnose", "report")))


class Zygote:
    """One helper process (see the module's docstring); :meth:`run` is ``subprocess.run``'s result."""

    def __init__(self, root: Path, executable: str = sys.executable):
        self.root = root
        self.argv0 = str(root / "vfcli" / "cli" / "main.py")
        env = {**os.environ, "PYTHONPATH": str(root)}
        modules = [m for m in PRELOAD if _importable(m)]
        self.proc = subprocess.Popen([executable, "-c", _SERVER, ",".join(modules)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, env=env, cwd=root, bufsize=0)
        self._pending = b""   # bytes of the helper's replies read but not yet used (os.read, no hidden buffer)
        if self._line(None) != b"ready":
            raise RuntimeError("the vfcli test helper process did not start")
        self._lock = threading.Lock()   # one request at a time: a test's threads may share the helper

    def alive(self) -> bool:
        return self.proc.poll() is None

    def run(self, args: list[str], cwd: Path | None, env: dict[str, str], timeout: float
            ) -> subprocess.CompletedProcess:
        with self._lock, tempfile.TemporaryDirectory(prefix="vfcli-zygote-") as tmp:
            out, err = Path(tmp) / "stdout", Path(tmp) / "stderr"
            out.touch()
            err.touch()
            req = {"args": args, "cwd": str(cwd or os.getcwd()), "env": env, "stdout": str(out),
                   "stderr": str(err), "argv0": self.argv0}
            self.proc.stdin.write(json.dumps(req).encode() + b"\n")
            self.proc.stdin.flush()
            pid = json.loads(self._line(None))["pid"]
            reply = self._line(timeout)
            ready = reply is not None
            if not ready:
                os.kill(pid, signal.SIGKILL)
                reply = self._line(None)
            status = json.loads(reply)["status"]
            stdout, stderr = out.read_text(errors="replace"), err.read_text(errors="replace")
        cmd = [sys.executable, "-m", "vfcli.cli.main", *args]
        if not ready:
            raise subprocess.TimeoutExpired(cmd, timeout, output=stdout, stderr=stderr)
        return subprocess.CompletedProcess(cmd, os.waitstatus_to_exitcode(status), stdout, stderr)

    def _line(self, timeout: float | None) -> bytes | None:
        """The helper's next reply line (without its newline), or None when ``timeout`` s pass first."""
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._pending:
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                return None
            chunk = os.read(fd, 65536)
            if not chunk:
                raise RuntimeError("the vfcli test helper process ended")
            self._pending += chunk
        line, self._pending = self._pending.split(b"\n", 1)
        return line

    def close(self) -> None:
        if self.alive():
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _importable(module: str) -> bool:
    """Whether ``module`` is installed (an optional library may not be)."""
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False
