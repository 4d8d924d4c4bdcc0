"""Cheap reads and writes of Basilisk messages from Python modules that run every step.

Basilisk's Python message layer is built for convenience, not for a 20 Hz loop: each
``reader()`` copies the payload into a new Python object (about 10 µs), each
``msg.write(payload)`` first creates a new writer, and each ``payload.field = value`` goes
through ``protectSetAttr``, which reads the field (another copy) to check that it exists.
Inside a ``SysModel.UpdateState`` that runs thousands of times this was most of the cost. The
same public API does it cheaply:

* :func:`live_view` — ``reader()`` returns a *live view* of the source's payload: taken
  once, its fields read the message's current contents (the view keeps its source alive);
* :func:`author` — ``msg.addAuthor()`` once, then ``write(payload, module_id, t_ns)``;
* :func:`setters` — the payload type's SWIG property setters, checked by name once, called
  directly.

A view is tied to the subscription it was taken from: take it again after re-subscribing
(the modules here take their views at the first call after ``Reset``).

Example:
    >>> from Basilisk.architecture import messaging
    >>> msg = messaging.IMUSensorMsg()
    >>> reader = messaging.IMUSensorMsgReader()
    >>> reader.subscribeTo(msg)
    >>> payload = messaging.IMUSensorMsgPayload()
    >>> set_rate, = setters(payload, "AngVelPlatform")
    >>> write = author(msg)
    >>> set_rate(payload, [0.0, 0.0, 0.1])
    >>> _ = write(payload, 0, 100)
    >>> view = live_view(reader)
    >>> set_rate(payload, [0.0, 0.0, 0.2])
    >>> _ = write(payload, 0, 200)
    >>> view.AngVelPlatform, reader.timeWritten()
    ([0.0, 0.0, 0.2], 200)
    >>> setters(payload, "AngularVelocity")
    Traceback (most recent call last):
    ...
    AttributeError: IMUSensorMsgPayload has no field 'AngularVelocity'
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["author", "live_view", "setters"]


def live_view(reader: Any) -> Any:
    """A live view of the payload ``reader`` is subscribed to (see the module docstring)."""
    return reader()


def author(msg: Any) -> Callable[[Any, int, int], Any]:
    """A writer of ``msg``: ``write(payload, module_id, t_ns)``."""
    return msg.addAuthor()


def setters(payload: Any, *names: str) -> tuple[Callable[[Any, Any], None], ...]:
    """The setters of the fields ``names`` of ``payload``'s type: ``set(payload, value)``."""
    cls = type(payload)
    out = []
    for name in names:
        prop = getattr(cls, name, None)
        if not isinstance(prop, property) or prop.fset is None:
            raise AttributeError(f"{cls.__name__} has no field {name!r}")
        out.append(prop.fset)
    return tuple(out)
