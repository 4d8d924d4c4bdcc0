"""adfusion: star-camera attitude fixes fused with gyro and magnetometer data.

Filters (:class:`MEKF`, :class:`UKF`) share one interface, so research scripts swap one
for the other; :class:`Estimator` owns a filter and a star solver for an ACS loop.

Example:
    >>> import numpy as np
    >>> import adfusion
    >>> f = adfusion.MEKF([1.0, 0, 0, 0], np.radians(1.0), 1e-5, 1e-6, 1e-9)
    >>> f.propagate(0.1, [0.0, 0.0, 0.01])
    >>> round(float(np.degrees(2 * np.arccos(f.q_body_icrs[0]))), 4)
    0.0573
"""

from adfusion.estimator import Estimator, StepRecord
from adfusion.mekf import MEKF, UpdateResult
from adfusion.ratefilter import RateMEKF
from adfusion.ukf import UKF

__version__ = "0.1.0"

__all__ = ["MEKF", "UKF", "Estimator", "RateMEKF", "StepRecord", "UpdateResult", "__version__"]
