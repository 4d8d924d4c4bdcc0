"""The compiled kernels' on-disk cache (starid.jit_cache): a kernel module's cached code is
stale as soon as any module it compiles in changes, not only its own file."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import numpy as np
from adfusion.starid import jit_cache
from adfusion.starid.identify import frame_kernels, kernels

STARID = Path(jit_cache.__file__).parent
FRAME = "identify/frame_kernels.py"


def _copy(name: str, to: Path) -> None:
    (to / name).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(STARID / name, to / name)


def test_a_change_to_the_kernels_a_module_calls_makes_its_cache_stale(tmp_path):
    """frame_kernels compiles kernels' code into its own: editing kernels.py alone (what
    moved the sky map's layout under a cached frame_kernels) must change frame_kernels'
    stamp — numba's own stamp, its file's hash, does not."""
    for name in jit_cache.DEPENDS[FRAME]:
        _copy(name, tmp_path)
    before = jit_cache.source_stamp(str(tmp_path / FRAME))
    own = (tmp_path / FRAME).read_bytes()
    with open(tmp_path / "identify/match_kernels.py", "a") as f:
        f.write("\n# an edit\n")
    assert jit_cache.source_stamp(str(tmp_path / FRAME)) != before
    assert (tmp_path / FRAME).read_bytes() == own
    with open(tmp_path / "catalog/pair_index.py", "a") as f:  # a constant the kernels read
        f.write("\n# an edit\n")
    assert jit_cache.source_stamp(str(tmp_path / "identify/match_kernels.py")) != \
        jit_cache.source_stamp(str(STARID / "identify/match_kernels.py"))


def test_the_kernels_are_cached_with_their_dependencies_in_the_stamp():
    for fn in (kernels.search, kernels.quick_checks, frame_kernels.solve_frame_packed):
        locator = fn._cache._impl.locator
        assert isinstance(locator, jit_cache._DependsLocator), fn
        inner, ours, module, numpy_version = locator.get_source_stamp()
        assert inner == locator._inner.get_source_stamp()  # numba's own stamp kept
        assert ours == jit_cache.source_stamp(fn.py_func.__code__.co_filename)
        assert module == fn.py_func.__module__
        assert numpy_version == np.__version__  # numba types numpy's calls by its rules


def test_the_same_file_under_another_import_name_is_cached_apart():
    """``pytest --doctest-modules starid/`` imports the kernel modules as ``starid.*``
    beside ``adfusion.starid.*``: their cached functions name that module, and an
    ``adfusion`` process that loaded them failed on ``No module named 'starid'``. The
    import name is part of the stamp, so neither loads the other's entries."""
    py_func = frame_kernels.solve_frame.py_func
    twin = type(py_func)(py_func.__code__, py_func.__globals__, py_func.__name__)
    twin.__module__ = "starid.identify.frame_kernels"
    here = jit_cache._DependsLocator.from_function(py_func, py_func.__code__.co_filename)
    there = jit_cache._DependsLocator.from_function(twin, py_func.__code__.co_filename)
    assert here.get_cache_path() == there.get_cache_path()
    assert here.get_source_stamp() != there.get_source_stamp()


def test_every_module_a_kernel_module_imports_is_in_its_stamp():
    """Jitted functions and constants imported from another of our modules are compiled
    in: each such module must be among the file's DEPENDS."""
    for name, deps in jit_cache.DEPENDS.items():
        tree = ast.parse((STARID / name).read_text())
        imported = {node.module[len("adfusion.starid."):].replace(".", "/") + ".py"
                    for node in tree.body
                    if isinstance(node, ast.ImportFrom) and node.module
                    and node.module.startswith("adfusion.starid.")}
        imported.discard("jit_cache.py")
        assert deps[0] == name and imported <= set(deps), (name, imported - set(deps))


def test_sources_that_are_no_plain_files_keep_numbas_own_cache(tmp_path, monkeypatch):
    """In a zip or a frozen application the modules beside a kernel module cannot be
    read: numba's own locators take over (the import failed with NotADirectoryError)."""
    _copy(FRAME, tmp_path)
    monkeypatch.setattr(jit_cache, "_HERE", str(tmp_path))
    py_func = frame_kernels.solve_frame.py_func
    assert jit_cache._DependsLocator.from_function(
        py_func, str(tmp_path / FRAME)) is None
    for name in jit_cache.DEPENDS[FRAME]:
        _copy(name, tmp_path)
    assert jit_cache._DependsLocator.from_function(
        py_func, str(tmp_path / FRAME)) is not None


def test_warm_up_loads_every_kernel_a_frame_of_noise_needs():
    """After Solver.warm_up, a frame that ends without an answer compiles nothing (the
    first one after kernels.prepare() took 4.9 s compiling frame_kernels.verify_weak)."""
    import subprocess
    import sys

    code = (
        "from adfusion import starid\n"
        "from adfusion.starid.identify import frame_kernels as f\n"
        "s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),"
        " starid.Camera.pinhole(1024, 768, 15.0))\n"
        "s.warm_up(triangles=False)\n"
        "print(len(f.verify_weak.signatures), len(f.solve_frame_packed.signatures))\n")
    out = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["1", "1"]
