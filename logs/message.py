"""The one event type every replay source yields: ``Message(t_s, topic, payload)``.

Example:
    >>> from adfusion.logs.message import Message
    >>> m = Message(1.5, "/imu/gyro", {"omega": [0.0, 0.0, 0.1]})
    >>> m.t_s, m.topic
    (1.5, '/imu/gyro')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Message:
    """One timestamped record from any source (MCAP, image folder + CSV, video).

    Attributes:
        t_s: time in seconds (float; MCAP stores integer nanoseconds).
        topic: one of the DESIGN topics (``/camera/image``, ``/imu/gyro``, ``/mag``, ...) or,
            for foreign MCAP channels that were not mapped, the channel's own topic.
        payload: ``numpy.ndarray`` for images (grey, uint8 or uint16), a ``dict`` otherwise.
            Quaternions inside payloads are Hamilton scalar-first ``[w, x, y, z]``.
        raw: the encoded bytes the payload was decoded from (MCAP JSON channels: JSON text;
            ``foxglove.RawImage`` and ``foxglove.PoseInFrame`` channels: the protobuf
            message), so that a replay can copy inputs to its output without encoding them
            again.
    """

    t_s: float
    topic: str
    payload: Any
    raw: bytes | None = None
