"""The smoothed history (:class:`SmoothResult`): attitudes, biases, covariances, outliers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass
class SmoothResult:
    """The smoothed history, one state per camera frame (see :func:`smooth`).

    ``cov_attitude`` is the body-frame attitude-error covariance (rad²); ``cov_diag`` its
    diagonal followed by the gyro bias variances (or, video-only, the rate variances), the
    layout of ``/estimate/state``. ``chi2_stars`` is each frame's sum of squared whitened
    star residuals after smoothing (2 dof per star; NaN without stars); ``outliers`` the star
    factors the robust kernel down-weighted, as (t, catalogue id, whitened residual).
    """

    t: Array
    q_body_icrs: Array
    bias_rad_s: Array
    omega_rad_s: Array | None
    cov_attitude: Array
    cov_diag: Array
    n_stars: NDArray[np.int64]
    chi2_stars: Array
    mode: str
    video_only: bool
    outliers: list[tuple[float, int, float]] = field(default_factory=list)
    iterations: int = 0
    error_initial: float = float("nan")
    error_final: float = float("nan")
    n_factors: int = 0
    sigma_star_rad: float = float("nan")
    streak_s: float = float("nan")
    build_s: float = 0.0
    optimize_s: float = 0.0
    covariance_s: float = 0.0
    update_s: Array = field(default_factory=lambda: np.empty(0))
    problems: list[str] = field(default_factory=list)

    @property
    def sigma_rad(self) -> Array:
        """Per-frame 1σ attitude error, sqrt(trace of the attitude covariance), rad."""
        return np.sqrt(np.trace(self.cov_attitude, axis1=1, axis2=2))

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no per-frame arrays)."""
        d: dict[str, Any] = {
            "mode": self.mode, "video_only": self.video_only, "states": len(self.t),
            "factors": self.n_factors, "iterations": self.iterations,
            "error_initial": self.error_initial, "error_final": self.error_final,
            "frames_with_stars": int(np.sum(self.n_stars > 0)),
            "outliers_downweighted": len(self.outliers),
            "sigma_star_rad": self.sigma_star_rad, "streak_s": self.streak_s,
            "build_s": self.build_s, "optimize_s": self.optimize_s,
            "covariance_s": self.covariance_s, "problems": list(self.problems),
        }
        if len(self.update_s):
            d["update_ms_median"] = float(np.median(self.update_s) * 1e3)
            d["update_ms_p95"] = float(np.percentile(self.update_s, 95) * 1e3)
        return d
