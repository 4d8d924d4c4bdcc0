"""GTSAM smoother for offline replay: with the whole log in hand, a smoother beats a filter.

A replay records what the smoother needs (:class:`SmootherInput`: per camera frame the
identified stars' measured body-frame directions and catalogue ICRS directions, the filter's
estimate as a starting point, the gyro and magnetometer samples), and :func:`smooth` builds
one factor graph over the whole history afterwards and solves it — in one batch
(Levenberg–Marquardt) or frame by frame (iSAM2) — with marginal covariances out. The graph,
its noise models and the measurements behind each choice: docs/concepts/smoother.md.

Example (synthetic, no camera: stars seen from a body turning at 0.2 rad/s, gyro at 100 Hz):
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> from adfusion.estimation.smoother import SmootherInput, smooth
    >>> rng = np.random.default_rng(0)
    >>> w = np.array([0.0, 0.0, 0.2])
    >>> q_true = lambda t: rot.multiply(rot.exp_map(-w * t), [1.0, 0, 0, 0])
    >>> stars = rot.radec_to_vector(rng.uniform(0, 6, 8), rng.uniform(-1, 1, 8))
    >>> inp = SmootherInput(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6)
    >>> for t in np.arange(0.0, 2.0, 0.01):
    ...     inp.add_gyro(t, w + rng.normal(0, 1e-3, 3))
    >>> for t in np.arange(0.0, 2.0, 0.1):
    ...     b = rot.rotate(q_true(t), stars) + rng.normal(0, 1e-4, (8, 3))
    ...     inp.add_frame(t, b_body=b, r_icrs=stars)
    >>> res = smooth(inp, sigma_star_rad=1e-4, streak_s=0.0)
    >>> len(res.t), res.mode
    (20, 'batch')
    >>> err = np.degrees(rot.angle_between(res.q_body_icrs, [q_true(t) for t in res.t]))
    >>> bool(err.max() < 0.01), bool(np.all(res.sigma_rad < 1e-4))
    (True, True)
"""

from adfusion.estimation.smoother.inputs import FrameData, SmootherError, SmootherInput
from adfusion.estimation.smoother.noise import calibrate_star_noise
from adfusion.estimation.smoother.result import SmoothResult
from adfusion.estimation.smoother.solve import smooth

__all__ = ["FrameData", "SmoothResult", "SmootherError", "SmootherInput",
           "calibrate_star_noise", "smooth"]
