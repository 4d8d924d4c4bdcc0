"""MkDocs hook: the installed package layout as a tree of links, for the API reference.

The repository's ``starid/``, ``sensors/`` and ``logs/`` install as ``adfusion.starid``,
``adfusion.sensors`` and ``adfusion.logs`` through setuptools' package mapping
(``[tool.setuptools.package-dir]`` in ``pyproject.toml``). mkdocstrings reads the sources
with griffe, which walks folders and does not follow that mapping, so this hook builds
``build/docs-layout/adfusion/`` (links to the folders of ``adfusion/`` and to the mapped
folders, copies of its few top-level files) and ``mkdocs.yml`` points griffe there
(``paths``). It is built once per ``mkdocs`` run.
"""

from __future__ import annotations

import os
import shutil
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
TREE = ROOT / "build" / "docs-layout"


def package_dirs(root: Path = ROOT) -> dict[str, Path]:
    """Package name → source folder, from ``[tool.setuptools.package-dir]``."""
    cfg = tomllib.loads((root / "pyproject.toml").read_text())
    mapping = cfg["tool"]["setuptools"].get("package-dir", {})
    return {name: root / folder for name, folder in mapping.items()}


def build_tree(tree: Path = TREE, root: Path = ROOT) -> Path:
    """(Re)create the link tree; returns its root (the folder to search for packages)."""
    shutil.rmtree(tree, ignore_errors=True)
    for name, folder in sorted(package_dirs(root).items()):
        target = tree.joinpath(*name.split("."))
        if "." in name:  # a mapped subpackage: one link to its folder
            target.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(folder, target, target_is_directory=True)
            continue
        # the top package: its folders linked, its files copied (griffe resolves a linked
        # __init__.py to its real folder, which lacks the mapped subpackages)
        target.mkdir(parents=True, exist_ok=True)
        for entry in folder.iterdir():
            if entry.name == "__pycache__" or (target / entry.name).exists():
                continue
            if entry.is_dir():
                os.symlink(entry, target / entry.name, target_is_directory=True)
            else:
                shutil.copy2(entry, target / entry.name)
    return tree


def on_startup(**kwargs: Any) -> None:
    """MkDocs hook, run once per ``mkdocs build`` or ``serve`` before any plugin's
    ``on_config``: mkdocstrings expands its ``paths`` there and drops a missing one."""
    build_tree()
