"""A gyro that stops: propagate as "no gyro", never on a held rate.

A gyro stream that ends before the frames (a logger that filled its card, a cable, a
clock that jumped) used to be held at its last sample for ever: the filter turned the
body on a rate nobody measured, with the covariance of a working gyro, and its gate then
rejected every correct star fix — about half of the estimates fell outside their own 3σ.

Here a sample older than ``gyro_max_age_s`` ends the gyro's authority. The estimator
hands its state to a :class:`~adfusion.estimation.ratefilter.RateMEKF`, the model of a
camera without a gyro: attitude and body rate, the rate starting at the last
bias-corrected sample with a wide uncertainty (``sigma_rate_rad_s``) and wandering as a
random walk. The attitude covariance is carried over whole, so nothing the filter knew
is lost, and the star fixes the honest covariance now admits estimate the rate. When the
gyro speaks again the gyro filter resumes from the rate filter's attitude, with the bias
(and its uncertainty) it had before the outage.

The decision and its defaults: docs/decisions.md, "A gyro that stops".

Example:
    >>> import numpy as np
    >>> from adfusion.estimation.mekf import MEKF
    >>> f = MEKF([1.0, 0, 0, 0], 1e-4, 1e-5, 1e-5, 1e-7, bias_rad_s=[0.0, 0.0, 0.001])
    >>> out = GyroOutage.begin(f, omega_meas_rad_s=[0.0, 0.0, 0.011], sigma_rate_rad_s=0.05,
    ...                        rate_walk_rad_s_sqrt_s=0.025)
    >>> out.filter.omega_rad_s.round(6).tolist()   # the last sample less the bias
    [0.0, 0.0, 0.01]
    >>> back = out.end(MEKF, arw_rad_sqrt_s=1e-5, rrw_rad_s_sqrt_s=1e-7)
    >>> back.bias_rad_s.tolist(), bool(np.allclose(back.P[3:, 3:], f.P[3:, 3:]))
    ([0.0, 0.0, 0.001], True)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.estimation.ratefilter import RateMEKF

__all__ = ["GyroOutage"]


@dataclass
class GyroOutage:
    """The state kept across a gyro outage: the rate filter that runs meanwhile, and the
    gyro bias (with its 3×3 covariance) to resume with."""

    filter: RateMEKF
    bias_rad_s: NDArray[np.float64]
    bias_cov: NDArray[np.float64]
    t_start_s: float = float("nan")

    @classmethod
    def begin(cls, gyro_filter, omega_meas_rad_s: ArrayLike, sigma_rate_rad_s: float,
              rate_walk_rad_s_sqrt_s: float, t_start_s: float = float("nan")) -> GyroOutage:
        """Hand ``gyro_filter``'s attitude (and its covariance, whole) to a rate filter
        whose rate starts at the last sample less the bias, 1σ ``sigma_rate_rad_s``."""
        p = np.asarray(gyro_filter.P, dtype=np.float64)
        bias = np.asarray(gyro_filter.bias_rad_s, dtype=np.float64)
        omega0 = np.asarray(omega_meas_rad_s, dtype=np.float64) - bias
        rate = RateMEKF(gyro_filter.q_body_icrs, 1.0, sigma_rate_rad_s, rate_walk_rad_s_sqrt_s,
                        omega0_rad_s=omega0, q_body_cam=gyro_filter.q_body_cam,
                        gate_probability=gyro_filter.gate_probability)
        rate._P[:3, :3] = p[:3, :3]  # what the filter knew of the attitude, kept whole
        return cls(rate, bias.copy(), p[3:, 3:].copy(), float(t_start_s))

    def end(self, filter_factory: Callable, *, arw_rad_sqrt_s: float,
            rrw_rad_s_sqrt_s: float):
        """The gyro filter again (built by ``filter_factory`` as the estimator builds it),
        from the rate filter's attitude and covariance, with the bias kept at the start."""
        f = self.filter
        p = f.P
        sigma_att = np.sqrt(np.clip(np.diag(p[:3, :3]), 1e-30, None))
        sigma_bias = np.sqrt(np.clip(np.diag(self.bias_cov), 1e-30, None))
        g = filter_factory(f.q_body_icrs, sigma_att, sigma_bias, arw_rad_sqrt_s,
                           rrw_rad_s_sqrt_s)  # the estimator's factory signature
        g._set_bias(self.bias_rad_s)
        cov = g._cov()  # the filters' own array: set the blocks in place
        cov[:3, :3] = p[:3, :3]
        cov[3:, 3:] = self.bias_cov
        cov[:3, 3:] = 0.0
        cov[3:, :3] = 0.0
        return g
