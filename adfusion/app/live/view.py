"""The live view: a Foxglove WebSocket server (the official ``foxglove-sdk``) that carries
every topic of the run's MCAP log, with the same schemas and the same bytes, as it is
written (:class:`~adfusion.logs.writer.Tee`).

In Foxglove: *Open connection* → *Foxglove WebSocket* → ``ws://HOST:PORT``, then import the
layout ``OUT.layout.json`` (Layouts → Import from file) — the same one a replay writes.
The server also serves that layout as an asset (``package://adfusion/layout.json``).

Example:
    >>> view = FoxgloveView(port=0)  # a free port
    >>> ch = view.channel("/live/status", "json", "adfusion.LiveStatus", "jsonschema",
    ...                   b'{"type": "object"}')
    >>> view.message(ch, 0, b'{"latency_ms": 3.0}')
    >>> view.port > 0
    True
    >>> view.close()
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["LAYOUT_URI", "FoxgloveView"]

#: where the server serves the layout
LAYOUT_URI = "package://adfusion/layout.json"

#: messages buffered per client before the oldest is dropped (a slow client must not
#: hold the run's frames: 1 Mpx frames are 1 MB each)
BACKLOG = 32


class FoxgloveView:
    """A Foxglove WebSocket server on ``host:port`` (``port=0``: a free one, see
    :attr:`port`), in a context of its own (two views in one process do not mix)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765) -> None:
        try:
            import foxglove
        except ImportError:  # pragma: no cover - a dependency
            raise ImportError("the live view needs foxglove-sdk: pip install foxglove-sdk "
                              "(or give --no-view)") from None
        from adfusion.app.layout import foxglove_layout

        self._fg = foxglove
        # the SDK's own notes (a port probe: "Dropping client …: handshake failed") are
        # not the user's business on the console
        foxglove.set_log_level("ERROR")
        self._layout = json.dumps(foxglove_layout(truth=False, live=True)).encode()
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name="adfusion live", host=host, port=port, context=self.context,
                asset_handler=self._asset, message_backlog_size=BACKLOG)
        except RuntimeError as exc:
            text = str(exc)
            why = ("the port is in use" if "in use" in text else
                   text.split(": ", 1)[-1].split(" (os error")[0])
            raise ValueError(f"the live view cannot listen on {host}:{port} ({why}): give "
                             "--port N (0 picks a free one) or --no-view") from None
        self.host = host
        self._channels: list[Any] = []

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def _asset(self, uri: str) -> bytes | None:
        return self._layout if uri == LAYOUT_URI else None

    def channel(self, topic: str, message_encoding: str, schema_name: str,
                schema_encoding: str, schema_data: bytes) -> Any:
        """A channel of the server for ``topic`` (the log's schema, as registered)."""
        fg = self._fg
        ch = fg.Channel(topic, message_encoding=message_encoding, context=self.context,
                        schema=fg.Schema(name=schema_name, encoding=schema_encoding,
                                         data=bytes(schema_data)))
        self._channels.append(ch)
        return ch

    def message(self, handle: Any, log_time_ns: int, data: bytes) -> None:
        """Publish one message (the server sends it to the clients subscribed)."""
        handle.log(data if isinstance(data, bytes) else bytes(data), log_time=int(log_time_ns))

    def close(self) -> None:
        """Stop the server (idempotent)."""
        for ch in self._channels:
            ch.close()
        self._channels = []
        self.server.stop()
