"""docs/concepts/architecture.md against the code: the generated import graph keeps the
layers of pyproject's import-linter contracts, the page keeps its marker, and every
``adfusion.…`` name the page cites exists."""

from __future__ import annotations

import importlib
import importlib.util
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "concepts" / "architecture.md"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_architecture",
                                                  ROOT / "docs" / "gen_architecture.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("gen_architecture", mod)
    spec.loader.exec_module(mod)
    return mod


gen = _generator()


def _contracts() -> list[dict]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return [c for c in config["tool"]["importlinter"]["contracts"] if c["type"] == "layers"]


def _layers(contract: dict) -> list[list[str]]:
    """The contract's layers, top first, each a list of full module names (its
    independent rooms)."""
    containers = contract.get("containers") or [""]
    out = []
    for layer in contract["layers"]:
        for container in containers:
            out.append([f"{container}.{item.strip()}" if container else item.strip()
                        for item in layer.split("|")])
    return out


def _place(module: str, layers: list[list[str]]) -> tuple[int, str] | None:
    for i, layer in enumerate(layers):
        for item in layer:
            if module == item or module.startswith(item + "."):
                return i, item
    return None


def test_the_contracts_are_found():
    contracts = _contracts()
    assert len(contracts) == 2
    placed = {m for m in gen.modules() if _place(m, _layers(contracts[0]))}
    assert "adfusion.app.cli" in placed and "adfusion.maths.rotations" in placed


@pytest.mark.parametrize("contract", _contracts(), ids=lambda c: c["name"][:40])
def test_no_upward_edge(contract):
    layers = _layers(contract)
    bad = []
    for src, dst in sorted(gen.module_edges()):
        a, b = _place(src, layers), _place(dst, layers)
        if a is None or b is None:
            continue
        (i, item_a), (j, item_b) = a, b
        if j < i:
            bad.append(f"{src} -> {dst} (upward: {item_a} imports {item_b})")
        elif i == j and item_a != item_b:
            bad.append(f"{src} -> {dst} (independent: {item_a} imports {item_b})")
    assert not bad, "\n".join(bad)


def test_the_table_has_every_room():
    table = gen.graph_table()
    for room in ("maths", "plain", "starid", "starid.camera", "starid.identify", "logs",
                 "sensors", "estimation", "pointing", "basilisk", "bench", "app"):
        assert f"| {room} |" in table


def test_type_checking_imports_do_not_count(tmp_path):
    import ast
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                     "    import adfusion.app\nelse:\n    import adfusion.maths\n"
                     "def f():\n    import adfusion.logs\n")
    names = {a.name for n in gen._import_nodes(tree) if isinstance(n, ast.Import)
             for a in n.names}
    assert names == {"adfusion.maths", "adfusion.logs"}


def test_the_page_holds_the_marker():
    assert gen.MARK in PAGE.read_text(encoding="utf-8")


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        name = ".".join(parts[:k])
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            spec = None
        if spec is None:
            continue
        obj = importlib.import_module(name)
        for attr in parts[k:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_every_cited_name_exists():
    text = PAGE.read_text(encoding="utf-8")
    cited = sorted(set(re.findall(r"`(adfusion(?:\.\w+)+)(?:\(\))?`", text)))
    assert len(cited) > 10
    missing = [name for name in cited if not _resolves(name)]
    assert not missing, missing
