"""The compiled kernels' on-disk cache (starid.jit_cache): a kernel module's cached code is
stale as soon as any module it compiles in changes, not only its own file."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

from adfusion.starid import frame_kernels, jit_cache, kernels

STARID = Path(kernels.__file__).parent


def test_a_change_to_the_kernels_a_module_calls_makes_its_cache_stale(tmp_path):
    """frame_kernels compiles kernels' code into its own: editing kernels.py alone (what
    moved the sky map's layout under a cached frame_kernels) must change frame_kernels'
    stamp — numba's own stamp, its file's hash, does not."""
    for name in jit_cache.DEPENDS["frame_kernels.py"]:
        shutil.copy(STARID / name, tmp_path / name)
    before = jit_cache.source_stamp(str(tmp_path / "frame_kernels.py"))
    own = (tmp_path / "frame_kernels.py").read_bytes()
    with open(tmp_path / "kernels.py", "a") as f:
        f.write("\n# an edit\n")
    assert jit_cache.source_stamp(str(tmp_path / "frame_kernels.py")) != before
    assert (tmp_path / "frame_kernels.py").read_bytes() == own
    with open(tmp_path / "verify.py", "a") as f:  # a constant kernels.py reads
        f.write("\n# an edit\n")
    assert jit_cache.source_stamp(str(tmp_path / "kernels.py")) != \
        jit_cache.source_stamp(str(STARID / "kernels.py"))


def test_the_kernels_are_cached_with_their_dependencies_in_the_stamp():
    for fn in (kernels.search, kernels.quick_checks, frame_kernels.solve_frame_packed):
        locator = fn._cache._impl.locator
        assert isinstance(locator, jit_cache._DependsLocator), fn
        inner, ours = locator.get_source_stamp()
        assert inner == locator._inner.get_source_stamp()  # numba's own stamp kept
        assert ours == jit_cache.source_stamp(fn.py_func.__code__.co_filename)


def test_every_module_a_kernel_module_imports_is_in_its_stamp():
    """Jitted functions and constants imported from another of our modules are compiled
    in: each such module must be among the file's DEPENDS."""
    for name, deps in jit_cache.DEPENDS.items():
        tree = ast.parse((STARID / name).read_text())
        imported = {node.module.rsplit(".", 1)[1] + ".py" for node in tree.body
                    if isinstance(node, ast.ImportFrom) and node.module
                    and node.module.startswith("adfusion.starid.")}
        imported.discard("jit_cache.py")
        assert deps[0] == name and imported <= set(deps), (name, imported - set(deps))
