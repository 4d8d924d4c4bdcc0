"""The fuzz runs' one exception: a broken promise (:mod:`adfusion.app.fuzz`).

Example:
    >>> str(FuzzViolation("traceback", "a case"))
    'traceback: a case'
"""

from __future__ import annotations

__all__ = ["FuzzViolation"]


class FuzzViolation(AssertionError):
    """A broken promise: ``kind`` (traceback, silent-loss, wrong-attitude, cli) and what."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
