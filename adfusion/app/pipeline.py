"""Logs in, logs out: the former home of ``simulate`` and ``replay``, kept for callers.

The replay is :mod:`adfusion.app.replay` (sources → stages → sinks); the simulation writer
is :mod:`adfusion.app.replay.simulate`.

Example:
    >>> from adfusion.app.pipeline import replay, simulate
    >>> from adfusion.app import replay as package
    >>> replay is package.replay and simulate is package.simulate
    True
"""

from adfusion.app.replay import ReplaySummary, replay, simulate

__all__ = ["ReplaySummary", "replay", "simulate"]
