"""vfcli.parallel's in-process maps of `--jobs` (the diagnosis's profile values and refits): ThreadMap,
vfcli.fork_map.ForkMap and local_map's choice, and the command line's option."""
from __future__ import annotations

import threading
import time

import pytest

from vfcli.parallel import ThreadMap, available_cores, local_map


def test_results_come_in_the_items_order_from_several_threads():
    """The later items end first (they sleep less); the results are still in the items' order, and the pieces ran
    on more than one thread at once."""
    running, most, names = [0], [0], set()
    lock = threading.Lock()

    def piece(i):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
            names.add(threading.current_thread().name)
        time.sleep(0.05 * (4 - i))
        with lock:
            running[0] -= 1
        return i * i

    assert ThreadMap(2)(piece, range(4)) == [0, 1, 4, 9]
    assert most[0] == 2 and len(names) == 2 and threading.current_thread().name not in names


def test_the_first_error_in_the_items_order_is_raised_after_every_piece_ended():
    ended = []

    def piece(i):
        if i in (1, 2):
            time.sleep(0.05 * (3 - i))            # item 2 fails first in time, item 1 first in order
            raise ValueError(f"piece {i}")
        time.sleep(0.1)
        ended.append(i)
        return i

    with pytest.raises(ValueError, match="piece 1"):
        ThreadMap(2)(piece, range(4))
    assert sorted(ended) == [0, 3]


def test_one_thread_is_the_caller_s_own_and_the_default_is_the_cores_it_may_use():
    from vfcli.fork_map import ForkMap

    assert local_map(1) is None
    default = local_map(None)
    cores = available_cores()
    assert (default is None) if cores == 1 else (isinstance(default, ForkMap) and default.n == cores)
    assert isinstance(local_map(3), ForkMap)                 # on Linux: forked children
    with pytest.raises(ValueError, match="at least 1"):
        local_map(0)


@pytest.mark.parametrize("command", ["diagnose", "run"])
def test_jobs_below_one_is_refused_in_one_line_before_anything_runs(vfcli, tmp_path, command):
    store = tmp_path / "rec.h5"
    res = vfcli(command, store, "--jobs", "0")
    assert res.returncode == 2 and "'--jobs'" in res.stderr and "0 is not in the range x>=1" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr and not store.exists()


def test_forked_pieces_see_the_caller_s_memory_and_send_back_their_results_in_order():
    """Each piece runs in a child forked when it starts: it reads what the caller holds without its being pickled
    (a lambda over a local array, which no pickling map could send), runs beside the others (their process ids
    differ from the caller's and from each other's) and its result comes back in the items' order."""
    import os

    import numpy as np

    from vfcli.fork_map import ForkMap

    held = np.arange(1000.0)

    def piece(i):
        time.sleep(0.05 * (4 - i))                      # the later items end first
        return os.getpid(), float(held[i] * 2)

    got = ForkMap(2)(lambda i: piece(i), range(4))
    assert [v for _, v in got] == [0.0, 2.0, 4.0, 6.0]
    pids = {p for p, _ in got}
    assert len(pids) == 4 and os.getpid() not in pids


def test_a_forked_piece_s_error_comes_back_with_its_traceback_and_a_dead_one_says_how_it_died():
    import os
    import signal

    from vfcli.fork_map import ForkMap, PieceDied, RemoteTraceback

    def failing(i):
        if i == 1:
            raise ValueError("piece one is wrong")
        return i

    with pytest.raises(ValueError, match="piece one is wrong") as info:
        ForkMap(2)(failing, range(3))
    assert isinstance(info.value.__cause__, RemoteTraceback) and "in failing" in str(info.value.__cause__)

    def killed(i):
        if i == 2:
            os.kill(os.getpid(), signal.SIGKILL)
        return i

    with pytest.raises(PieceDied, match=r"piece 3 of 3: .*killed by SIGKILL"):
        ForkMap(2)(killed, range(3))


_INTERRUPTED = """
import os, sys, time
from vfcli.fork_map import ForkMap

def piece(i):
    os.write(1, f"{os.getpid()}\\n".encode())      # one write: print's two would interleave with the other child's
    time.sleep(60)

try:
    ForkMap(2)(piece, range(4))
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def test_ctrl_c_while_forked_pieces_run_kills_and_reaps_them_at_once():
    """A real SIGINT to the caller (a process of its own) while two children sleep: it ends within seconds, not
    after their minute, and leaves no child behind (each pid the children printed is gone)."""
    import os
    import signal
    import subprocess
    import sys

    from conftest import ROOT, sigint_default

    # SIGINT at its default in the child: a suite started where SIGINT is ignored (a script's background job) passed
    # that on, Python then raised no KeyboardInterrupt and the children slept their minute (session 64, `-n 3`)
    proc = subprocess.Popen([sys.executable, "-c", _INTERRUPTED], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, preexec_fn=sigint_default)
    pids = [int(proc.stdout.readline()) for _ in range(2)]
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 130 and out.strip() == "interrupted" and time.perf_counter() - t0 < 10
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


_KILLED = """
import os, sys, time
from vfcli.fork_map import ForkMap

def piece(i):
    os.write(1, f"{os.getpid()}\\n".encode())      # one write: print's two would interleave with the other child's
    time.sleep(60)

ForkMap(2)(piece, range(2))
"""


_FLAG_ONLY = """
import _thread, signal, sys, threading, time
from vfcli.fork_map import ForkMap

# Python's own Ctrl-C handler, which interrupt_main needs: a suite started as a background job (`make test &` from a
# script) passes SIGINT on ignored, and interrupt_main then does nothing (the wait ran its 30 s, session 76)
signal.signal(signal.SIGINT, signal.default_int_handler)

def piece(i):
    time.sleep(30)
    return i

threading.Timer(1.0, _thread.interrupt_main).start()   # the flag a signal sets, without waking any system call
t0 = time.monotonic()
try:
    ForkMap(2)(piece, range(2))
except KeyboardInterrupt:
    print(f"{time.monotonic() - t0:.2f}", flush=True)
    sys.exit(130)
"""


def test_a_ctrl_c_that_wakes_no_system_call_still_ends_the_wait_at_once():
    """A SIGINT that lands after Python last looked at its signal flag and before the wait for the pieces' output
    sets the flag and wakes nothing (CI lost one so in another command, session 69); ``_thread.interrupt_main``
    sets the flag exactly so.  The wait looks again every ``WAKE_S`` (0.5 s): interrupted within that of the flag
    (measured 1.00-1.01 s after the start, the flag set at 1 s), not after the pieces' 30 s (without the bound:
    30.0 s)."""
    import os
    import subprocess
    import sys

    from conftest import ROOT
    from vfcli.fork_map import WAKE_S

    proc = subprocess.run([sys.executable, "-c", _FLAG_ONLY], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 130, proc.stderr
    assert 0.9 < float(proc.stdout) < 1.0 + WAKE_S + 2.0, proc.stdout


def test_a_parent_killed_outright_leaves_no_forked_piece_running():
    """`kill -9` (or the out-of-memory killer) of the caller while two pieces run: the children die with it
    (PR_SET_PDEATHSIG), they do not compute on for their minute."""
    import os
    import signal
    import subprocess
    import sys

    from conftest import ROOT

    proc = subprocess.Popen([sys.executable, "-c", _KILLED], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    pids = [int(proc.stdout.readline()) for _ in range(2)]
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.perf_counter() + 10
    alive = list(pids)
    while alive and time.perf_counter() < deadline:
        alive = [p for p in alive if _alive(p)]
        time.sleep(0.05)
    assert not alive


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped by init, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_no_second_child_is_forked_while_the_memory_holds_none_and_the_first_always_is():
    """``room`` says whether one more child fits in the memory available beside the running ones: while it says no,
    the pieces run one at a time (no two children alive at once), and still every piece runs; the machine's own
    figure reads /proc (MemAvailable against CHILD_SHARE of this process's resident memory per child, the running
    ones counted)."""
    import os

    from vfcli.fork_map import ForkMap, _kb, room_for_a_child

    def piece(i):
        start = time.time()
        time.sleep(0.15)
        return os.getpid(), start, time.time()

    got = ForkMap(3, room=lambda running: False)(piece, range(3))
    spans = sorted((s, e) for _, s, e in got)
    assert all(spans[k][1] <= spans[k + 1][0] for k in range(2)), spans          # never two at once
    both = ForkMap(3, room=lambda running: True)(piece, range(3))
    spans = sorted((s, e) for _, s, e in both)
    assert spans[1][0] < spans[0][1]                                            # side by side when there is room
    available, rss = _kb("/proc/meminfo", "MemAvailable"), _kb("/proc/self/status", "VmRSS")
    assert 0 < rss < available < _kb("/proc/meminfo", "MemTotal") and room_for_a_child()   # a test process fits
    assert not room_for_a_child(int(2 * available / rss))     # nor beside as many as would take all that memory


def test_a_forked_piece_s_warning_is_logged_by_the_caller_so_a_stage_stores_it():
    """A warning a piece logs in its child is logged again by the caller, under the piece's logger, once: where a
    stage captures its warnings to store them (vfcli.stages.base.captured_warnings), the pieces' warnings are among
    them in the pieces' order, as when the pieces run in the caller itself."""
    import logging

    from vfcli.fork_map import ForkMap
    from vfcli.stages.base import captured_warnings

    def piece(i):
        time.sleep(0.2 * (1 - i))                         # the first piece ends last: its warning still comes first
        logging.getLogger("vfcli.diagnose.somewhere").warning("piece %d: the corner is at the end", i)
        return i

    for mapper in (None, ForkMap(2)):
        with captured_warnings() as stored:
            got = (mapper or (lambda f, xs: [f(x) for x in xs]))(piece, range(2))
        assert got == [0, 1]
        assert stored == [f"WARNING vfcli.diagnose.somewhere: piece {i}: the corner is at the end" for i in (0, 1)]
