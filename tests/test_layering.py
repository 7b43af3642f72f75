"""The three layers stay apart: only the store opens HDF5, only the CLI uses click,
and no module but the layout spells an HDF5 path."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from vfcli.store import layout

PKG = Path(__file__).resolve().parents[1] / "vfcli"
MODULES = sorted(p for p in PKG.rglob("*.py"))
STAGE_PATH = re.compile(r"^/(%s)(/|$)" % "|".join(layout.STAGES))


def _imports(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def _rel(p: Path) -> str:
    return p.relative_to(PKG).as_posix()


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_only_the_store_opens_hdf5_and_only_the_cli_uses_click(path):
    tree = ast.parse(path.read_text())
    imported = _imports(tree)
    rel = _rel(path)
    if not rel.startswith("store/"):
        assert "h5py" not in imported, f"{rel} imports h5py: go through vfcli.store"
    if not rel.startswith("cli/"):
        assert "click" not in imported, f"{rel} imports click: keep the CLI in vfcli/cli/"


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_no_module_but_the_layout_spells_an_hdf5_path(path):
    if _rel(path).startswith("store/"):
        return
    tree = ast.parse(path.read_text())
    docstrings = {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
        and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
    }
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            assert not STAGE_PATH.match(node.value), f"{_rel(path)} spells the HDF5 path {node.value!r}"
