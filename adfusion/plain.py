"""Plain values and plain text: the project's one JSON conversion, and how messages show
names and lists.

* :func:`to_jsonable` / :func:`json_default` — plain Python values from numpy ones (JSON
  has no NaN, no arrays); every string comes out :func:`printable`;
* :func:`printable` — text as valid Unicode: a file name that is not UTF-8 (Python holds
  its undecodable bytes as lone surrogates, ``"\\udcff"``) shows them as ``\\xNN``, so the
  text encodes as strict UTF-8 and strict JSON readers accept it. Every place a name enters
  JSON or MCAP text (the log's metadata, the replay summary, ``--json``) goes through it;
* :func:`listed` — a list in a message as plain text, ``a.png, b.png, c.png and 4 more``,
  never a Python repr (``['a.png', 'b.png']``, ``{'tracking': 3}``, a tuple).

A leaf below every layer (it imports nothing of ours), so the log writer
(:mod:`adfusion.logs`), the scenario configurations (:mod:`adfusion.sensors`), the cache
keys (:mod:`adfusion.starid.catalog.cache`) and every message share it without depending
on each other.

Example:
    >>> import json
    >>> import numpy as np
    >>> to_jsonable({"q": np.array([1.0, 0.0, 0.0, 0.0]), "nis": float("nan")})
    {'q': [1.0, 0.0, 0.0, 0.0], 'nis': None}
    >>> json.dumps({"n": np.int64(3)}, default=json_default)
    '{"n": 3}'
    >>> printable("frame-\\udcff.png")  # the file b"frame-\\xff.png"
    'frame-\\\\xff.png'
    >>> listed(["a.png", "b.png", "c.png", "d.png", "e.png"])
    'a.png, b.png, c.png and 2 more'
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import Any

import numpy as np

__all__ = ["json_default", "listed", "printable", "to_jsonable"]


def to_jsonable(value: Any) -> Any:
    """Plain-Python copy of ``value``: numpy arrays → lists, numpy scalars → numbers, tuples →
    lists, datetimes → ISO 8601 text, paths → text, non-finite floats → ``None`` (JSON has no
    NaN; JavaScript's ``JSON.parse`` rejects it), every string and key :func:`printable`
    (strict JSON has no lone surrogates)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str):
        return printable(value)
    if isinstance(value, bool | int) or value is None:
        return value
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            return to_jsonable(value.astype(object).tolist())
        return value.tolist()
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, Mapping):
        return {printable(str(k)): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, os.PathLike):
        return printable(os.fsdecode(value))
    raise TypeError(f"cannot write {type(value).__name__} as JSON: {value!r}")


def json_default(value: Any) -> Any:
    """``json.dumps(…, default=json_default)``: the same conversions, applied only to the
    values the encoder cannot write itself (no copy of the whole structure)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"cannot write {type(value).__name__} as JSON: {value!r}")


_SURROGATE = re.compile("[\ud800-\udfff]")


def _escaped(m: re.Match[str]) -> str:
    c = ord(m.group())
    return f"\\x{c - 0xDC00:02x}" if 0xDC80 <= c <= 0xDCFF else f"\\u{c:04x}"


def printable(text: str) -> str:
    """``text`` as valid Unicode, for every place text leaves the program as UTF-8 (JSON,
    MCAP metadata, a terminal): each lone surrogate — how :func:`os.fsdecode` holds a file
    name's byte that is not UTF-8 — becomes ``\\xNN`` of that byte (as Python's
    ``backslashreplace`` shows it, and :func:`adfusion.imagefiles.shown_path` in
    messages), any other ``\\uNNNN``.
    Text that is valid already comes back as it is (the same object).

    The escape is for reading, not for opening the file again: a name that itself holds
    ``\\xff`` reads the same. Strict decoders (``json.loads`` of strictly decoded UTF-8
    bytes, Rust's ``serde_json``, ``jq``) accept the result; a lone surrogate they refuse.

    >>> printable("caf\\udce9.png"), printable("café.png"), printable("a\\ud800b")
    ('caf\\\\xe9.png', 'café.png', 'a\\\\ud800b')
    """
    if text.isascii():
        return text
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return _SURROGATE.sub(_escaped, text)
    return text


def listed(items: Iterable[object], first: int | None = 3, *, sep: str = ", ") -> str:
    """``items`` as plain text for a message: their ``str`` (:func:`printable`) joined by
    ``sep``, the first ``first`` of them and how many more (``None``: all), ``"none"``
    for none — never a Python repr of the list, dict, set or tuple.

    >>> listed(["a.png", "b.png", "c.png", "d.png"])
    'a.png, b.png, c.png and 1 more'
    >>> listed(("lost-in-space", "tracking"), None), listed([])
    ('lost-in-space, tracking', 'none')
    >>> listed(f"{mode} {n}" for mode, n in {"tracking": 80, "lost-in-space": 3}.items())
    'tracking 80, lost-in-space 3'
    """
    texts = [printable(str(x)) for x in items]
    if not texts:
        return "none"
    if first is None or len(texts) <= first:
        return sep.join(texts)
    return sep.join(texts[:first]) + f" and {len(texts) - first} more"
