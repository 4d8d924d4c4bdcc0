"""The command line's error kinds: what makes ``adfusion`` exit 2 rather than 1.

Example:
    >>> issubclass(UsageError, ValueError)
    True
"""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """The command line is wrong or incomplete — a flag's value, a flag that must be given
    (``--fps`` for a folder, ``--camera`` or ``--fov`` without a camera model), a path
    that names no file, an output that is a folder or the input: exit code 2, like
    argparse's own usage errors. What is wrong inside an input, or during a run, is a
    ``ValueError`` and exit code 1."""
