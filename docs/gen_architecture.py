"""The import graph of ``docs/concepts/architecture.md``, generated from the code.

A MkDocs hook (``hooks:`` in ``mkdocs.yml``): at build time it replaces the
``<!-- rooms:graph -->`` marker of that page with (a) a table of the package's rooms,
their module and line counts and the rooms each one imports, and (b) the same edges as a
Mermaid flowchart. The imports are read with :mod:`ast` from the source folders (nothing
is imported), so the page cannot drift from the code. The source folders map to the
installed names as in ``pyproject.toml``: ``adfusion/`` → ``adfusion``, ``starid/`` →
``adfusion.starid``, ``sensors/`` → ``adfusion.sensors``, ``logs/`` → ``adfusion.logs``.

A room is a top-level package of ``adfusion`` (``maths``, ``logs``, ``app`` …), or one
of starid's own rooms: a subpackage (``starid.camera`` …) or a top module
(``starid.solver``, ``starid.jit_cache`` …), as in the second import-linter contract.
``starid`` alone is that package's ``__init__`` (its public names); ``adfusion`` is the
top package's ``__init__`` and ``__main__`` its ``python -m adfusion``. The rows follow
the contracts' layers of ``pyproject.toml``, bottom first; rooms the contracts do not
name come last.

What counts as an import: every ``import`` and ``from … import`` statement of a module,
those deferred into functions included; those under ``if TYPE_CHECKING:`` are not
imports at run time and do not count; docstring examples are strings, not code.

Run it as a script to print the generated Markdown::

    python docs/gen_architecture.py
"""

from __future__ import annotations

import ast
import tomllib
from functools import cache
from pathlib import Path
from typing import Any

MARK = "<!-- rooms:graph -->"
PAGE = "concepts/architecture.md"
ROOT = Path(__file__).resolve().parent.parent

# installed package name → source folder (pyproject.toml, [tool.setuptools.package-dir])
SOURCES = {
    "adfusion": "adfusion",
    "adfusion.starid": "starid",
    "adfusion.sensors": "sensors",
    "adfusion.logs": "logs",
}


@cache
def layer_order() -> list[str]:
    """The rooms of the import-linter ``layers`` contracts of ``pyproject.toml``, bottom
    layer first: the package's layers, with ``starid`` opened into its own contract's
    layers (and the package ``starid`` itself after them)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = [c for c in config["tool"]["importlinter"]["contracts"]
                 if c["type"] == "layers"]
    inner: dict[str, list[str]] = {}
    for contract in contracts:
        for container in contract.get("containers", []):
            inner[container] = [f"{container}.{item.strip()}"
                                for layer in reversed(contract["layers"])
                                for item in layer.split("|")]
    order: list[str] = []
    for contract in contracts:
        if contract.get("containers"):
            continue
        for layer in reversed(contract["layers"]):
            for item in layer.split("|"):
                item = item.strip()
                order += [*inner.get(item, []), item]
    return [name.removeprefix("adfusion.") for name in order]


@cache
def modules() -> dict[str, Path]:
    """Every module of the package: its installed dotted name → its source file."""
    found: dict[str, Path] = {}
    for package, folder in SOURCES.items():
        base = ROOT / folder
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base)
            if "__pycache__" in rel.parts:
                continue
            parts = list(rel.with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            name = ".".join([package, *parts])
            # adfusion/ holds no starid/, sensors/ or logs/ of its own; keep the mapped one
            found.setdefault(name, path)
    return found


def _is_package(name: str) -> bool:
    return modules()[name].name == "__init__.py"


def _is_type_checking(test: ast.expr) -> bool:
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _import_nodes(tree: ast.AST):
    """The import statements of ``tree``, skipping the bodies of ``if TYPE_CHECKING:``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            todo.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
            continue
        todo.extend(ast.iter_child_nodes(node))


def _known(name: str) -> str | None:
    """The longest prefix of ``name`` that is a module of ours, or None."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules():
            return candidate
        parts.pop()
    return None


def imports_of(name: str) -> set[str]:
    """The modules of ours that module ``name`` imports (at run time)."""
    path = modules()[name]
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    package = name if _is_package(name) else name.rpartition(".")[0]
    out: set[str] = set()
    for node in _import_nodes(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            if node.level:
                base_parts = package.split(".")
                if node.level > 1:
                    base_parts = base_parts[:-(node.level - 1)]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            # ``from pkg import sub`` imports the submodule when there is one
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules() else base
                       for alias in node.names]
        for target in targets:
            mod = _known(target)
            if mod is not None and mod != name:
                out.add(mod)
    return out


@cache
def module_edges() -> frozenset[tuple[str, str]]:
    """(importer, imported) for every import between two modules of ours."""
    return frozenset((src, dst) for src in modules() for dst in imports_of(src))


def room_of(name: str) -> str:
    """The room of a module: ``starid.camera``, ``starid.solver`` … for starid's
    subpackages and top modules, ``starid`` for its ``__init__``, the first name under
    ``adfusion`` otherwise: ``__main__`` for ``python -m adfusion``, ``adfusion`` itself
    for the package's own ``__init__``."""
    parts = name.split(".")
    if len(parts) == 1:
        return "adfusion"
    if parts[1] == "starid" and len(parts) >= 3:
        return f"starid.{parts[2]}"
    return parts[1]


def room_edges() -> dict[str, set[str]]:
    """Each room → the other rooms it imports."""
    out: dict[str, set[str]] = {room_of(m): set() for m in modules()}
    for src, dst in module_edges():
        a, b = room_of(src), room_of(dst)
        if a != b:
            out[a].add(b)
    return out


def rooms() -> list[str]:
    """The rooms in table order: the contracts' layers, bottom first; a room the
    contracts do not name comes last, so a new room shows up on the page anyway."""
    present = {room_of(m) for m in modules()}
    order = layer_order()
    return [r for r in order if r in present] + sorted(present - set(order))


def graph_table() -> str:
    """The Markdown table: room, modules, lines, the rooms it imports (bottom first)."""
    counts: dict[str, list[int]] = {}
    for name, path in modules().items():
        c = counts.setdefault(room_of(name), [0, 0])
        c[0] += 1
        c[1] += len(path.read_text(encoding="utf-8").splitlines())
    edges = room_edges()
    order = {r: i for i, r in enumerate(rooms())}
    rows = ["| Room | Modules | Lines | Imports |", "|---|--:|--:|---|"]
    for room in rooms():
        n, lines = counts[room]
        imported = ", ".join(f"`{r}`" for r in sorted(edges[room], key=order.__getitem__))
        rows.append(f"| `{room}` | {n} | {lines} | {imported or '—'} |")
    total_n = sum(c[0] for c in counts.values())
    total_lines = sum(c[1] for c in counts.values())
    rows.append(f"| **all** | {total_n} | {total_lines} | |")
    return "\n".join(rows)


def _node(room: str) -> str:
    """A Mermaid node id: letters, digits and underscores."""
    return "adfusion_main" if room == "__main__" else room.replace(".", "_")


def graph_mermaid() -> str:
    """The same edges as a Mermaid flowchart (importer above imported); starid's rooms
    in a box of their own."""
    out = ["```mermaid", "flowchart TD"]
    inside = [r for r in rooms() if r == "starid" or r.startswith("starid.")]
    for room in rooms():
        if room not in inside:
            out.append(f'  {_node(room)}["{room}"]')
    out.append('  subgraph starid_rooms ["adfusion.starid"]')
    out += [f'    {_node(room)}["{room}"]' for room in inside]
    out.append("  end")
    edges = room_edges()
    order = {r: i for i, r in enumerate(rooms())}
    for room in reversed(rooms()):
        for dst in sorted(edges[room], key=order.__getitem__, reverse=True):
            out.append(f"  {_node(room)} --> {_node(dst)}")
    out.append("```")
    return "\n".join(out)


def generated() -> str:
    """What replaces the marker: the table, then the flowchart."""
    return f"{graph_table()}\n\n{graph_mermaid()}"


def on_page_markdown(markdown: str, page: Any, **kwargs: Any) -> str:
    """MkDocs hook: fill the marker of the architecture page."""
    if page.file.src_uri != PAGE:
        return markdown
    if MARK not in markdown:
        raise RuntimeError(f"docs/{PAGE}: the marker {MARK} is missing")
    for cached in (layer_order, modules, module_edges):  # ``mkdocs serve`` rebuilds
        cached.cache_clear()
    return markdown.replace(MARK, generated())


if __name__ == "__main__":
    print(generated())
