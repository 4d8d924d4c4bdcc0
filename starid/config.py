"""The options of a :class:`~adfusion.starid.solver.Solver`, as one value.

A :class:`SolverConfig` holds what a solver is told besides its catalogue and camera: the
pattern sizes, tolerances and thresholds, the field-of-view knowledge, the method and its
budgets. It checks what it can without the camera when it is made (the same one-line
errors the solver gives), can be kept, compared, printed and varied with
:func:`dataclasses.replace`, and a solver made from it equals one made from the same
keywords.

Example:
    >>> from dataclasses import replace
    >>> from adfusion import starid
    >>> cfg = starid.SolverConfig(fov_error_deg=0.5)
    >>> replace(cfg, n_max=5).n_max, cfg.n_max
    (5, 6)
    >>> starid.SolverConfig(p_false_max=2.0)
    Traceback (most recent call last):
    ...
    ValueError: p_false_max must be in (0, 1)
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

__all__ = ["SolverConfig"]


@dataclass(frozen=True)
class SolverConfig:
    """The options of :class:`~adfusion.starid.solver.Solver` (its keywords, same names and
    defaults).

    Attributes:
        tolerance_deg: pair-distance tolerance; default from the camera and
            ``centroid_sigma_px``: 3·√2·σ·pixel scale plus 0.003° for lens residuals.
        centroid_sigma_px: 1-σ centroid error, used for the tolerance, match radius and
            covariance.
        n_max, n_min: pattern sizes (Renken 1998: 3…6).
        p_false_max: acceptance threshold on the false-match probability.
        fov_error_deg: ± uncertainty of the camera's horizontal FOV (0 = known).
        fov_range_deg: instead, the horizontal FOV as a range (lo, hi) in degrees; the
            camera is the nominal model (its FOV is tried first, then outwards). The
            field is searched on a grid of focal scales within ``max_patterns`` per scale
            and the ``work_budget``; the fitted camera comes back as ``Solution.camera``.
        fit_camera: after identification, fit the camera to the matched stars:
            ``"auto"`` (default) fits when the FOV is uncertain, ``"none"`` never,
            ``"focal"`` the focal length only, ``"full"`` always the full model selected
            by the data (focal length, pixel aspect, principal point, OpenCV radial and
            tangential distortion; :func:`starid.camera.calibrate.fit_camera_model`).
        faithful: use Renken's reference nested loops instead of the index (slow).
        n_bands: Renken's declination sub-catalogues (1 = none); results are identical.
        dec_check: Renken's declination-difference pre-check (faithful mode only).
        max_detections: the brightest detections considered (the rest are ignored).
        max_patterns: Not-Modus budget (patterns tried per focal scale).
        max_fix_sigma_px: a tracking fix less certain than this is refused: its 1-σ
            error moves the frame's corners by more than this many pixels (two stars close
            together leave the roll open; such a fix would misplace the frame's edges).
        max_tracking_cone_deg: a prior looser than this (k·σ) goes straight to
            lost-in-space: beyond it, associating by prediction is no longer safe.
        p_false_max_tracking: acceptance threshold with a prior. Tracking asks a much
            narrower question than lost-in-space (are these the predicted stars?), a
            filter's innovation gate checks the fix again, and two-star frames must be
            usable: 1e-4 by default.
        whole_streak_px: with a prior's ``smear_cam_rad``, streaks up to this long (px)
            are taken as detected whole and a longer one's pieces as at least this long
            (:func:`adfusion.maths.attitude.refine_streaked`). 20 px keeps the arcs of a spinning
            payload (up to 18 px on the OEDIPUS-like log, detected whole: with 8 px the
            60 s replay's RMS error grew from 0.0202° to 0.0224°) and catches the 34–68 px
            streaks of the rate sweep, which break into pieces (an isotropic fit accepted
            pieces 10 px off; with this model, 0 wrong in 6000 rendered frames).
        work_budget: maximum partial assignments per matching level.
        cache: keep the pattern index in the on-disk cache
            (:mod:`adfusion.starid.catalog.cache`).
        method: ``"nstar"`` (Renken's n-star patterns, default), ``"triad"`` (Yee) or
            ``"bleif"`` (Bleif's reference-star matcher); every method's candidates pass the
            same verification.
        triad_params, bleif_params: the triad's and Bleif's parameters (``None``: theirs).
    """

    tolerance_deg: float | None = None
    centroid_sigma_px: float = 0.5
    n_max: int = 6
    n_min: int = 3
    p_false_max: float = 1e-6
    fov_error_deg: float = 0.0
    fov_range_deg: tuple[float, float] | None = None
    fit_camera: str = "auto"
    faithful: bool = False
    n_bands: int = 1
    dec_check: bool = True
    max_detections: int = 30
    max_patterns: int = 200
    work_budget: int = 200_000
    cache: bool = True
    method: str = "nstar"
    triad_params: Any = None
    bleif_params: Any = None
    max_tracking_cone_deg: float = 3.0
    max_fix_sigma_px: float = 5.0
    p_false_max_tracking: float = 1e-4
    whole_streak_px: float = 20.0

    def __post_init__(self) -> None:
        if self.method not in ("nstar", "triad", "bleif"):
            raise ValueError(f"method must be 'nstar', 'triad' or 'bleif', got {self.method!r}")
        if not (np.isfinite(self.whole_streak_px) and self.whole_streak_px >= 0):
            raise ValueError(f"whole_streak_px must be ≥ 0, got {self.whole_streak_px}")
        if not 2 <= self.n_min <= self.n_max <= 8:
            raise ValueError(f"need 2 ≤ n_min ≤ n_max ≤ 8, got {self.n_min}, {self.n_max}")
        if self.centroid_sigma_px <= 0 or not np.isfinite(self.centroid_sigma_px):
            raise ValueError("centroid_sigma_px must be positive")
        if self.fov_range_deg is not None:
            try:
                lo, hi = (float(v) for v in self.fov_range_deg)
            except (TypeError, ValueError):
                raise ValueError(f"fov_range_deg must be (lo, hi) in degrees, got "
                                 f"{self.fov_range_deg!r}") from None
            if not (0 < lo <= hi < 179):
                raise ValueError(f"fov_range_deg must satisfy 0 < lo ≤ hi < 179, got "
                                 f"({lo:g}, {hi:g})")
            if self.fov_error_deg:
                raise ValueError("give fov_range_deg or fov_error_deg, not both")
            object.__setattr__(self, "fov_range_deg", (lo, hi))
        if self.fit_camera not in ("auto", "none", "focal", "full"):
            raise ValueError(f"fit_camera must be 'auto', 'none', 'focal' or 'full', got "
                             f"{self.fit_camera!r}")
        t = self.tolerance_deg
        if t is not None and not (np.isfinite(t) and 0 < t < 90):
            raise ValueError(f"tolerance_deg must be in (0, 90) degrees, got {t}"
                             " (or None: from the camera and centroid_sigma_px)")
        if not 0 < self.p_false_max < 1:
            raise ValueError("p_false_max must be in (0, 1)")
        if not 3 <= self.max_detections <= 64:
            # the search marks a pattern's detections in a 64-bit mask
            raise ValueError(f"max_detections must be in [3, 64], got {self.max_detections}")
        if self.max_patterns < 1 or self.work_budget < 1:
            raise ValueError(f"max_patterns and work_budget must be ≥ 1, got "
                             f"{self.max_patterns} and {self.work_budget}")

    @classmethod
    def of(cls, config: SolverConfig | None = None, **options: Any) -> SolverConfig:
        """``config`` with ``options`` in place of its values (the defaults when ``config``
        is None); an unknown option is a TypeError naming it.

        >>> SolverConfig.of(SolverConfig(n_max=5), p_false_max=1e-8).n_max
        5
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"unknown solver option(s) {', '.join(unknown)}; the options are "
                            f"the fields of SolverConfig")
        if config is None:
            return cls(**options)
        return replace(config, **options) if options else config
