import os
import signal
import subprocess
import sys
from pathlib import Path

# One BLAS thread per process, set before numpy is first imported (here, in every pytest-xdist
# worker and in every `vfcli` subprocess the tests start, which inherit it): `make test` runs two
# workers on two cores, and OpenBLAS's default of a thread per core in each of them oversubscribes
# the CPU; its idle threads spin, which cost a third of the CPU time of the numeric tests
# (tests/test_response.py and tests/test_fem.py: 77 s of CPU with the default, 50 s with one
# thread). An explicit setting in the environment is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Python's bytecode cache for every process the suite starts, as `make test` keeps it (the Makefile's head), when
# pytest is typed by hand in an environment that turns the cache off (PYTHONDONTWRITEBYTECODE=1, as many container
# images set it): the examples' make and snakemake, the batch workers, the crash tests' subprocesses and the vfcli
# helper otherwise compile vfcli and its libraries again each (9 min 53 s against make test's 8 min 7 s on session
# 66's machine: docs/benchmarks.md "Session 66: the suite's time as `make test` runs it"). This process keeps its
# own setting (read at its start); inside a venv only, whose pycache folder is make's.
if (os.environ.get("PYTHONDONTWRITEBYTECODE") and "PYTHONPYCACHEPREFIX" not in os.environ
        and sys.prefix != sys.base_prefix):
    del os.environ["PYTHONDONTWRITEBYTECODE"]
    os.environ["PYTHONPYCACHEPREFIX"] = str(Path(sys.prefix) / "pycache")

import pytest  # noqa: E402

from vfcli.allocator import keep_freed_blocks  # noqa: E402

# The allocator as the CLI sets it at start (vfcli/allocator.py), for the code the tests run in this process: numpy's
# large temporaries from the heap, not a fresh mmap and a page fault per 4 kB each (two inertia refit tests 77.9 -> 66.9 s;
# docs/benchmarks.md "Session 69: the allocator"). The `vfcli` commands the tests start set it themselves.
keep_freed_blocks()

ROOT = Path(__file__).resolve().parents[1]
VFCLI = [sys.executable, "-m", "vfcli.cli.main"]


def sigint_default() -> None:
    """``preexec_fn`` of a child a test interrupts with SIGINT: SIGINT at its default disposition, as
    Ctrl-C in a terminal finds it.  A shell without job control (``make test &`` in a script) starts
    background jobs with SIGINT ignored, the child inherits that, and Python then installs no
    KeyboardInterrupt handler: the signal would be lost, not the code under test wrong."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


_ZYGOTE = None


def run_vfcli(*args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the real `vfcli` command in its own process: forked from this worker's helper process,
    which imported vfcli and its libraries once (tests/_zygote.py), or a fresh interpreter when
    ``VFCLI_TEST_FRESH=1``. Output captured as text, as ``subprocess.run(..., capture_output=True,
    text=True)``; ``subprocess.TimeoutExpired`` after ``timeout`` s."""
    global _ZYGOTE
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [str(a) for a in args]
    if os.environ.get("VFCLI_TEST_FRESH") == "1":
        return subprocess.run([*VFCLI, *argv], capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout)
    from _zygote import Zygote

    if _ZYGOTE is None or not _ZYGOTE.alive():
        _ZYGOTE = Zygote(ROOT)
    return _ZYGOTE.run(argv, cwd, env, timeout)


def pytest_unconfigure(config):
    """This worker's helper process (:func:`run_vfcli`) ends with it."""
    if _ZYGOTE is not None:
        _ZYGOTE.close()


#: the test files that take longest (`make test --durations`), started first: pytest-xdist's
#: loadfile scheduling hands out files in collection order (see :func:`pytest_configure`), and with
#: the slowest last one worker ran test_diagnose_refit_phantom.py alone for its last three minutes
#: (10 min 8 s on a quiet machine). Ordered by the files' time in session 29's run (tests/_zygote.py
#: in use), 84 s down to 26 s; session 68 split inertia's refit tests (about 90 s, 46 s of them the mesh part's)
#: out of test_diagnose_refit.py and put them second. test_contact_phantom.py builds the diagnosed contact phantom
#: that test_diagnose_stage.py and test_report.py read (:func:`shared_product`): in collection order the two files
#: started together and one worker waited 13 s on the other's build (session 77, the wait logged per product), so it
#: comes early.
SLOW_FIRST = ("test_diagnose_refit_phantom.py", "test_diagnose_refit_inertia.py", "test_examples_batch.py",
              "test_diagnose_refit.py", "test_run.py",
              "test_hostile_fuzz_files.py", "test_batch.py", "test_store_commit.py", "test_rotation_end_to_end.py",
              "test_fem.py", "test_contact_phantom.py", "test_hostile_fuzz.py", "test_flow_stage.py",
              "test_diagnose_calibrate.py")


def pytest_configure(config):
    """pytest-xdist (3.7 on) reorders the files of ``--dist loadfile`` by their number of tests, most
    first, unless ``--no-loadscope-reorder``: that put :data:`SLOW_FIRST`'s files, which hold few tests
    each, among the last ones handed out. Here the collection order is kept unless
    ``--loadscope-reorder`` is given."""
    if hasattr(config.option, "loadscopereorder") and "--loadscope-reorder" not in config.invocation_params.args:
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """The files of :data:`SLOW_FIRST` first, in that order; the others keep theirs."""
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(Path(str(item.fspath)).name, len(rank)))


@pytest.fixture
def vfcli():
    return run_vfcli


def shared_product(tmp_path_factory, name: str, build) -> Path:
    """The folder ``<shared>/<name>`` after ``build(folder)`` filled it, built once per test run.

    A phantom pipeline several test files need (the same seed, options and stages) is built by
    the first caller and reused by the others, in this process and in every other pytest-xdist
    worker of the run: the shared folder is the run's base temp folder (the workers' common
    parent under xdist), and an exclusive ``fcntl.flock`` on ``<name>.lock`` beside the product
    makes the other callers wait for it (pytest-xdist's documented pattern for session fixtures
    that run once). ``<name>.done`` (beside, not inside, the product) marks a finished build;
    a build that raised is started again by the next caller. Callers treat the product as
    read-only: a test that writes copies it (:func:`vfcli.store.parts.copy_store` for a store,
    ``shutil.copytree`` for a raw folder).
    """
    import fcntl
    import shutil

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    shared = root / "shared"
    shared.mkdir(exist_ok=True)
    product, done = shared / name, shared / f"{name}.done"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(product, ignore_errors=True)
            product.mkdir()
            build(product)
            done.touch()
    return product
