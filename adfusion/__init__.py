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

from importlib import import_module
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# Loaded on first use (PEP 562), so `adfusion --help` and light scripts do not pay for
# OpenCV, SciPy and filterpy at import time.
_LAZY = {
    "Estimator": "adfusion.estimation.estimator",
    "StepRecord": "adfusion.estimation.estimator",
    "MEKF": "adfusion.estimation.mekf",
    "UpdateResult": "adfusion.estimation.mekf",
    "RateMEKF": "adfusion.estimation.ratefilter",
    "UKF": "adfusion.estimation.ukf",
}

if TYPE_CHECKING:  # pragma: no cover
    from adfusion.estimation.estimator import Estimator, StepRecord
    from adfusion.estimation.mekf import MEKF, UpdateResult
    from adfusion.estimation.ratefilter import RateMEKF
    from adfusion.estimation.ukf import UKF


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'adfusion' has no attribute {name!r}")

__all__ = ["MEKF", "UKF", "Estimator", "RateMEKF", "StepRecord", "UpdateResult", "__version__"]
