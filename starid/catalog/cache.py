"""On-disk cache for derived arrays (parsed catalogues, pattern indexes).

Entries are ``.npz`` files named by a SHA-256 of everything that determines their
content: a kind tag, the parameters, and a fingerprint of each source file. A changed
parameter or a changed source therefore maps to a different file and can never reuse a
stale entry; there is no invalidation logic to get wrong.

The directory is ``$ADFUSION_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/adfusion``,
else ``~/.cache/adfusion``. Set ``ADFUSION_CACHE_DIR=off`` to disable caching.

Size: the entries together are kept under ``$ADFUSION_CACHE_MAX_MB`` megabytes (default
2000). Each load marks its entry used (its modification time); after a write, the least
recently used entries are removed until the rest fit, the new entry last. An entry larger
than the whole cap is not kept. :func:`cache_info` lists the entries, :func:`cache_clear`
removes them (``adfusion cache info`` / ``adfusion cache clear``).

Integrity: each entry holds, beside its arrays, a SHA-256 of them (:func:`arrays_digest`:
every array's name, dtype, shape and bytes), checked on every load. An entry that does not
match it (rewritten by a bug or by hand), that cannot be read (a flipped byte, a truncated
file) or that has no digest (written before digests) is a miss: it is rebuilt and rewritten,
with one :class:`CacheWarning` naming the file for the damaged ones — never trusted, never an
exception. A folder that cannot be made or written is an :class:`OSError` naming
``ADFUSION_CACHE_DIR``.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.catalog.cache import cached_arrays
    >>> arrays = cached_arrays("demo", {"n": 3}, [], lambda: {"x": np.arange(3)})
    >>> arrays["x"].tolist()
    [0, 1, 2]
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from adfusion.plain import json_default

__all__ = ["CacheEntry", "CacheWarning", "arrays_digest", "cache_clear", "cache_dir",
           "cache_info", "cache_key", "cache_limit_bytes", "cached_arrays", "evict",
           "file_fingerprint", "source_digest"]

DEFAULT_MAX_MB = 2000.0
DIGEST_NAME = "__sha256__"  # the member of an entry holding the digest of the others


class CacheWarning(UserWarning):
    """A cache entry was damaged or tampered with and has been rebuilt (or could not be
    stored): the result is right, the user is told."""

_FINGERPRINTS: dict[tuple[str, int, int], str] = {}


def cache_dir() -> Path | None:
    """Return the cache directory (created on demand), or None when caching is off."""
    env = os.environ.get("ADFUSION_CACHE_DIR")
    if env is not None and env.strip().lower() in {"off", "0", "none", ""}:
        return None
    if env:
        root = Path(env)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = (Path(xdg) if xdg else Path.home() / ".cache") / "adfusion"
    try:
        root.mkdir(parents=True, exist_ok=True)
        if not root.is_dir():
            raise NotADirectoryError(20, "not a folder")
    except OSError as exc:
        raise _dir_error(exc, root, "cannot be created") from None
    return root


def _dir_error(exc: OSError, root: Path, what: str) -> OSError:
    """A one-line error about the cache folder, naming the variable that chooses it."""
    why = exc.strerror or type(exc).__name__
    where = (f"ADFUSION_CACHE_DIR={os.environ['ADFUSION_CACHE_DIR']}"
             if os.environ.get("ADFUSION_CACHE_DIR") else f"the cache folder {root}")
    return type(exc)(f"{where}: the cache folder {what} ({why}): set ADFUSION_CACHE_DIR to "
                     "a writable folder, or to off to disable the cache")


def file_fingerprint(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, memoised per (path, size, mtime) within the process."""
    p = Path(path)
    st = p.stat()
    memo_key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    if memo_key not in _FINGERPRINTS:
        h = hashlib.sha256()
        with p.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        _FINGERPRINTS[memo_key] = h.hexdigest()
    return _FINGERPRINTS[memo_key]


def source_digest(*modules: str) -> str:
    """A digest of the Python sources of ``modules`` (a package: every ``.py`` file in it and
    its subpackages). Results that depend on the code carry it, so a cache or a partial file
    is not reused after the code changed.

    >>> len(source_digest("adfusion.starid"))
    16
    """
    import importlib.util

    h = hashlib.sha256()
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise ValueError(f"no module {name!r}")
        if spec.submodule_search_locations:  # a package
            for loc in spec.submodule_search_locations:
                for f in sorted(Path(loc).rglob("*.py")):
                    h.update(f"{name}/{f.relative_to(loc).as_posix()}\0".encode())
                    h.update(f.read_bytes())
        else:
            h.update(f"{name}\0".encode() + Path(spec.origin).read_bytes())
    return h.hexdigest()[:16]


def cache_key(kind: str, params: dict, sources: Iterable[str | os.PathLike[str]] = ()) -> str:
    """Stable hex key for a cache entry from its kind, parameters and source files."""
    payload = {
        "kind": kind,
        "params": params,
        "sources": [file_fingerprint(s) for s in sources],
        "format": 1,
    }
    text = json.dumps(payload, sort_keys=True, default=json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def arrays_digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 (hex) of a set of arrays: each one's name, dtype, shape and bytes, by name.

    >>> arrays_digest({"x": np.arange(3)}) == arrays_digest({"x": np.arange(3)})
    True
    >>> arrays_digest({"x": np.arange(3)}) == arrays_digest({"x": np.arange(3) + 1})
    False
    """
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.data)
    return h.hexdigest()


def _read_entry(path: Path) -> tuple[dict[str, np.ndarray] | None, str | None]:
    """The arrays of an entry, checked against its digest: ``(arrays, None)``; else
    ``(None, why)`` for a damaged entry, ``(None, None)`` for one without a digest (written
    before digests: a plain miss) or one gone meanwhile."""
    try:
        with path.open("rb") as f, np.load(f, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:  # removed meanwhile (evicted, cleared): a miss
        return None, None
    except AttributeError:  # np.load gave a bare array (an .npy), not an archive
        return None, "not an .npz archive"
    except Exception as exc:  # any damage: zip, npy header, CRC, EOF, …
        text = " ".join(str(exc).split()) or "unreadable"
        return None, f"unreadable: {type(exc).__name__}: {text[:120]}"
    stored = arrays.pop(DIGEST_NAME, None)
    if stored is None:
        return None, None
    if stored.shape != () or stored.dtype.kind != "U" or str(stored[()]) != arrays_digest(arrays):
        return None, "its arrays do not match their digest"
    return arrays, None


def _write_entry(root: Path, path: Path, arrays: dict[str, np.ndarray]) -> bool:
    """Store an entry atomically (a private temporary file renamed over it), with its
    digest. A folder that cannot be written is an error naming ``ADFUSION_CACHE_DIR``; a
    write that fails part way (a full disk) is a warning: the result is not cached."""
    if DIGEST_NAME in arrays:
        raise ValueError(f"a cached array may not be named {DIGEST_NAME!r}")
    try:
        fd, tmp = tempfile.mkstemp(dir=root, suffix=".npz.tmp")
    except OSError as exc:
        raise _dir_error(exc, root, "is not writable") from None
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays, **{DIGEST_NAME: np.array(arrays_digest(arrays))})
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        warnings.warn(CacheWarning(f"cache entry {path} could not be written "
                                   f"({exc.strerror or exc}): not cached (ADFUSION_CACHE_DIR)"),
                      stacklevel=3)
        return False
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return True


def cached_arrays(
    kind: str,
    params: dict,
    sources: Iterable[str | os.PathLike[str]],
    build: Callable[[], dict[str, np.ndarray]],
    valid: Callable[[dict[str, np.ndarray]], bool] | None = None,
) -> dict[str, np.ndarray]:
    """Load the arrays for (kind, params, sources) from the cache, or build and store them.

    ``build`` returns a dict of numpy arrays. ``valid``, if given, judges a loaded entry:
    one it rejects is rebuilt and replaced under the same key. An entry whose arrays do not
    match its digest, or that cannot be read, is rebuilt and replaced too, with one
    :class:`CacheWarning` naming it. Writes are atomic (temp file + rename), so a crash or
    two processes racing never leave a half-written entry behind; after a write the cache
    is trimmed to its cap (:func:`evict`).
    """
    root = cache_dir()
    if root is None:
        return build()
    path = root / f"{kind}-{cache_key(kind, params, sources)}.npz"
    damaged = None
    if path.exists():
        arrays, damaged = _read_entry(path)
        if arrays is not None and (valid is None or valid(arrays)):
            _touch(path)
            return arrays
    arrays = build()
    if _write_entry(root, path, arrays):
        if damaged is not None:
            warnings.warn(CacheWarning(f"cache entry {path} was damaged ({damaged}): rebuilt"),
                          stacklevel=2)
        evict(keep=path)
    elif damaged is not None:
        warnings.warn(CacheWarning(f"cache entry {path} was damaged ({damaged}): rebuilt, "
                                   "but not stored"), stacklevel=2)
    return arrays


@dataclass(frozen=True)
class CacheEntry:
    """One cache file: its path, kind (``"pattern-index"``, ``"hip2-raw"``, …), size in
    bytes and when it was last used (Unix time)."""

    path: Path
    kind: str
    size: int
    last_used: float


def env_size_bytes(name: str, default: float, unit: str, scale: float,
                   allow_zero: bool) -> int:
    """A size limit from the environment variable ``name`` in ``unit`` (``scale`` bytes
    each; ``default`` when unset), as bytes — one reader for the cache cap and the index's
    memory bound, with the error naming the variable. ``inf`` is no limit (the largest
    size a file system can hold, 2⁶³ − 1 bytes); ``nan`` and negative values are errors.

    >>> env_size_bytes("ADFUSION_NO_SUCH_LIMIT", 1.5, "gigabytes", 1e9, False)
    1500000000
    """
    env = os.environ.get(name, "").strip()
    try:
        value = float(env) if env else default
    except ValueError:
        raise ValueError(f"{name} must be a number of {unit}, got {env!r}") from None
    if not (value >= 0 if allow_zero else value > 0):
        raise ValueError(f"{name} must be {'≥ 0' if allow_zero else 'positive'}, got {env!r}")
    return min(int(min(value * scale, 2.0**63)), 2**63 - 1)  # inf: no limit


def cache_limit_bytes() -> int:
    """The cache's size cap: ``$ADFUSION_CACHE_MAX_MB`` megabytes (default 2000).

    >>> cache_limit_bytes() > 0
    True
    """
    return env_size_bytes("ADFUSION_CACHE_MAX_MB", DEFAULT_MAX_MB, "megabytes", 1e6, True)


def cache_info() -> list[CacheEntry]:
    """The cache's entries, most recently used first (empty when caching is off).

    >>> isinstance(cache_info(), list)
    True
    """
    root = cache_dir()
    if root is None:
        return []
    out = []
    for p in root.glob("*.npz"):
        try:
            st = p.stat()
        except OSError:  # removed meanwhile by another process
            continue
        out.append(CacheEntry(p, p.name.rsplit("-", 1)[0], st.st_size, st.st_mtime))
    return sorted(out, key=lambda e: -e.last_used)


def cache_clear(kind: str | None = None) -> tuple[int, int]:
    """Remove every entry (or those of one ``kind``); returns (files, bytes) removed.

    Leftover temporary files of interrupted writes go too.

    >>> n, size = cache_clear("no-such-kind")
    >>> n, size
    (0, 0)
    """
    n = size = 0
    for e in cache_info():
        if kind is None or e.kind == kind:
            e.path.unlink(missing_ok=True)
            n, size = n + 1, size + e.size
    root = cache_dir()
    if kind is None and root is not None:
        for p in root.glob("*.npz.tmp"):
            if time.time() - p.stat().st_mtime > 3600:  # not another process's live write
                p.unlink(missing_ok=True)
    return n, size


def evict(limit_bytes: int | None = None, keep: Path | None = None) -> list[CacheEntry]:
    """Remove least recently used entries until the cache fits ``limit_bytes`` (default
    :func:`cache_limit_bytes`); ``keep`` goes last. Returns the entries removed.

    >>> evict(10**15)
    []
    """
    limit = cache_limit_bytes() if limit_bytes is None else int(limit_bytes)
    entries = cache_info()
    total = sum(e.size for e in entries)
    # oldest first; the entry just written only when nothing else is left to remove
    order = sorted(entries, key=lambda e: (keep is not None and e.path == keep, e.last_used))
    removed = []
    for e in order:
        if total <= limit:
            break
        e.path.unlink(missing_ok=True)
        total -= e.size
        removed.append(e)
    return removed


def _touch(path: Path) -> None:
    """Mark an entry used (its mtime: atime is often not kept, see mount's relatime)."""
    try:
        os.utime(path)
    except OSError:  # read-only cache: still usable, just not ordered
        pass
