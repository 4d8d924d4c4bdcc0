"""Replay inputs: each is a :class:`Source` — time-ordered messages plus what the input
knows about its run (camera model, configuration, damage found while reading).

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import McapInput, simulate
    >>> path = os.path.join(tempfile.mkdtemp(), "sim.mcap")
    >>> _ = simulate(oedipus(duration_s=0.2, render=False), path)
    >>> src = McapInput(path)
    >>> src.camera_model()["width"], src.has_images, src.problem
    (512, False, None)
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any, Protocol

from adfusion.logs import McapLogReader, Message, topics

__all__ = ["McapInput", "Source"]


class Source(Protocol):
    """What a replay input provides (see :class:`McapInput`).

    Attributes:
        name: the input, as named in the output's ``replay`` metadata.
        config: the run configuration (``q_body_cam``, ``gyro``, ``camera``, ``catalog``,
            ``mag_limit`` … as :func:`adfusion.app.replay.simulate` records it); ``{}`` if
            unknown.
        has_images: whether frames come as images (else as centroids).
    """

    name: str
    config: dict[str, Any]
    has_images: bool

    def camera_model(self) -> dict[str, Any] | None:
        """The camera model (:meth:`adfusion.starid.camera.Camera.to_dict`), if known."""

    def __iter__(self) -> Iterator[Message]:
        """The messages in time order."""

    @property
    def problem(self) -> str | None:
        """Where the input broke (``None`` for an intact one); read after iterating."""


class McapInput:
    """An MCAP log of ours (or one with the same topics): messages as
    :class:`~adfusion.logs.McapLogReader` reads them, the camera model from the
    ``camera.json`` attachment, the configuration from the ``config`` metadata."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.name = str(path)
        self.reader = McapLogReader(path)
        self.config: dict[str, Any] = self.reader.metadata.get("config", {})
        self.has_images = any(c.topic == topics.CAMERA_IMAGE
                              for c in self.reader.channels.values())

    def camera_model(self) -> dict[str, Any] | None:
        return self.reader.camera_model()

    def __iter__(self) -> Iterator[Message]:
        return iter(self.reader)

    def __len__(self) -> int:
        return self.reader.message_count

    @property
    def problem(self) -> str | None:
        return None if self.reader.problem is None else str(self.reader.problem)

    @property
    def problems(self) -> list[str]:
        """Every problem the reader found (read after iterating: a chunk failing its CRC
        is found when reached)."""
        return [str(p) for p in self.reader.problems]
