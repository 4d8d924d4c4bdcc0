"""docs/concepts/architecture.md against the code: the generated import graph keeps the
layers of pyproject's import-linter contracts (an independent check of them: read with
``ast`` by docs/gen_architecture.py, not by import-linter), the page keeps its marker and
its place in mkdocs.yml, and every ``adfusion.…`` name the page cites exists."""

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
    for room in ("maths", "plain", "starid", "starid.camera", "starid.catalog",
                 "starid.detection", "starid.identify", "starid.tracking", "starid.solver",
                 "starid.jit_cache", "logs", "sensors", "estimation", "pointing", "basilisk",
                 "bench", "app"):
        assert f"| `{room}` |" in table
    # bottom layer first, as the contracts order them
    rows = [line.split("`")[1] for line in table.splitlines()[2:] if line.startswith("| `")]
    assert rows.index("maths") < rows.index("starid.camera") < rows.index("starid.solver") \
        < rows.index("sensors") < rows.index("app")


def test_the_chart_has_the_tables_edges():
    text = gen.generated()
    assert "\n```mermaid\nflowchart " in text
    chart = text.split("```mermaid", 1)[1].split("```", 1)[0]
    drawn = set(re.findall(r"^\s*(\w+) --> (\w+)$", chart, re.MULTILINE))
    table = {(gen._node(a), gen._node(b)) for a, bs in gen.room_edges().items() for b in bs}
    assert drawn == table and len(drawn) > 20


def test_what_counts_as_an_import():
    import ast
    tree = ast.parse('''"""Example:
    >>> import adfusion.bench
"""
from typing import TYPE_CHECKING
if TYPE_CHECKING:
    import adfusion.app
else:
    import adfusion.maths
def f():
    import adfusion.logs
''')
    names = {a.name for n in gen._import_nodes(tree) if isinstance(n, ast.Import)
             for a in n.names}
    assert names == {"adfusion.maths", "adfusion.logs"}


def test_the_page_holds_the_marker():
    assert gen.MARK in PAGE.read_text(encoding="utf-8")
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")  # !!python tags: not YAML-safe
    assert "  - docs/gen_architecture.py\n" in config and f": {gen.PAGE}\n" in config


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
