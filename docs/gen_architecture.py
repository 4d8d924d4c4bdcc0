"""The room table of ``docs/concepts/architecture.md``, generated from the code.

A MkDocs hook (``hooks:`` in ``mkdocs.yml``): at build time it replaces the
``<!-- rooms:graph -->`` marker of that page with a table of the package's rooms, their
module and line counts, and the rooms each one imports. The imports are read with
:mod:`ast` from the source folders (nothing is imported), so the page cannot drift from
the code. The source folders map to the installed names as in ``pyproject.toml``:
``adfusion/`` → ``adfusion``, ``starid/`` → ``adfusion.starid``, ``sensors/`` →
``adfusion.sensors``, ``logs/`` → ``adfusion.logs``.

What counts as an import: every ``import`` and ``from … import`` statement of a module,
those deferred into functions included; those under ``if TYPE_CHECKING:`` are not
imports at run time and do not count; docstring examples are strings, not code.

Run it as a script to print the table::

    python docs/gen_architecture.py
"""

from __future__ import annotations

import ast
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

# the order of the table's rows, bottom layer first; a room the code has and this list
# does not is appended, so a new room shows up on the page anyway
ORDER = [
    "maths", "plain",
    "starid.camera", "starid.catalog", "starid.detection",
    "starid.identify", "starid.triad", "starid.bleif", "starid.tracking", "starid",
    "logs", "sensors", "estimation", "pointing", "basilisk", "bench", "app", "adfusion",
]


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
    """The room of a module: ``starid.camera`` … for starid's subpackages, ``starid`` for
    its top modules, the first name under ``adfusion`` otherwise (``adfusion`` itself for
    the package's own ``__init__`` and ``__main__``)."""
    parts = name.split(".")
    if len(parts) == 1 or (len(parts) == 2 and parts[1] == "__main__"):
        return "adfusion"
    if parts[1] == "starid":
        if len(parts) >= 3 and _is_package(".".join(parts[:3])):
            return f"starid.{parts[2]}"
        return "starid"
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
    """The rooms in table order."""
    present = {room_of(m) for m in modules()}
    return [r for r in ORDER if r in present] + sorted(present - set(ORDER))


def graph_table() -> str:
    """The Markdown table: room, modules, lines, the rooms it imports."""
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
        imported = ", ".join(sorted(edges[room], key=order.__getitem__)) or "—"
        rows.append(f"| {room} | {n} | {lines} | {imported} |")
    total_n = sum(c[0] for c in counts.values())
    total_lines = sum(c[1] for c in counts.values())
    rows.append(f"| **all** | {total_n} | {total_lines} | |")
    return "\n".join(rows)


def on_page_markdown(markdown: str, page: Any, **kwargs: Any) -> str:
    """MkDocs hook: fill the marker of the architecture page."""
    if page.file.src_uri != PAGE:
        return markdown
    if MARK not in markdown:
        raise RuntimeError(f"docs/{PAGE}: the marker {MARK} is missing")
    return markdown.replace(MARK, graph_table())


if __name__ == "__main__":
    print(graph_table())
