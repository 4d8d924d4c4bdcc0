"""numba's on-disk cache for the compiled kernels, keyed by every module a kernel module
compiles in — not only its own file.

Why: numba keys a cached function by its own source file. A kernel that calls kernels of
another module (:mod:`starid.identify.frame_kernels` calls the search, check and fit
kernels of :mod:`starid.identify`, which read constants of :mod:`starid.catalog.pair_index`
and :mod:`starid.catalog.triangle_index`) has their code compiled into its own;
when only the other module changes — an upgrade, a ``git pull`` — numba still loads the
old compiled code and runs it
with the new Python around it. That happened here: the sky map's layout changed in
``kernels.py``, the cached ``frame_kernels`` kept reading the old one, and every frame of
noise lost its weak candidates. :func:`njit_cached` adds the contents of those modules
(:data:`DEPENDS`) to the cache's source stamp, so a change to any of them recompiles.
Where the sources are no plain files (a zip, a frozen application) numba's own locators
apply, and ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, replaces every locator, this one too.

Use it as ``numba.njit(cache=True)`` in a module of :data:`DEPENDS`
(``_jit = njit_cached(nogil=True)``; elsewhere it caches as numba does):

Example:
    >>> from adfusion.starid import jit_cache
    >>> from adfusion.starid.identify import frame_kernels
    >>> jit_cache.DEPENDS["identify/frame_kernels.py"][:2]
    ('identify/frame_kernels.py', 'identify/check_kernels.py')
    >>> type(frame_kernels.solve_frame._cache._impl.locator).__name__
    '_DependsLocator'
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable

import numba
from numba.core import caching

__all__ = ["DEPENDS", "njit_cached", "source_stamp"]

#: the modules each kernel module compiles in (paths below the starid folder), itself first;
#: a module not named here is keyed by its own file, as numba does
_IDX = ("catalog/pair_index.py", "catalog/triangle_index.py")
DEPENDS: dict[str, tuple[str, ...]] = {
    "identify/match_kernels.py": ("identify/match_kernels.py", *_IDX),
    "identify/check_kernels.py": ("identify/check_kernels.py", "identify/match_kernels.py",
                                  *_IDX),
    "identify/search_kernels.py": ("identify/search_kernels.py", "identify/check_kernels.py",
                                   "identify/match_kernels.py", *_IDX),
    "identify/fit_kernels.py": ("identify/fit_kernels.py", "identify/check_kernels.py",
                                "identify/match_kernels.py", *_IDX),
    "identify/frame_kernels.py": ("identify/frame_kernels.py", "identify/check_kernels.py",
                                  "identify/fit_kernels.py", "identify/match_kernels.py",
                                  "identify/search_kernels.py", *_IDX),
    "tracking/kernels.py": ("tracking/kernels.py", "identify/fit_kernels.py",
                            "identify/check_kernels.py", "identify/match_kernels.py", *_IDX),
}


def _key_of(py_file: str) -> tuple[str, str]:
    """(the starid folder, the :data:`DEPENDS` key) of ``py_file``; the key is the file's
    name alone when it is none of them."""
    path = os.path.abspath(py_file).replace(os.sep, "/")
    for key in DEPENDS:
        if path.endswith("/" + key):
            return path[: -len(key) - 1], key
    folder, name = os.path.split(path)
    return folder, name


def source_stamp(py_file: str) -> str:
    """SHA-256 of the contents of ``py_file``'s :data:`DEPENDS` (or of the file alone).

    >>> import adfusion.starid.identify.frame_kernels as k
    >>> source_stamp(k.__file__) != source_stamp(k.__file__.replace("frame_", "fit_"))
    True
    """
    root, key = _key_of(py_file)
    h = hashlib.sha256()
    for dep in DEPENDS.get(key, (key,)):
        with open(os.path.join(root, dep), "rb") as f:
            h.update(dep.encode() + b"\0" + f.read())
    return h.hexdigest()


# numba's cache implementation (CacheImpl; _CacheImpl in older releases)
_IMPL = getattr(caching, "CacheImpl", None) or caching._CacheImpl


class _DependsLocator(caching._CacheLocator):
    """numba's own locator for the file (cache directory, disambiguator), with
    :func:`source_stamp` and the module's import name added to its source stamp.

    The name, because a cached function's environment names its module, and loading it
    imports that module: the same file imported under another name (``starid.identify.kernels``,
    as ``pytest --doctest-modules starid/`` imports it beside ``adfusion.starid``) wrote
    entries that every later ``adfusion`` process loaded and failed on (``No module named
    'starid'``), until the cache was cleared."""

    def __init__(self, inner: caching._CacheLocator, py_file: str, module: str = "") -> None:
        self._inner = inner
        self._py_file = py_file
        self._module = module

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return self._inner.get_source_stamp(), source_stamp(self._py_file), self._module

    def get_disambiguator(self) -> str:
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        root, key = _key_of(py_file)
        # numba's own locators where the sources are not plain files (a zip, a frozen app)
        if key not in DEPENDS or root != _HERE.replace(os.sep, "/") or not all(
                os.path.isfile(os.path.join(root, dep)) for dep in DEPENDS[key]):
            return None
        for other in _IMPL._locator_classes:
            if other is not cls:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, py_file, py_func.__module__)
        return None


_HERE = os.path.dirname(os.path.abspath(__file__))


def _register() -> None:
    classes = _IMPL._locator_classes
    if _DependsLocator not in classes:
        classes.insert(0, _DependsLocator)


def njit_cached(**options) -> Callable:
    """``numba.njit(cache=True, **options)`` with the cache keyed by :data:`DEPENDS`."""
    _register()
    return numba.njit(cache=True, **options)
