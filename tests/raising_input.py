"""A replay input that fails part-way, for the tests of what a failed run leaves and says."""

from __future__ import annotations

from adfusion.app.replay import sources as replay_sources


def raising_after(n: int, exc: BaseException, monkeypatch) -> None:
    """Every input that :func:`adfusion.app.replay.replay` opens raises ``exc`` after its
    ``n``-th message."""
    opened = replay_sources.open_input

    class Raising:
        def __init__(self, source):
            self._source = source

        def __getattr__(self, name):
            return getattr(self._source, name)

        def __iter__(self):
            for k, msg in enumerate(self._source):
                if k == n:
                    raise exc
                yield msg

    monkeypatch.setattr(replay_sources, "open_input",
                        lambda path, **kw: Raising(opened(path, **kw)))
