"""Rotation conventions for the estimation side: the same module as :mod:`starid.rotations`.

One implementation only. It lives in ``starid`` because ``starid`` is the bottom of the
dependency graph (``starid`` → ``adfusion``); this name exists so filter code reads
``from adfusion import rotations``.

Example:
    >>> from adfusion import rotations as rot
    >>> rot.normalize([2.0, 0.0, 0.0, 0.0]).tolist()
    [1.0, 0.0, 0.0, 0.0]
"""

from starid.rotations import *  # noqa: F403
from starid.rotations import __all__  # noqa: F401
