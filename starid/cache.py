"""On-disk cache for derived arrays (parsed catalogues, pattern indexes).

Entries are ``.npz`` files named by a SHA-256 of everything that determines their
content: a kind tag, the parameters, and a fingerprint of each source file. A changed
parameter or a changed source therefore maps to a different file and can never reuse a
stale entry; there is no invalidation logic to get wrong.

The directory is ``$ADFUSION_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/adfusion``,
else ``~/.cache/adfusion``. Set ``ADFUSION_CACHE_DIR=off`` to disable caching.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.cache import cached_arrays
    >>> arrays = cached_arrays("demo", {"n": 3}, [], lambda: {"x": np.arange(3)})
    >>> arrays["x"].tolist()
    [0, 1, 2]
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from adfusion.plain import json_default

__all__ = ["cache_dir", "cache_key", "cached_arrays", "file_fingerprint", "source_digest"]

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
    root.mkdir(parents=True, exist_ok=True)
    return root


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


def cached_arrays(
    kind: str,
    params: dict,
    sources: Iterable[str | os.PathLike[str]],
    build: Callable[[], dict[str, np.ndarray]],
) -> dict[str, np.ndarray]:
    """Load the arrays for (kind, params, sources) from the cache, or build and store them.

    ``build`` returns a dict of numpy arrays. Writes are atomic (temp file + rename), so
    a crash or two processes racing never leave a half-written entry behind.
    """
    root = cache_dir()
    if root is None:
        return build()
    path = root / f"{kind}-{cache_key(kind, params, sources)}.npz"
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError):
            path.unlink(missing_ok=True)  # corrupt entry: rebuild below
    arrays = build()
    fd, tmp = tempfile.mkstemp(dir=root, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)
    return arrays
