"""``adfusion live``: frames solved as they arrive (a folder being filled, a camera, a
recording at its pace), recorded to MCAP and shown live in Foxglove.

* :mod:`~adfusion.app.live.feeds` — where frames and IMU samples come from;
* :mod:`~adfusion.app.live.source` — them as a replay source, the newest frame kept;
* :mod:`~adfusion.app.live.view` — the Foxglove WebSocket server;
* :mod:`~adfusion.app.live.run` — the run: :func:`live`.

Design notes: docs/live.md.
"""

from adfusion.app.live.run import LiveOptions, LiveSink, live

__all__ = ["LiveOptions", "LiveSink", "live"]
