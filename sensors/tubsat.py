"""A DLR-TUBSAT-like satellite for night-pointing simulations (Bleif 2004 §8.1.1).

The thesis: docs/references.md#bleif-2004.

Two pieces, both deterministic from a seed:

* :func:`star_blocks` — a reduced star image as the on-board PHDRA program sends it: a
  list of 4 × 1 px blocks. The 16 mm lens is defocused on purpose, so a star is a disc
  whose rows each give one block (brighter → larger disc → more blocks); hot pixels give
  single blocks (Bleif 2004 §3.1.2). Only stars down to ``mag_limit`` (≈ 5 after reduction on
  the damaged chip) register.
* :class:`SimulatedACS` — three single-axis wheel-gyro units: inertial hold, slew commands
  at a constant rate after a command latency (> 1 s), and the gyro drift of Tab. 8.1. The
  angle loops null the *measured* rate, so a gyro bias ``b`` makes the held satellite turn
  at −b while the gyro reads zero — the drift no gyro-only estimate can see. Telemetry
  reports the executed angle of each unit's last slew.

Attitudes are ``q_cam_icrs`` (the body frame is the camera frame); rates rad/s in camera
axes; satellite axes as :mod:`adfusion.starid.bleif.star_angles` (X_S = −y, Y_S = x, Z_S = z).

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> acs = SimulatedACS(rot.IDENTITY, bias_cam_rad_s=np.zeros(3))
    >>> acs.command("Z", np.radians(10.0), t=0.0)
    >>> acs.advance(30.0)
    >>> round(float(np.degrees(rot.angle_between(acs.q_cam_icrs, rot.IDENTITY))), 9)
    10.0
    >>> round(float(np.degrees(acs.executed_rad("Z"))), 9)
    10.0
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["AXES_CAM", "DRIFT_TAB_8_1_DEG_MIN", "SimulatedACS", "StarBlocks", "star_blocks"]

AXES_CAM = {"X": np.array([0.0, -1.0, 0.0]), "Y": np.array([1.0, 0.0, 0.0]),
            "Z": np.array([0.0, 0.0, 1.0])}
DRIFT_TAB_8_1_DEG_MIN = (0.51, 0.26, 0.79)  # about X_S, Y_S, Z_S


@dataclass(frozen=True)
class StarBlocks:
    """A reduced star image: ``xy`` block positions (px), and per block the catalogue id
    of the star it belongs to (−1: a hot pixel)."""

    xy: NDArray[np.float64]
    star_id: NDArray[np.int64]


def star_blocks(catalog, camera: Camera, q_cam_icrs: ArrayLike, seed: int = 0, *,
                mag_limit: float = 5.0, n_hot: int = 30, px_per_mag: float = 0.8,
                max_blocks: int = 126) -> StarBlocks:
    """The block list of a 5 s star image at ``q_cam_icrs`` (brightest stars first, at most
    ``max_blocks``, the PHDRA list's capacity)."""
    rng = np.random.default_rng(seed)
    q = np.asarray(q_cam_icrs, dtype=np.float64)
    v = rot.rotate(q, catalog.vectors)
    front = np.flatnonzero((v[:, 2] > 0) & (catalog.mag <= mag_limit))
    xy = camera.vectors_to_pixels(v[front])
    inside = camera.in_frame(xy, margin=3.0)
    idx, xy = front[inside], xy[inside]
    order = np.argsort(catalog.mag[idx], kind="stable")
    out_xy, out_id = [], []
    for i, (x, y) in zip(idx[order].tolist(), xy[order].tolist(), strict=True):
        radius = 1.0 + px_per_mag * (mag_limit - float(catalog.mag[i]))  # defocused disc
        for dy in np.arange(-np.floor(radius), np.floor(radius) + 1):
            out_xy.append((x + rng.uniform(-1.0, 1.0), y + dy))  # frayed row starts
            out_id.append(int(catalog.ids[i]))
    hot = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], size=(n_hot, 2))
    out_xy += [tuple(h) for h in hot.tolist()]
    out_id += [-1] * n_hot
    b = np.array(out_xy, dtype=np.float64).reshape(-1, 2)[:max_blocks]
    return StarBlocks(b, np.array(out_id, dtype=np.int64)[:max_blocks])


@dataclass
class _Slew:
    axis: str
    angle_rad: float
    start_s: float
    end_s: float


@dataclass
class SimulatedACS:
    """The satellite's attitude under its per-axis angle loops (see the module docstring).

    Args:
        q_cam_icrs: the attitude at ``t_s``.
        bias_cam_rad_s: the gyro bias (camera axes); the held satellite drifts at −bias.
        slew_rate_rad_s: the constant slew rate of a unit.
        latency_s: command-to-motion delay.
    """

    q_cam_icrs: NDArray[np.float64]
    bias_cam_rad_s: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    slew_rate_rad_s: float = float(np.radians(2.0))
    latency_s: float = 1.5
    t_s: float = 0.0
    slews: list[_Slew] = field(default_factory=list)
    _executed: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.q_cam_icrs = rot.normalize(np.asarray(self.q_cam_icrs, dtype=np.float64))
        self.bias_cam_rad_s = np.asarray(self.bias_cam_rad_s, dtype=np.float64).reshape(3)

    def command(self, axis: str, angle_rad: float, t: float) -> None:
        """An angle command for one unit, received at ``t``; it starts after the latency
        and after any slew still running (the units turn one at a time)."""
        if axis not in AXES_CAM:
            raise ValueError(f"axis must be 'X', 'Y' or 'Z', got {axis!r}")
        start = max(float(t) + self.latency_s, self.slews[-1].end_s if self.slews else 0.0)
        dur = abs(float(angle_rad)) / self.slew_rate_rad_s
        self.slews.append(_Slew(axis, float(angle_rad), start, start + dur))

    def busy_until(self) -> float:
        """When the last commanded slew ends."""
        return self.slews[-1].end_s if self.slews else self.t_s

    def rate_at(self, t: float) -> NDArray[np.float64]:
        """The commanded body rate at ``t`` (what the gyro reads, bias compensated by the
        loops)."""
        for s in self.slews:
            if s.start_s <= t < s.end_s:
                return np.sign(s.angle_rad) * self.slew_rate_rad_s * AXES_CAM[s.axis]
        return np.zeros(3)

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        """Times in (t0, t1) where the rate changes."""
        pts = {p for s in self.slews for p in (s.start_s, s.end_s) if t0 < p < t1}
        return sorted(pts)

    def advance(self, t: float) -> None:
        """Move the true attitude to time ``t``: commanded rates minus the gyro bias."""
        t = float(t)
        if t < self.t_s:
            raise ValueError(f"time went backwards: {t} < {self.t_s}")
        cuts = [self.t_s, *self.breakpoints(self.t_s, t), t]
        for a, b in itertools.pairwise(cuts):
            omega = self.rate_at(0.5 * (a + b)) - self.bias_cam_rad_s
            self.q_cam_icrs = rot.multiply(rot.exp_map(-omega * (b - a)), self.q_cam_icrs)
            for s in self.slews:  # telemetry: the angle the unit has measured so far
                if s.start_s < b and a < s.end_s:
                    done = (min(b, s.end_s) - s.start_s) * self.slew_rate_rad_s
                    self._executed[s.axis] = float(np.sign(s.angle_rad) * done)
        self.t_s = t

    def gyro(self, t: float) -> NDArray[np.float64]:
        """The gyro reading at ``t``: true rate plus bias = the commanded rate."""
        return self.rate_at(t)

    def executed_rad(self, axis: str) -> float:
        """Telemetry: the angle the unit of ``axis`` executed in its latest slew."""
        return self._executed.get(axis, 0.0)
