"""JSON helpers for the ``logs`` boundary: numpy → JSON values, metadata string maps.

MCAP metadata maps strings to strings; :func:`encode_metadata` keeps plain strings readable in
Foxglove and JSON-encodes everything else so that :func:`decode_metadata` restores it exactly.

Example:
    >>> from adfusion.logs.jsonio import decode_metadata, encode_metadata
    >>> enc = encode_metadata({"scenario": "oedipus", "seed": 7, "note": "42"})
    >>> enc
    {'scenario': 'oedipus', 'seed': '7', 'note': '"42"'}
    >>> decode_metadata(enc) == {"scenario": "oedipus", "seed": 7, "note": "42"}
    True
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from adfusion.plain import json_default, to_jsonable


def dumps(value: Any) -> str:
    """Compact, strict JSON text of ``value`` (after :func:`to_jsonable`).

    Tried first without the copy — the encoder meets numpy values through ``default`` —
    and redone with it when a non-finite float makes strict JSON fail (a replay writes a
    few records a frame; the copy cost ~0.15 ms of them). Both give the same text, except
    that dict keys ``True``/``False``/``None`` come out as JSON spells them."""
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False, default=json_default)
    except ValueError:  # NaN or infinity: to_jsonable turns them into null
        return json.dumps(to_jsonable(value), separators=(",", ":"), allow_nan=False)


def _parses_as_json(text: str) -> bool:
    try:
        json.loads(text)
    except ValueError:
        return False
    return True


def encode_metadata(data: Mapping[str, Any]) -> dict[str, str]:
    """String map for an MCAP metadata record: strings stay as they are unless they would read
    back as another JSON value (then they are JSON-quoted); everything else is JSON text."""
    out: dict[str, str] = {}
    for key, value in data.items():
        if isinstance(value, str) and not _parses_as_json(value):
            out[str(key)] = value
        else:
            out[str(key)] = dumps(value)
    return out


def decode_metadata(data: Mapping[str, str]) -> dict[str, Any]:
    """Inverse of :func:`encode_metadata` (values that are not JSON stay strings)."""
    out: dict[str, Any] = {}
    for key, text in data.items():
        try:
            out[key] = json.loads(text)
        except ValueError:
            out[key] = text
    return out
