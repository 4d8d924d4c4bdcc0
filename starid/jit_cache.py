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

Compiled at install: ``pip install .`` runs :func:`adfusion.starid.prepare.prepare` in its
build and ships the cache's entries inside the package (:func:`export`, into
``adfusion/starid/_jit/<module>/``). Nothing in them depends on where the package lies —
the stamp is the sources' contents, the module's name and numpy's version, and numba's
index adds its own version and the CPU's name and features — so the first import of a
kernel module copies its entries into numba's cache folder unless they are there already
(:func:`seed`), and the first solve loads them instead of compiling (~1.5 min). On another
CPU, numba or numpy the entries do not match and numba compiles, as without them
(docs/decisions.md, "First use"). ``ADFUSION_JIT_PREBUILT`` names another folder of them.

Use it as ``numba.njit(cache=True)`` in the kernel modules of this package
(``_jit = njit_cached(nogil=True)``; a module not in :data:`DEPENDS` is keyed by its own
file):

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
import pickle
import shutil
import sys
import uuid
from collections.abc import Callable

import numba
import numpy as np
from numba.core import caching

__all__ = ["DEPENDS", "export", "njit_cached", "prebuilt_root", "seed", "source_stamp"]

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
    "catalog/triangle_index.py": ("catalog/triangle_index.py", "catalog/pair_index.py",
                                  "catalog/cache.py"),
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
    :func:`source_stamp`, the module's import name and numpy's version added to its source
    stamp.

    The name, because a cached function's environment names its module, and loading it
    imports that module: the same file imported under another name (``starid.identify.kernels``,
    as ``pytest --doctest-modules starid/`` imports it beside ``adfusion.starid``) wrote
    entries that every later ``adfusion`` process loaded and failed on (``No module named
    'starid'``), until the cache was cleared. numpy's version, because numba types numpy's
    functions by the installed numpy's rules: entries compiled at install (:func:`export`)
    in a build environment of another numpy must not load."""

    def __init__(self, inner: caching._CacheLocator, py_file: str, module: str = "") -> None:
        self._inner = inner
        self._py_file = py_file
        self._module = module

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return (self._inner.get_source_stamp(), source_stamp(self._py_file), self._module,
                np.__version__)

    def get_disambiguator(self) -> str:
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        root, key = _key_of(py_file)
        # numba's own locators where the sources are not plain files (a zip, a frozen app),
        # and for functions not of this package (the locator list is numba's, global)
        if key in DEPENDS:
            if root != _HERE.replace(os.sep, "/") or not all(
                    os.path.isfile(os.path.join(root, dep)) for dep in DEPENDS[key]):
                return None
        elif not (py_func.__module__.startswith("adfusion.") and os.path.isfile(py_file)):
            return None
        for other in _IMPL._locator_classes:
            if other is not cls:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    self = cls(inner, py_file, py_func.__module__)
                    seed(self)
                    return self
        return None


def prebuilt_root() -> str:
    """The folder of the entries compiled at install: ``$ADFUSION_JIT_PREBUILT``, else
    ``_jit`` beside this module (absent in a checkout or an editable install).

    >>> os.path.basename(prebuilt_root()) == "_jit" or "ADFUSION_JIT_PREBUILT" in os.environ
    True
    """
    return os.environ.get("ADFUSION_JIT_PREBUILT") or os.path.join(_HERE, "_jit")


def _read_index(path: str) -> tuple[object, dict] | None:
    """(stamp, overloads) of a numba index file of this numba version, else None. Only
    once its module is whole: the overloads' types name classes the module defines."""
    try:
        with open(path, "rb") as f:
            if pickle.load(f) != numba.__version__:
                return None
            return pickle.loads(f.read())
    except Exception:  # a partial or foreign file: no entries
        return None


def _copy_atomic(src: str, dst: str) -> None:
    # another process may be reading dst or seeding it too: it sees the old file or the new
    tmp = f"{dst}.tmp.{uuid.uuid4().hex}"
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _read_bytes(path: str) -> bytes | None:
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError:
        return None


_SEEDED: set[tuple[str, str]] = set()


def seed(locator: _DependsLocator) -> int:
    """Copy the prebuilt entries (:func:`prebuilt_root`) of ``locator``'s module into its
    numba cache folder, and return how many functions' entries it copied. Each function's
    entries come with a stamp file (``.nbs``, plain Python values: numba's version, the
    source stamp, the data files' names): those of another numba or other sources are
    left, and the stamp file, copied last, marks the target as seeded from them — a later
    process leaves it, and the entries numba adds to that index, alone. Once per module
    and folder in a process, at its import (so nothing here unpickles numba's types: the
    module defining them is not whole yet); a folder it cannot write is left to numba,
    which then compiles as without prebuilt entries.

    >>> from adfusion.starid.identify import frame_kernels
    >>> seed(frame_kernels.solve_frame._cache._impl.locator)  # done at the import
    0
    """
    module, target = locator._module, locator.get_cache_path()
    if (module, target) in _SEEDED:
        return 0
    _SEEDED.add((module, target))
    src = os.path.join(prebuilt_root(), module)
    try:
        names = sorted(n for n in os.listdir(src) if n.endswith(".nbs"))
    except OSError:
        return 0
    stamp, copied = locator.get_source_stamp(), 0
    try:
        for name in names:
            raw = _read_bytes(os.path.join(src, name))
            try:
                version, theirs, data = pickle.loads(raw or b"")
            except Exception:  # not ours: skip it
                continue
            if version != numba.__version__ or theirs != stamp \
                    or _read_bytes(os.path.join(target, name)) == raw:
                continue
            locator.ensure_cache_path()
            index = name[:-len(".nbs")] + ".nbi"
            for f in (*data, index, name):  # the data first: an index names only files there
                _copy_atomic(os.path.join(src, f), os.path.join(target, f))
            copied += 1
    except OSError:
        pass
    return copied


def export(dest: str) -> int:
    """Copy the current cache entries of every cached kernel of the modules loaded in this
    process into ``dest/<module>/``, each function's with its stamp file (the layout
    :func:`seed` reads); returns how many functions' entries it copied. The build runs it
    after :func:`adfusion.starid.prepare.prepare`.

    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     n = export(folder)
    >>> n >= 0
    True
    """
    copied = 0
    for name, mod in list(sys.modules.items()):
        if not name.startswith("adfusion.") or mod is None:
            continue
        for obj in list(vars(mod).values()):
            cache = getattr(obj, "_cache", None)
            impl = getattr(cache, "_impl", None)
            if not isinstance(getattr(impl, "locator", None), _DependsLocator) \
                    or obj.py_func.__module__ != name:
                continue
            cf, stamp = cache._cache_file, impl.locator.get_source_stamp()
            index = _read_index(cf._index_path)
            if index is None or index[0] != stamp or not index[1]:
                continue
            out = os.path.join(dest, name)
            os.makedirs(out, exist_ok=True)
            data = sorted(set(index[1].values()))
            for f in data:
                shutil.copyfile(os.path.join(cf._cache_path, f), os.path.join(out, f))
            base = os.path.basename(cf._index_path)
            shutil.copyfile(cf._index_path, os.path.join(out, base))
            with open(os.path.join(out, base[:-len(".nbi")] + ".nbs"), "wb") as f:
                pickle.dump((numba.__version__, stamp, data), f, protocol=4)
            copied += 1
    return copied


_HERE = os.path.dirname(os.path.abspath(__file__))


def _register() -> None:
    classes = _IMPL._locator_classes
    if _DependsLocator not in classes:
        classes.insert(0, _DependsLocator)


def njit_cached(**options) -> Callable:
    """``numba.njit(cache=True, **options)`` with the cache keyed by :data:`DEPENDS` (a
    module of this package not named there: by its own file's contents)."""
    _register()
    return numba.njit(cache=True, **options)
