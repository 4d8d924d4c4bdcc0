"""Drift budget of a single star fix (tubsat.md §9.1): how long the pointing stays good.

Between Bleif's star fix and the target only the gyro-held angle loops carry the
attitude, and their drift (Tab. 8.1: 0.51, 0.26, 0.79 °/min about X_S, Y_S, Z_S after
8 min) eats the pointing budget (3.5°, half the 50 mm image). Here the drift is the
filter's gyro-bias uncertainty: :func:`drift_estimator` builds an
:class:`adfusion.Estimator` whose MEKF starts with a 1-σ bias of the drift rates, so its
propagated covariance grows like the observed errors; :func:`time_left_s` says how long
until the boresight's k-σ error (the worse of the two cross axes X_S, Y_S) exceeds the
budget. The thesis itself assumed no drift (dead reckoning): ``DriftModel.none()``.

Example:
    >>> import numpy as np
    >>> est = drift_estimator(DriftModel.isotropic(0.5))
    >>> rec = est.add_fix(0.0, [1.0, 0.0, 0.0, 0.0], np.eye(3) * np.radians(0.01) ** 2)
    >>> round(time_left_s(est.filter, 3.5) / 60, 1)
    7.0
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from adfusion.estimation.estimator import Estimator
from adfusion.estimation.mekf import MEKF

__all__ = ["TAB_8_1_DEG_PER_MIN", "DriftModel", "boresight_sigma_deg", "drift_estimator",
           "time_left_s"]

TAB_8_1_DEG_PER_MIN = (0.51, 0.26, 0.79)  # about X_S, Y_S, Z_S: error after 8 min / 8


@dataclass(frozen=True)
class DriftModel:
    """1-σ drift rates (deg/min) about the satellite axes X_S, Y_S, Z_S."""

    rates_deg_min: tuple[float, float, float] = TAB_8_1_DEG_PER_MIN

    @classmethod
    def isotropic(cls, rate_deg_min: float) -> DriftModel:
        return cls((rate_deg_min,) * 3)

    @classmethod
    def none(cls) -> DriftModel:
        return cls((0.0, 0.0, 0.0))

    def sigma_bias_cam_rad_s(self) -> NDArray[np.float64]:
        """The rates as a gyro-bias σ in camera axes (x = Y_S, y = −X_S, z = Z_S)."""
        x, y, z = self.rates_deg_min
        return np.radians([y, x, z]) / 60.0


def drift_estimator(drift: DriftModel = DriftModel(), solver=None, *,
                    arw_rad_sqrt_s: float = 1e-6, **kwargs) -> Estimator:
    """An :class:`Estimator` (body = camera frame) whose filter propagates a fix with the
    drift model as its gyro-bias uncertainty (no bias walk: the drift stays as measured)."""
    sb = np.maximum(drift.sigma_bias_cam_rad_s(), 1e-12)  # 0 would make P singular

    def factory(q, sigma_att, _sigma_bias, arw, rrw):
        return MEKF(q, sigma_att, sb, arw, rrw)

    return Estimator(solver, filter_factory=factory, arw_rad_sqrt_s=arw_rad_sqrt_s,
                     rrw_rad_s_sqrt_s=0.0, **kwargs)


def boresight_sigma_deg(filt) -> float:
    """1-σ boresight error (deg): the worse of the two cross-boresight axes (camera x, y)
    of the filter's attitude covariance (body = camera)."""
    P = filt.P[:2, :2]
    return math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(P)[-1]), 0.0)))


def time_left_s(filt, budget_deg: float, k: float = 1.0, horizon_s: float = 3600.0,
                resolution_s: float = 0.5) -> float:
    """Seconds (from the filter's present) until k·σ of the boresight exceeds
    ``budget_deg`` with no new fix; 0 if it already does, ``horizon_s`` if never before."""
    if not budget_deg > 0:
        raise ValueError(f"budget_deg must be positive, got {budget_deg}")

    def over(dt: float) -> bool:
        f = copy.deepcopy(filt)
        if dt > 0:
            f.propagate(dt, np.asarray(f.bias_rad_s))
        return k * boresight_sigma_deg(f) > budget_deg

    if over(0.0):
        return 0.0
    if not over(horizon_s):
        return float(horizon_s)
    lo, hi = 0.0, float(horizon_s)
    while hi - lo > resolution_s:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if over(mid) else (mid, hi)
    return 0.5 * (lo + hi)
