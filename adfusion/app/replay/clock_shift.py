"""``--imu-offset``: the IMU's messages moved onto the frames' clock.

A gyro whose clock runs ``offset_s`` early (the replay's clock check reports it: "shift
the gyro's times by +0.475 s") is put right by adding ``offset_s`` to every gyro and
magnetometer time — both come from the IMU and its clock. The stream stays in time order
with a reorder buffer no longer than the offset: a message can be let out once no later
input can still land before it.

Example:
    >>> from adfusion.logs.message import Message
    >>> ms = [Message(0.0, "/imu/gyro", {}), Message(0.1, "/camera/centroids", {}),
    ...       Message(0.2, "/imu/gyro", {}), Message(0.3, "/camera/centroids", {})]
    >>> [(round(m.t_s, 2), m.topic[1:4]) for m in shift_imu(ms, 0.15)]
    [(0.1, 'cam'), (0.15, 'imu'), (0.3, 'cam'), (0.35, 'imu')]
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
from collections.abc import Iterable, Iterator

from adfusion.logs import topics
from adfusion.logs.message import Message

__all__ = ["IMU_TOPICS", "shift_imu"]

IMU_TOPICS = frozenset({topics.GYRO, topics.MAG})


def shift_imu(messages: Iterable[Message], offset_s: float) -> Iterator[Message]:
    """``messages`` (in time order) with ``offset_s`` added to the times of the IMU's
    (:data:`IMU_TOPICS`), still in time order (ties keep their input order)."""
    offset_s = float(offset_s)
    if not math.isfinite(offset_s):
        raise ValueError(f"--imu-offset must be a finite number of seconds, got {offset_s}")
    if offset_s == 0.0:
        yield from messages
        return
    # a later input has t ≥ the current t; shifted, an IMU one lands at ≥ t + offset_s:
    # whatever is at or before t - horizon is final
    horizon = max(0.0, -offset_s)
    heap: list[tuple[float, int, Message]] = []
    order = itertools.count()
    for m in messages:
        t_new = m.t_s + offset_s if m.topic in IMU_TOPICS else m.t_s
        heapq.heappush(heap, (t_new, next(order), m if t_new == m.t_s
                              else dataclasses.replace(m, t_s=t_new)))
        while heap and heap[0][0] <= m.t_s - horizon:
            yield heapq.heappop(heap)[2]
    while heap:
        yield heapq.heappop(heap)[2]
