"""Plain Python values from numpy ones: the project's one JSON conversion.

A leaf below every layer (it imports nothing of ours), so the log writer
(:mod:`adfusion.logs`), the scenario configurations (:mod:`adfusion.sensors`) and the cache
keys (:mod:`adfusion.starid.catalog.cache`) share it without depending on each other.

Example:
    >>> import json
    >>> import numpy as np
    >>> to_jsonable({"q": np.array([1.0, 0.0, 0.0, 0.0]), "nis": float("nan")})
    {'q': [1.0, 0.0, 0.0, 0.0], 'nis': None}
    >>> json.dumps({"n": np.int64(3)}, default=json_default)
    '{"n": 3}'
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from datetime import datetime
from typing import Any

import numpy as np

__all__ = ["json_default", "to_jsonable"]


def to_jsonable(value: Any) -> Any:
    """Plain-Python copy of ``value``: numpy arrays → lists, numpy scalars → numbers, tuples →
    lists, datetimes → ISO 8601 text, paths → text, non-finite floats → ``None`` (JSON has no
    NaN; JavaScript's ``JSON.parse`` rejects it)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str | bool | int) or value is None:
        return value
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            return to_jsonable(value.astype(object).tolist())
        return value.tolist()
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
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
