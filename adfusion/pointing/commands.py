"""Slew-command bookkeeping of Bleif's manoeuvre window (tubsat.md §6.5, §7.2).

Each partial manoeuvre has a computed angle and three buttons: **send** (transmit the
angle command and couple the slew into the attitude model), **re-send** (transmit again
after a radio drop-out, *without* coupling again) and **query** (read back the angle the
ACS unit actually executed, recorded but — as in the thesis — not fed back). The book
guarantees that a slew is applied to the model at most once, whatever the operator
presses; every action is logged with its time.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> model = DeadReckoning(rot.IDENTITY)
    >>> book = CommandBook(model)
    >>> i = book.add("Z", np.radians(50.8))
    >>> book.send(i, t=0.0); book.resend(i, t=5.0); book.send(i, t=6.0)
    True
    False
    False
    >>> book.query(i, np.radians(50.7), t=20.0)
    >>> model.n_applied, [e.kind for e in book.log]
    (1, ['send', 'resend', 'resend', 'query'])
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from adfusion.pointing.slews import slew

__all__ = ["CommandBook", "CommandEvent", "DeadReckoning", "SlewCommand"]


class DeadReckoning:
    """The thesis's attitude model: a fix, then every coupled slew applied exactly as
    commanded (no drift; :mod:`adfusion.pointing.drift` adds the error budget)."""

    def __init__(self, q_cam_icrs: ArrayLike) -> None:
        self.q_cam_icrs = np.asarray(q_cam_icrs, dtype=np.float64)
        self.n_applied = 0

    def apply_slew(self, axis: str, angle_rad: float) -> None:
        self.q_cam_icrs = slew(self.q_cam_icrs, axis, angle_rad)
        self.n_applied += 1


@dataclass
class SlewCommand:
    """One partial manoeuvre: axis ('X', 'Y', 'Z'), commanded angle, and what happened."""

    axis: str
    angle_rad: float
    coupled: bool = False
    transmissions: int = 0
    executed_rad: float | None = None


@dataclass(frozen=True)
class CommandEvent:
    t: float
    kind: str  # "send" | "resend" | "query"
    index: int
    axis: str
    angle_rad: float


@dataclass
class CommandBook:
    """The manoeuvre rows of one pass over an attitude model with ``apply_slew``."""

    model: object
    commands: list[SlewCommand] = field(default_factory=list)
    log: list[CommandEvent] = field(default_factory=list)

    def add(self, axis: str, angle_rad: float) -> int:
        """Append a partial manoeuvre; returns its index."""
        if axis not in ("X", "Y", "Z"):
            raise ValueError(f"axis must be 'X', 'Y' or 'Z', got {axis!r}")
        if not np.isfinite(angle_rad):
            raise ValueError(f"slew angle must be finite, got {angle_rad}")
        self.commands.append(SlewCommand(axis, float(angle_rad)))
        return len(self.commands) - 1

    def send(self, i: int, t: float) -> bool:
        """Transmit command ``i`` and couple it into the model — once: a second send
        is a re-send. Returns whether the slew was coupled now."""
        c = self._get(i)
        if c.coupled:
            self.resend(i, t)
            return False
        c.coupled = True
        c.transmissions += 1
        self.model.apply_slew(c.axis, c.angle_rad)
        self.log.append(CommandEvent(float(t), "send", i, c.axis, c.angle_rad))
        return True

    def resend(self, i: int, t: float) -> bool:
        """Transmit command ``i`` again without coupling (radio drop-out). Returns False
        (nothing coupled)."""
        c = self._get(i)
        c.transmissions += 1
        self.log.append(CommandEvent(float(t), "resend", i, c.axis, c.angle_rad))
        return False

    def query(self, i: int, executed_rad: float, t: float) -> None:
        """Record the angle the ACS unit reports as executed (telemetry only)."""
        c = self._get(i)
        c.executed_rad = float(executed_rad)
        self.log.append(CommandEvent(float(t), "query", i, c.axis, float(executed_rad)))

    def complete(self, i: int, tol_rad: float = np.radians(0.2)) -> bool:
        """Whether the read-back of command ``i`` shows it executed (within ``tol_rad``)."""
        c = self._get(i)
        return c.executed_rad is not None and abs(c.executed_rad - c.angle_rad) <= tol_rad

    def _get(self, i: int) -> SlewCommand:
        if not 0 <= i < len(self.commands):
            raise IndexError(f"no manoeuvre {i}: the book holds {len(self.commands)}")
        return self.commands[i]


