"""Recording and reading adfusion runs: MCAP with Foxglove schemas, and replay sources.

``logs`` depends on nothing else of ours: it takes numpy arrays, floats and dicts.

Example:
    >>> import os, tempfile
    >>> import numpy as np
    >>> from adfusion import logs
    >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with logs.LogWriter(path) as log:
    ...     log.write_image(0.5, np.full((4, 6), 7, np.uint8))
    >>> [(m.t_s, m.topic, m.payload.shape) for m in logs.read_mcap(path)]
    [(0.5, '/camera/image', (4, 6))]
"""

from adfusion.logs.message import Message
from adfusion.logs.reader import McapLogReader, ReadProblem, read_mcap
from adfusion.logs.sources import ImageFolderSource, McapSource, VideoSource, read_sensor_csv
from adfusion.logs.writer import LogWriter

__all__ = [
    "ImageFolderSource",
    "LogWriter",
    "McapLogReader",
    "McapSource",
    "Message",
    "ReadProblem",
    "VideoSource",
    "read_mcap",
    "read_sensor_csv",
]
