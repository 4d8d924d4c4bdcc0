"""Replay as sources → stages → sinks.

A **source** (:mod:`.sources`) yields the input's time-ordered messages and says what it
knows about the run (camera model, configuration). **Stages** (:mod:`.stages`) turn each
message into a :class:`~adfusion.app.replay.stages.Step`: detection runs ahead in a worker,
the estimation stage feeds the :class:`~adfusion.estimation.estimator.Estimator`
(identification and filter) and attaches what it did. **Sinks** (:mod:`.sinks`) take every
step: the log writer, the smoother's recorder, the summary counters. :func:`run` wires them;
:func:`replay` is the one-call form. A new input format is one source class; a new product
is one sink class.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import replay, simulate
    >>> d = tempfile.mkdtemp()
    >>> simulate(oedipus(duration_s=0.5, render=False), os.path.join(d, "sim.mcap"))
    15
    >>> s = replay(os.path.join(d, "sim.mcap"), os.path.join(d, "out.mcap"), progress=False)
    >>> s.frames, s.identified >= 14
    (15, True)
"""

from adfusion.app.replay.run import ReplayOptions, replay, run
from adfusion.app.replay.simulate import simulate
from adfusion.app.replay.sinks import LogSink, ReplaySummary, SmootherSink, SummarySink
from adfusion.app.replay.sources import McapInput, Source
from adfusion.app.replay.stages import DetectAhead, EstimationStage, Step

__all__ = [
    "DetectAhead",
    "EstimationStage",
    "LogSink",
    "McapInput",
    "ReplayOptions",
    "ReplaySummary",
    "SmootherSink",
    "Source",
    "Step",
    "SummarySink",
    "replay",
    "run",
    "simulate",
]
