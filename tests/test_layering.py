"""The layers stay apart, checked on the syntax tree of every module of vfcli/.

1. The core (every module outside vfcli/store, vfcli/stages, vfcli/cli, vfcli/io and vfcli/batch) imports
   none of vfcli.store, vfcli.stages, vfcli.cli, click or h5py; beyond the core, only the
   store imports h5py and only the CLI imports click.
2. No module but those of vfcli/store/ spells an HDF5 stage path ("/flow", f"/optimize/{run}").
3. No stage module imports another stage module (vfcli.stages.base, the shared runner, excepted).

Each rule is a function of a module's source and its path, so the tests at the end can feed
it a violating snippet and see it fail.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from vfcli.store import layout

PKG = Path(__file__).resolve().parents[1] / "vfcli"
MODULES = sorted(PKG.rglob("*.py"))
STAGE_PATH = re.compile(r"^/(%s)(/|$)" % "|".join(map(re.escape, layout.STAGES)))
EDGE_LAYERS = ("store", "stages", "cli", "io", "batch")  # batch: runs whole recordings (stages) on a cluster
CORE_MAY_NOT_IMPORT = ("vfcli.store", "vfcli.stages", "vfcli.cli", "click", "h5py")
STAGE_RUNNER = "vfcli.stages.base"
#: `vfcli run`: calls every stage's runner in order, as the command line does one at a time.
PIPELINE_RUNNER = "stages/run.py"
#: shared by the export and report stages (not a stage of its own)
SHARED_STAGE_HELPERS = {STAGE_RUNNER, "vfcli.stages.export_job"}


def _rel(p: Path) -> str:
    return p.relative_to(PKG).as_posix()


def _module_name(rel: str) -> str:
    """``flow/gap/rays.py`` -> ``vfcli.flow.gap.rays``; ``stages/__init__.py`` -> ``vfcli.stages``."""
    parts = ["vfcli", *rel[: -len(".py")].split("/")]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_names(source: str, rel: str) -> set[str]:
    """Every module a source imports, as absolute dotted names, anywhere in the file.

    ``from a.b import c`` yields ``a.b`` and ``a.b.c`` (``c`` may be a submodule);
    relative imports are resolved against the module's package.
    """
    package = _module_name(rel) if rel.endswith("__init__.py") else _module_name(rel).rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, base] if base else up)
            names.add(base)
            names |= {f"{base}.{a.name}" for a in node.names if a.name != "*"}
    return names


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def import_violations(source: str, rel: str) -> list[str]:
    """Rule 1: imports that cross a layer."""
    layer = rel.split("/")[0] if "/" in rel else ""
    names = imported_names(source, rel)
    out = []
    if layer not in EDGE_LAYERS:
        out += [f"{rel} (core) imports {n}" for n in sorted(names)
                if any(_within(n, banned) for banned in CORE_MAY_NOT_IMPORT)]
    else:
        if layer != "store":
            out += [f"{rel} imports h5py: go through vfcli.store" for n in sorted(names) if _within(n, "h5py")]
        if layer != "cli":
            out += [f"{rel} imports click: keep it in vfcli/cli" for n in sorted(names) if _within(n, "click")]
    return out


def _docstrings(tree: ast.AST) -> set[int]:
    return {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
        and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
    }


def hdf5_path_violations(source: str, rel: str) -> list[str]:
    """Rule 2: string literals and f-strings (placeholders read as ``{}``) that start with a stage path."""
    if rel.startswith("store/"):
        return []
    tree = ast.parse(source)
    skip = _docstrings(tree)
    inside_fstring = {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            text = "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip | inside_fstring:
            text = node.value
        else:
            continue
        if STAGE_PATH.match(text):
            out.append(f"{rel}:{node.lineno} spells the HDF5 path {text!r}: use vfcli.store.layout")
    return out


def stage_import_violations(source: str, rel: str) -> list[str]:
    """Rule 3: a stage module importing another stage module."""
    if not rel.startswith("stages/") or rel in ("stages/__init__.py", PIPELINE_RUNNER):
        return []
    me = _module_name(rel)
    stages = {".".join(n.split(".")[:3]) for n in imported_names(source, rel) if _within(n, "vfcli.stages")}
    return [f"{rel} imports the stage module {n}: move what both need into the core or the store"
            for n in sorted(stages - {"vfcli.stages", me} - SHARED_STAGE_HELPERS)]


#: Violations known today: {rule: {module: why}}; each test of one is xfail(strict=True), so it
#: turns red the day the violation is gone (then delete the entry).
KNOWN: dict[str, dict[str, str]] = {}


def _modules(rule) -> list:
    known = KNOWN.get(rule.__name__, {})
    return [pytest.param(p, id=_rel(p), marks=[pytest.mark.xfail(strict=True, reason=known[_rel(p)])]
                         if _rel(p) in known else []) for p in MODULES]


def _check(rule, path: Path) -> None:
    found = rule(path.read_text(), _rel(path))
    assert not found, "\n".join(found)


@pytest.mark.parametrize("path", _modules(import_violations))
def test_the_core_imports_no_store_stage_cli_click_or_h5py(path):
    _check(import_violations, path)


@pytest.mark.parametrize("path", _modules(hdf5_path_violations))
def test_no_module_but_the_store_spells_an_hdf5_path(path):
    _check(hdf5_path_violations, path)


@pytest.mark.parametrize("path", _modules(stage_import_violations))
def test_no_stage_imports_another_stage(path):
    _check(stage_import_violations, path)


def test_every_layer_of_the_package_is_inspected():
    """The rules see the modules they speak of (an empty glob would pass everything)."""
    layers = {_rel(p).split("/")[0] for p in MODULES if "/" in _rel(p)}
    assert {"store", "stages", "cli", "io", "flow", "model", "camera", "inverse", "sync", "synth"} <= layers
    assert len(MODULES) > 60


# ---- each rule fails on a violating snippet ---------------------------------------------

@pytest.mark.parametrize("source", [
    "import h5py",
    "import click",
    "from vfcli.store.transaction import StoreReader",
    "from vfcli import store",
    "import vfcli.stages.flow",
    "def f():\n    from vfcli.cli.main import main\n",
    "from ...store import layout",
])
def test_the_import_rule_catches_a_core_module_crossing_a_layer(source):
    assert import_violations(source, "flow/gap/rays.py")


def test_the_import_rule_lets_the_edges_use_what_they_own():
    assert not import_violations("import h5py\nfrom vfcli.store import layout", "store/transaction.py")
    assert not import_violations("import click\nfrom vfcli.stages.flow import run", "cli/flow.py")
    assert not import_violations("import numpy as np\nfrom vfcli.flow.gap import rays", "inverse/problem.py")
    assert import_violations("import h5py", "stages/flow.py")
    assert import_violations("import click", "io/pressure.py")


@pytest.mark.parametrize("source", [
    'P = "/optimize"',
    'P = "/flow/velocity"',
    'def f(run):\n    return f"/optimize/{run}/x"\n',
    'def f(ds):\n    return f"/fields/{ds}"\n',
])
def test_the_path_rule_catches_strings_and_f_strings(source):
    assert hdf5_path_violations(source, "stages/flow.py")
    assert not hdf5_path_violations(source, "store/layout.py")


def test_the_path_rule_ignores_docstrings_and_other_strings():
    source = '"""Writes /flow from /hsc."""\nX = "flow"\nY = f"{1}/flow"\nZ = "a/optimize"\n'
    assert not hdf5_path_violations(source, "stages/flow.py")


@pytest.mark.parametrize("source", [
    "from vfcli.stages.mesh import read_mesh",
    "from vfcli.stages import mesh",
    "import vfcli.stages.flow",
    "from . import mesh",
    "from .mesh import read_mesh",
])
def test_the_stage_rule_catches_a_stage_importing_a_stage(source):
    assert stage_import_violations(source, "stages/optimize.py")


def test_the_stage_rule_allows_the_shared_runner():
    assert not stage_import_violations("from vfcli.stages.base import RunContext, run_stage\n"
                                       "from .base import StageResult", "stages/optimize.py")
