"""The step API for an attitude-control loop: one object owning a filter and a solver.

``est.step(t, gyro=..., mag=..., frame=... or detections=...)`` advances the estimate to
time ``t`` and folds in whatever measurements arrived, returning the current estimate
with a record of what happened (which sensors were used, the star-ID mode, innovation
NIS values, and every rejected input with its reason). Nothing is silently dropped.

* **Gyro**: held from one step to the next (zero-order hold): at ``step(t)`` the filter
  is propagated from the previous time to ``t`` with the last gyro sample, then the new
  sample is stored.
* **Star camera**: with an attitude estimate, the filter's prediction (mounted into the
  camera frame, its 1-σ cone widened after each miss) is the solver's prior — tracking
  mode, where two stars suffice; after ``max_misses`` misses in a row, or with no
  estimate yet, lost-in-space. The first lost-in-space fix initialises the filter.
* **Magnetometer**: a body-frame field vector with its ICRS reference, applied as a
  direction update.

Deterministic: the same inputs give bit-identical outputs (no clocks, no randomness).

Example:
    >>> import numpy as np
    >>> from adfusion import starid
    >>> from adfusion.estimation.estimator import Estimator
    >>> from adfusion.app.examples import example_frame
    >>> ex = example_frame()
    >>> cat = starid.Catalog.hipparcos(mag_limit=6.5)
    >>> est = Estimator(starid.Solver(cat, ex.camera))
    >>> rec = est.step(0.0, frame=ex.image)
    >>> rec.star_mode, rec.fix_accepted, est.initialized
    ('lost-in-space', True, True)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.estimation.gyro_outage import GyroOutage
from adfusion.estimation.mekf import MEKF, chi2_gate
from adfusion.maths import rotations as rot
from adfusion.starid.solver import Prior, Solution, Solver

__all__ = ["Estimator", "StepRecord"]

#: a verified star fix this surprising (NIS, 3 dof; χ² 0.99: one nominal fix in a hundred
#: at the fix's own covariance, next to none at ``fix_covariance_scale`` 4) but inside the
#: gate widens the filter's σ to reach it before the update: a gyro 0.4 s late held 21 %
#: of a flight's estimates outside their 3σ when only refused fixes widened it, 3 % with
#: this (tests/test_gyro_outage.py; docs/concepts/filter.md)
SURPRISE_NIS = chi2_gate(0.99, 3)


@dataclass
class StepRecord:
    """What one :meth:`Estimator.step` did, and the estimate after it."""

    t: float
    q_body_icrs: NDArray[np.float64] | None
    bias_rad_s: NDArray[np.float64] | None
    sigma_rad: NDArray[np.float64] | None  # sqrt(diag P): 3 attitude, 3 bias
    sensors: list[str] = field(default_factory=list)
    star_mode: str = ""  # "tracking" | "lost-in-space" | "" (no frame)
    star_ok: bool = False
    fix_accepted: bool = False
    n_stars: int = 0
    cone_deg: float | None = None
    nis: dict[str, float] = field(default_factory=dict)
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (input, reason)
    reinitialized: bool = False  # the filter was restarted from this step's star fix
    solution: Solution | None = None
    detections_xy: NDArray[np.float64] | None = None  # the frame's detections (pixels)
    # how the frame's stars were found: "windows" (``detect_tracking`` around the stars
    # the prior predicts), "frame" (the whole frame), "given" (detections passed in), ""
    detection: str = ""
    # the full error covariance P (6×6, a copy): attitude error δθ (body, rad), then gyro
    # bias (rad/s) — or the rate without a gyro; ``sigma_rad`` is the root of its diagonal
    cov: NDArray[np.float64] | None = None


class Estimator:
    """Filter + star identification, stepped by the caller (see module docstring).

    Args:
        solver: a :class:`starid.Solver` for the star camera (None: no camera).
        q_body_cam: mounting, rotates camera-frame vectors into the body frame.
        arw_rad_sqrt_s, rrw_rad_s_sqrt_s: gyro noise for the filter.
        sigma_bias0_rad_s: initial 1-σ gyro bias uncertainty.
        filter_factory: builds the filter from (q_body_icrs, sigma_attitude_rad,
            sigma_bias_rad_s, arw, rrw); default :class:`adfusion.MEKF` — pass
            :class:`adfusion.UKF` to swap.
        q_body_icrs0, sigma_attitude0_rad: an initial attitude, if known (otherwise the
            first lost-in-space fix initialises the filter).
        max_misses: camera frames without an accepted fix before tracking gives way to
            lost-in-space.
        widen_per_miss: factor by which the tracking cone grows after each miss.
        min_cone_deg: the smallest tracking σ handed to the solver (centroid noise, lens
            residuals and timing make a perfectly confident prediction wrong).
        sigma_mag_rad: 1-σ direction error of a magnetometer update (field model and
            hard/soft-iron residuals dominate, hence a degree by default).
        video_only: no gyro — the filter is :class:`adfusion.estimation.ratefilter.RateMEKF`, which
            estimates the body rate itself (constant rate plus a random walk of spectral
            density ``rate_walk_rad_s_sqrt_s``, initial 1-σ ``sigma_rate0_rad_s``); its
            prediction drives tracking between frames as the gyro would.
        fix_covariance_scale: star-fix covariance multiplier. Fixes from consecutive
            frames share their errors (the same stars, streak geometry, catalogue and lens
            residuals); a filter that takes them as independent grows overconfident. On the
            OEDIPUS-like replay: 1 → the estimate inside its 3σ bound 81 % of the time,
            4 → 99.3 % (RMS error 0.024° → 0.028°). Use 1 for truly independent fixes.
        detect: the detection function for ``frame=`` (default ``starid.detection.detect``).
        detect_tracking: for a frame with a tracking prior, ``detect_tracking(image,
            prior)`` — detection around the stars the prior predicts, e.g.
            :meth:`starid.detection.windows.TrackingWindows.detect` — returning detections, or
            None to detect the whole frame with ``detect``. The prior is the one the solver
            then tracks from (computed once per frame). The record says which ran
            (``StepRecord.detection``).
        exposure_s: the camera's exposure (s), if known. With it, tracking priors carry
            the rotation during the exposure (the rate estimate × exposure, camera axes),
            so the solver trusts streaked stars only across their streaks and reports
            the larger along-streak uncertainty (:class:`starid.Prior`); a step may
            override it (``step(..., exposure_s=...)``).
        gyro_max_rate_rad_s: a gyro sample faster than this (any axis norm) is refused as
            a glitch (default 35 rad/s ≈ 2000°/s, a common MEMS full scale).
        gyro_max_accel_rad_s2: a sample that differs from the last accepted one by more
            than this × the time between them (plus 8 noise σ from ``arw_rad_sqrt_s``) is
            refused as a glitch. One 100 rad/s sample of 5 ms otherwise turns the estimate
            28° and the gate then rejects every correct fix.
        gyro_max_age_s: a gyro sample older than this ends the gyro's authority: the
            estimator propagates as without a gyro (:mod:`adfusion.estimation.gyro_outage`:
            a rate filter whose rate starts at the last sample, 1σ
            ``sigma_rate_outage_rad_s``, and walks at ``rate_walk_rad_s_sqrt_s``), never on
            the held rate, until samples come again. Default (None): with
            ``gyro_stream``, 5 sample intervals of the gyro's own (the median of its last
            16), at most 1 s; without, ``inf`` (each sample holds until the next). Each
            outage is in :attr:`gyro_outages`.
        sigma_rate_outage_rad_s: the rate's 1σ when an outage begins (rad/s).
        gyro_stream: the gyro samples are a logged sensor stream (a replay), not a
            caller's zero-order hold: a sample is trusted for ``gyro_max_age_s`` only, and
            a filter started before the stream's first sample runs without the gyro until
            it comes (a stream that starts late would otherwise hold the attitude still
            with a gyro's confidence). False (default): each sample holds until the next,
            however long (a commanded rate, a slew plan), and with no sample yet the
            attitude is held, its covariance grown by the filter's own model.
        reinit_after_fixes: that many lost-in-space fixes in a row, each rejected by the
            gate and agreeing with the one before on the filter's error (within
            ``reinit_agree_deg``), restart the filter from the last of them (recorded as
            ``StepRecord.reinitialized`` with the reason in ``rejected``). 0 disables.
    """

    def __init__(
        self,
        solver: Solver | None,
        q_body_cam: ArrayLike = rot.IDENTITY,
        *,
        arw_rad_sqrt_s: float = 1e-5,
        rrw_rad_s_sqrt_s: float = 1e-7,
        sigma_bias0_rad_s: float = np.radians(0.5) / 3600 * 100,
        filter_factory: Callable | None = None,
        q_body_icrs0: ArrayLike | None = None,
        sigma_attitude0_rad: float = np.radians(1.0),
        max_misses: int = 10,
        widen_per_miss: float = 1.5,
        min_cone_deg: float = 0.02,
        fix_covariance_scale: float = 4.0,
        detect: Callable | None = None,
        detect_tracking: Callable | None = None,
        sigma_mag_rad: float = np.radians(1.0),
        video_only: bool = False,
        rate_walk_rad_s_sqrt_s: float = 0.025,
        sigma_rate0_rad_s: float = 5.0,
        exposure_s: float | None = None,
        gyro_max_rate_rad_s: float = 35.0,
        gyro_max_accel_rad_s2: float = 100.0,
        reinit_after_fixes: int = 3,
        reinit_agree_deg: float = 1.0,
        gyro_max_age_s: float | None = None,
        sigma_rate_outage_rad_s: float = 0.02,
        gyro_stream: bool = False,
    ) -> None:
        for name, value in (("gyro_max_rate_rad_s", gyro_max_rate_rad_s),
                            ("gyro_max_accel_rad_s2", gyro_max_accel_rad_s2),
                            ("gyro_max_age_s", 1.0 if gyro_max_age_s is None
                             else gyro_max_age_s),
                            ("sigma_rate_outage_rad_s", sigma_rate_outage_rad_s),
                            ("reinit_agree_deg", reinit_agree_deg)):
            if not value > 0:  # inf allowed: no check
                raise ValueError(f"{name} must be > 0, got {value}")
        if not (isinstance(reinit_after_fixes, int | np.integer) and reinit_after_fixes >= 0):
            raise ValueError(f"reinit_after_fixes must be an integer ≥ 0, got "
                             f"{reinit_after_fixes!r}")
        self.gyro_max_rate = float(gyro_max_rate_rad_s)
        self.gyro_max_accel = float(gyro_max_accel_rad_s2)
        self.reinit_after = int(reinit_after_fixes)
        self.reinit_agree_rad = float(np.radians(reinit_agree_deg))
        self._gyro_last: tuple[float, NDArray[np.float64]] | None = None  # (t, ω) accepted
        self._max_age_s = None if gyro_max_age_s is None else float(gyro_max_age_s)
        self._gyro_dts: list[float] = []  # the last sample intervals (for the default age)
        self.sigma_rate_outage = float(sigma_rate_outage_rad_s)
        self._outage: GyroOutage | None = None  # while the gyro is silent
        self._gyro_note = ""  # the end of an outage, for the step's record
        self._first_wait = False  # the outage is the wait for the gyro's first sample
        self.gyro_stream = bool(gyro_stream)
        #: every gyro outage: (start, end) run seconds, end NaN while it lasts
        self.gyro_outages: list[list[float]] = []
        self._lis_rejects: list[NDArray[np.float64]] = []  # fix ⊗ filter⁻¹ of rejected fixes
        if exposure_s is not None and not (np.isfinite(exposure_s) and exposure_s >= 0):
            raise ValueError(f"exposure_s must be a finite duration ≥ 0, got {exposure_s}")
        self.exposure_s = None if exposure_s is None else float(exposure_s)
        if not fix_covariance_scale >= 1.0:
            raise ValueError(f"fix_covariance_scale must be ≥ 1, got {fix_covariance_scale}")
        self.fix_covariance_scale = float(fix_covariance_scale)
        self.sigma_mag_rad = float(sigma_mag_rad)
        self.video_only = bool(video_only)
        self.rate_walk = float(rate_walk_rad_s_sqrt_s)
        self.sigma_rate0 = float(sigma_rate0_rad_s)
        self.solver = solver
        self.q_body_cam = rot.normalize(q_body_cam)
        self.q_cam_body = rot.inverse(self.q_body_cam)
        self.R_body_cam = rot.to_matrix(self.q_body_cam)
        self.arw = float(arw_rad_sqrt_s)
        self.rrw = float(rrw_rad_s_sqrt_s)
        self.sigma_bias0 = float(sigma_bias0_rad_s)
        self.filter_factory = filter_factory or MEKF
        self.max_misses = int(max_misses)
        self.widen_per_miss = float(widen_per_miss)
        self.min_cone_deg = float(min_cone_deg)
        self._detect = detect
        self._detect_tracking = detect_tracking
        self.filter = None
        if q_body_icrs0 is not None:
            self.filter = self._make_filter(rot.normalize(q_body_icrs0), sigma_attitude0_rad)
        self.t: float | None = None
        self._omega_hold: NDArray[np.float64] | None = None
        self.misses = 0
        self._heads: list[dict] = []  # several cameras (add_camera): each one's own state
        self._active = 0

    @property
    def initialized(self) -> bool:
        return self.filter is not None

    _HEAD = ("solver", "q_body_cam", "q_cam_body", "R_body_cam", "misses")

    def add_camera(self, solver: Solver, q_body_cam: ArrayLike) -> int:
        """Another star camera (its own model in ``solver``, its own mounting) fused into
        the same filter; returns its index for ``step(..., camera=k)`` (the constructor's
        camera is 0). Each camera keeps its own tracking state (misses, search cone);
        the attributes ``solver``, ``q_body_cam`` and ``misses`` are camera 0's."""
        if not self._heads:
            self._heads.append({a: getattr(self, a) for a in self._HEAD})
        q = rot.normalize(q_body_cam)
        self._heads.append({"solver": solver, "q_body_cam": q, "q_cam_body": rot.inverse(q),
                            "R_body_cam": rot.to_matrix(q), "misses": 0})
        return len(self._heads) - 1

    def _use_camera(self, k: int) -> None:
        if k == self._active:
            return
        if not 0 <= k < max(len(self._heads), 1):
            raise ValueError(f"no camera {k} (add_camera adds cameras 1, 2, …)")
        self._heads[self._active].update({a: getattr(self, a) for a in self._HEAD})
        for a, v in self._heads[k].items():
            setattr(self, a, v)
        self._active = k

    def _make_filter(self, q_body_icrs: NDArray, sigma_att_rad: float):
        if self._outage is not None:  # restarted while the gyro is silent: a rate filter
            from adfusion.estimation.ratefilter import RateMEKF

            self._outage.filter = RateMEKF(q_body_icrs, sigma_att_rad, self.sigma_rate0,
                                           self.rate_walk,
                                           omega0_rad_s=self._outage.filter.omega_rad_s)
            return self._outage.filter
        if self.video_only or (self.gyro_stream and self._gyro_last is None):
            from adfusion.estimation.ratefilter import RateMEKF

            rate = RateMEKF(q_body_icrs, sigma_att_rad, self.sigma_rate0, self.rate_walk)
            if not self.video_only:  # no gyro sample yet: without the gyro until one comes
                t = math.nan if getattr(self, "t", None) is None else self.t
                self._outage = GyroOutage(rate, np.zeros(3), np.eye(3) * self.sigma_bias0**2,
                                          t_start_s=t)
                self.gyro_outages.append([t, math.nan])
                self._first_wait = True
            return rate
        return self.filter_factory(q_body_icrs, sigma_att_rad, self.sigma_bias0, self.arw,
                                   self.rrw)

    # --- the step ---------------------------------------------------------------------

    def step(
        self,
        t: float,
        gyro: ArrayLike | None = None,
        mag: tuple[ArrayLike, ArrayLike] | None = None,
        frame: NDArray | str | None = None,
        detections=None,
        exposure_s: float | None = None,
        camera: int = 0,
    ) -> StepRecord:
        """Advance to time ``t`` (s) and apply the measurements taken at ``t``.

        ``gyro``: body rate (rad/s). ``mag``: (field in the body frame, the same field in
        ICRS) in any common unit. ``frame``: an image (detected here) or ``detections``
        (a :class:`starid.Detections` or an (N, 2) / (N, 3) array), taken at mid-exposure;
        ``exposure_s`` overrides the estimator's exposure for this frame; ``camera`` is the
        index of the camera that took it (:meth:`add_camera`).
        """
        try:
            t = float(t)
        except (TypeError, ValueError):
            rec = StepRecord(t=float("nan"), q_body_icrs=None, bias_rad_s=None, sigma_rad=None)
            rec.rejected.append(("time", f"not a number: {t!r}; all inputs of this step "
                                         "ignored"))
            return self._finish(rec)
        rec = StepRecord(t=t, q_body_icrs=None, bias_rad_s=None, sigma_rad=None)
        if not np.isfinite(t):
            rec.rejected.append(("time", f"non-finite time {t}"))
            return self._finish(rec)
        if exposure_s is not None:
            try:
                exposure_s = float(exposure_s)
            except (TypeError, ValueError):
                exposure_s = float("nan")
            if not (np.isfinite(exposure_s) and exposure_s >= 0):
                rec.rejected.append(("camera", f"exposure_s must be a finite duration ≥ 0, "
                                               f"got {exposure_s}; the frame is ignored"))
                frame = detections = None
        if self.t is not None and t < self.t:
            rec.rejected.append(("time", f"time went backwards ({t} < {self.t}); "
                                         "all inputs of this step ignored"))
            return self._finish(rec)
        self._propagate_to(float(t), rec)
        if gyro is not None:
            refused = self._take_gyro(float(t), gyro)
            if refused:
                rec.rejected.append(("gyro", refused))
            else:
                rec.sensors.append("gyro")
            if self._gyro_note:
                rec.rejected.append(("gyro", self._gyro_note))
                self._gyro_note = ""
        if frame is not None or detections is not None:
            self._use_camera(camera)
            try:
                self._star_update(frame, detections, rec,
                                  self.exposure_s if exposure_s is None else exposure_s)
            finally:
                self._use_camera(0)
        if mag is not None:
            self._mag_update(mag, rec)
        return self._finish(rec)

    def step_gyro(self, t: float, gyro: ArrayLike) -> tuple[str, str] | None:
        """``step(t, gyro=gyro)`` without building its :class:`StepRecord`, for loops that
        step at the gyro rate and look at the estimate only now and then: the same checks,
        propagation and zero-order hold (the filter ends up bit-identical). Returns None,
        or what the record's ``rejected`` would hold — ``("time", why)`` when the step was
        refused, ``("gyro", why)`` when the sample was.

        >>> est = Estimator(None, q_body_icrs0=[1.0, 0.0, 0.0, 0.0])
        >>> est.step_gyro(0.0, [0.0, 0.0, 0.01]), est.step_gyro(1.0, [0.0, 0.0, 0.01])
        (None, None)
        >>> round(float(np.degrees(rot.angle_between(est.filter.q_body_icrs, rot.IDENTITY))), 3)
        0.573
        >>> est.step_gyro(2.0, [0.0, float("nan"), 0.0])
        ('gyro', 'not a finite 3-vector: [0.0, nan, 0.0]')
        >>> est.step_gyro(1.5, [0.0, 0.0, 0.01])[0]
        'time'
        """
        try:
            t = float(t)
        except (TypeError, ValueError):
            return ("time", f"not a number: {t!r}; all inputs of this step ignored")
        if not math.isfinite(t):
            return ("time", f"non-finite time {t}")
        if self.t is not None and t < self.t:
            return ("time", f"time went backwards ({t} < {self.t}); all inputs of this step "
                            "ignored")
        self._propagate_to(t, None)
        refused = self._take_gyro(t, gyro)
        return ("gyro", refused) if refused else None

    def add_fix(self, t: float, q_cam_icrs: ArrayLike, covariance_cam: ArrayLike,
                source: str = "star fix") -> StepRecord:
        """Adopt an attitude fix identified outside :meth:`step` — e.g. an operator-confirmed
        candidate (:mod:`adfusion.starid.bleif.operator`) — taken at time ``t`` (s): ``q_cam_icrs``
        with its 3×3 camera-frame covariance (rad²). It initialises the filter, or updates it
        through the NIS gate like a solver fix (a rejection is recorded, never dropped
        silently).

        >>> import numpy as np
        >>> est = Estimator(None)
        >>> rec = est.add_fix(0.0, [1.0, 0.0, 0.0, 0.0], np.eye(3) * 1e-6)
        >>> rec.fix_accepted, est.initialized
        (True, True)
        """
        rec = StepRecord(t=float(t), q_body_icrs=None, bias_rad_s=None, sigma_rad=None)
        if not np.isfinite(t) or (self.t is not None and t < self.t):
            rec.rejected.append((source, f"bad time {t} (last step at {self.t})"))
            return self._finish(rec)
        try:
            q = rot.normalize(np.asarray(q_cam_icrs, dtype=np.float64))
            cov = np.asarray(covariance_cam, dtype=np.float64).reshape(3, 3)
        except ValueError as e:
            rec.rejected.append((source, f"bad fix: {e}"))
            return self._finish(rec)
        self._propagate_to(float(t), rec)
        rec.sensors.append(source)
        q_body_icrs = rot.multiply(self.q_body_cam, q)
        cov_body = self.R_body_cam @ cov @ self.R_body_cam.T
        if self.filter is None:
            sigma0 = float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(cov_body))), 0.0)))
            self.filter = self._make_filter(q_body_icrs, max(sigma0, 1e-7))
            rec.fix_accepted = True
        else:
            res = self.filter.update_attitude(q_body_icrs, cov_body)
            rec.nis[source] = float(res.nis)
            rec.fix_accepted = bool(res.accepted)
            if not res.accepted:
                rec.rejected.append((source, f"rejected by the filter gate: {res.reason}"))
        if rec.fix_accepted:
            self.misses = 0
        return self._finish(rec)

    # --- pieces ---------------------------------------------------------------------------

    def _take_gyro(self, t: float, gyro: ArrayLike) -> str:
        """Hold the sample ``gyro`` taken at ``t``; "" or why it is refused."""
        if self.video_only:
            return "video-only estimator: gyro samples are ignored"
        try:
            g = np.asarray(gyro, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            return f"not a finite 3-vector: {gyro!r}"
        if g.shape != (3,):
            return f"not a finite 3-vector: {g.tolist()}"
        x, y, z = g.tolist()
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return f"not a finite 3-vector: {[x, y, z]}"
        glitch = self._gyro_glitch(t, x, y, z)
        if glitch:
            return glitch
        if self._gyro_last is not None and self._outage is None and t > self._gyro_last[0]:
            self._gyro_dts.append(t - self._gyro_last[0])
            del self._gyro_dts[:-16]
        self._omega_hold = g
        self._gyro_last = (t, g)
        if self._outage is not None:
            self._gyro_note = self._end_outage(t)
        return ""

    def _gyro_glitch(self, t: float, x: float, y: float, z: float) -> str:
        """Why the sample (x, y, z) at ``t`` is implausible, or "" if it is not (in floats:
        this runs at the gyro rate)."""
        rate = math.sqrt(x * x + y * y + z * z)
        if rate > self.gyro_max_rate:
            return (f"glitch: |ω| = {rate:.3g} rad/s exceeds gyro_max_rate_rad_s = "
                    f"{self.gyro_max_rate:g}; sample ignored")
        if self._gyro_last is None or not math.isfinite(self.gyro_max_accel):
            return ""
        t0, g0 = self._gyro_last
        x0, y0, z0 = g0.tolist()
        dt = max(t - t0, 0.0)
        step = math.sqrt((x - x0) ** 2 + (y - y0) ** 2 + (z - z0) ** 2)
        if dt == 0.0:
            allowed = self.gyro_max_accel * 1e-3  # a repeated time: allow a ms of change
        else:
            noise = 8.0 * self.arw / math.sqrt(dt)
            allowed = self.gyro_max_accel * dt + (noise if math.isfinite(noise) else 0.0)
        if step > allowed:
            return (f"glitch: ω changed by {step:.3g} rad/s in {dt:.3g} s (more than "
                    f"gyro_max_accel_rad_s2 = {self.gyro_max_accel:g} allows); sample ignored")
        return ""

    @property
    def gyro_max_age_s(self) -> float:
        """The age (s) past which a gyro sample no longer propagates the filter: the one
        given, or for a ``gyro_stream`` 5 of its sample intervals (median of the last 16),
        at most 1 s (else ``inf``)."""
        if self._max_age_s is not None:
            return self._max_age_s
        if not self.gyro_stream:
            return math.inf
        if not self._gyro_dts:
            return 1.0
        return min(5.0 * float(np.median(self._gyro_dts)), 1.0)

    @property
    def without_gyro(self) -> bool:
        """Whether the filter runs on its own rate estimate: a video-only estimator, or a
        gyro outage (:attr:`gyro_max_age_s`)."""
        return self.video_only or self._outage is not None

    def _propagate_to(self, t: float, rec: StepRecord | None) -> None:
        if self.t is not None and self.filter is not None and t > self.t:
            if self._outage is None and self._gyro_last is not None and not self.video_only:
                # the held sample is good until it is gyro_max_age_s old, then the outage
                t_stale = self._gyro_last[0] + self.gyro_max_age_s
                if t > t_stale:
                    if t_stale > self.t:
                        self.filter.propagate(t_stale - self.t, self._omega_hold)
                        self.t = t_stale
                    self._begin_outage(max(self.t, t_stale), rec)
            if self._omega_hold is not None and not self.without_gyro:
                self.filter.propagate(t - self.t, self._omega_hold)
            elif t > self.t:  # without a gyro the rate filter uses its own rate; with none
                # ever seen, the gyro filter holds the attitude
                self.filter.propagate(t - self.t, self.filter.bias_rad_s)
        self.t = t

    def _begin_outage(self, t: float, rec: StepRecord | None) -> None:
        t_last, omega = self._gyro_last
        self._outage = GyroOutage.begin(self.filter, omega, self.sigma_rate_outage,
                                        self.rate_walk, t_start_s=t)
        self.filter = self._outage.filter
        self.gyro_outages.append([t, math.nan])
        if rec is not None:
            rec.rejected.append(("gyro", f"no sample since t = {t_last:.6g} s (more than "
                                         f"gyro_max_age_s = {self.gyro_max_age_s:g} s): "
                                         "propagating without the gyro"))

    def _end_outage(self, t: float) -> str:
        self.filter = self._outage.end(self.filter_factory, arw_rad_sqrt_s=self.arw,
                                       rrw_rad_s_sqrt_s=self.rrw)
        self.gyro_outages[-1][1] = t
        self._outage = None
        start = self.gyro_outages[-1][0]
        if self._first_wait:  # the filter started before the gyro's first sample
            self._first_wait = False
            if not t - start > self.gyro_max_age_s:  # (as a stream starts: nothing to say)
                self.gyro_outages.pop()
                return ""
            return f"first sample {t - start:.6g} s after the filter started: the gyro " \
                   "filter takes over"
        return f"samples again after {t - start:.6g} s without: the gyro filter resumes"

    def _star_update(self, frame, detections, rec: StepRecord,
                     exposure_s: float | None = None) -> None:
        if self.solver is None:
            rec.rejected.append(("camera", "no solver configured"))
            return
        # the prior once: the windows are placed from the one the solver tracks from
        prior = self.tracking_prior(exposure_s)
        if detections is not None:
            rec.detection = "given"
        else:
            if prior is not None and self._detect_tracking is not None \
                    and isinstance(frame, np.ndarray):
                try:
                    detections = self._detect_tracking(frame, prior)
                except (ValueError, TypeError) as e:
                    rec.rejected.append(("camera", f"detection in windows failed: {e}; "
                                                   "the whole frame is detected"))
                if detections is not None:
                    rec.detection = "windows"
            if detections is None:
                detect = self._detect
                if detect is None:
                    from adfusion import starid
                    detect = starid.detect
                try:
                    detections = detect(frame, self.solver.camera)
                except (ValueError, TypeError, FileNotFoundError) as e:
                    rec.rejected.append(("camera", f"detection failed: {e}"))
                    return
                rec.detection = "frame"
        rec.sensors.append("camera")
        xy = getattr(detections, "xy", None)
        if isinstance(xy, np.ndarray) and xy.dtype == np.float64 and xy.ndim == 2 \
                and xy.shape[1] == 2:
            rec.detections_xy = xy  # a Detections' own (N, 2) array: no conversion
        else:
            try:
                arr = np.asarray(detections if xy is None else xy, dtype=np.float64)
                rec.detections_xy = arr[:, :2] if arr.ndim == 2 and arr.shape[1] >= 2 \
                    else None
            except (TypeError, ValueError):
                rec.detections_xy = None
        if prior is not None:
            rec.cone_deg = prior.k * prior.sigma_deg
        try:
            sol = self.solver.solve(detections, prior=prior)
        except (ValueError, TypeError) as e:
            rec.rejected.append(("camera", f"bad detections: {e}"))
            self.misses += 1
            return
        rec.solution = sol
        rec.star_mode = sol.mode
        rec.star_ok = sol.ok
        rec.n_stars = len(sol.matches)
        if not sol.ok:
            rec.rejected.append(("star fix", sol.reason))
            self.misses += 1
            return
        q_body_icrs = rot.multiply(self.q_body_cam, sol.q_cam_icrs)
        cov_body = self.fix_covariance_scale * (self.R_body_cam @ sol.covariance
                                                @ self.R_body_cam.T)
        if self.filter is None:
            sigma0 = float(np.sqrt(np.max(np.linalg.eigvalsh(cov_body))))
            self.filter = self._make_filter(q_body_icrs, max(sigma0, 1e-7))
            rec.fix_accepted = True
            self.misses = 0
            return
        delta = rot.log_map(rot.multiply(q_body_icrs, rot.inverse(self.filter.q_body_icrs)))
        surprise = float(delta @ np.linalg.solve(self.filter.P[:3, :3] + cov_body, delta))
        widened = SURPRISE_NIS < surprise <= chi2_gate(
            self.filter.gate_probability or 1 - 1e-12, 3)
        if widened:
            # the prediction is worse than its σ says (a late or mis-scaled gyro): the
            # update then lands near the fix, and the σ after it says what it knows
            self.filter.widen_attitude(delta)
        res = self.filter.update_attitude(q_body_icrs, cov_body)
        rec.nis["star fix"] = surprise if widened else float(res.nis)  # against the prediction
        if res.accepted:
            rec.fix_accepted = True
            self.misses = 0
            self._lis_rejects = []
        elif self._omega_hold is None and sol.mode == "lost-in-space":
            # no gyro has ever been seen: the filter cannot predict a moving body, so a
            # verified lost-in-space fix restarts it (a rate-estimating video-only model
            # is the proper answer; until then, per-frame fixes beat a frozen prediction)
            sigma0 = float(np.sqrt(np.max(np.linalg.eigvalsh(cov_body))))
            self.filter = self._make_filter(q_body_icrs, max(sigma0, 1e-7))
            rec.fix_accepted = True
            rec.rejected.append(("star fix", "no rate information: filter re-initialised "
                                             "from a lost-in-space fix"))
            self.misses = 0
        else:
            rec.rejected.append(("star fix", f"{sol.mode} fix rejected by the filter gate: "
                                             f"{res.reason}"))
            self.misses += 1
            # a verified fix the filter calls impossible: one of the two is wrong, and a
            # filter fed a late or mis-scaled gyro is the likelier (the stream fuzz run:
            # 0.3° off at σ 0.03°, every fix refused). Its σ is widened to reach the fix,
            # the state kept: an honest estimate either way, and the next fix that agrees
            # passes the gate (a false one does not repeat itself)
            self.filter.widen_attitude(delta)
            if sol.mode == "lost-in-space" and self._consistent_rejects(q_body_icrs):
                sigma0 = float(np.sqrt(np.max(np.linalg.eigvalsh(cov_body))))
                off = float(np.degrees(rot.angle_between(self._lis_rejects[-1], rot.IDENTITY)))
                self.filter = self._make_filter(q_body_icrs, max(sigma0, 1e-7))
                rec.fix_accepted = True
                rec.reinitialized = True
                rec.rejected.append(("filter", f"re-initialised from a lost-in-space fix: "
                                     f"{len(self._lis_rejects)} in a row agreed with each "
                                     f"other and put the filter {off:.3g}° off"))
                self._lis_rejects = []
                self.misses = 0

    def tracking_prior(self, exposure_s: float | None = None) -> Prior | None:
        """The prior the next frame of the active camera is identified from — the filter's
        attitude mounted into the camera frame, its 1-σ cone (at least ``min_cone_deg``,
        widened by ``widen_per_miss`` per miss), the smear over ``exposure_s`` — or None
        when that frame goes to lost-in-space (no estimate, or ``max_misses`` misses). A
        caller that detects stars itself (in windows around the predicted stars) uses it
        to place the windows; :meth:`step` uses the same.

        >>> est = Estimator(None, q_body_icrs0=[1.0, 0.0, 0.0, 0.0], sigma_attitude0_rad=1e-3)
        >>> p = est.tracking_prior()
        >>> round(p.sigma_deg, 4), p.k, Estimator(None).tracking_prior()
        (0.0573, 3.0, None)
        """
        if self.filter is None or self.misses >= self.max_misses:
            return None
        f = self.filter
        q_cam_icrs = rot.multiply(self.q_cam_body, f.q_body_icrs)
        p = f.P
        if math.degrees(math.sqrt(max(p[0, 0] + p[1, 1] + p[2, 2], 0.0))) <= self.min_cone_deg:
            sigma = self.min_cone_deg  # λmax ≤ trace: the floor wins (no eigenvalues)
        else:
            sigma = max(f.search_cone_deg(k=1.0), self.min_cone_deg)
        sigma *= self.widen_per_miss ** self.misses
        return Prior(q_cam_icrs, sigma, smear_cam_rad=self._smear(exposure_s))

    def _consistent_rejects(self, q_fix_body_icrs: NDArray) -> bool:
        """Note a gate-rejected lost-in-space fix; ``True`` once ``reinit_after`` of them in a
        row saw the same filter error (a wrong identification does not repeat itself; a
        filter knocked off by a fault shows the same offset to every correct fix)."""
        if self.reinit_after == 0:
            return False
        err = rot.multiply(q_fix_body_icrs, rot.inverse(self.filter.q_body_icrs))
        if self._lis_rejects and (float(rot.angle_between(err, self._lis_rejects[-1]))
                                  > self.reinit_agree_rad):
            self._lis_rejects = []
        self._lis_rejects.append(err)
        return len(self._lis_rejects) >= self.reinit_after

    def _smear(self, exposure_s: float | None) -> NDArray[np.float64] | None:
        """The camera's rotation during the exposure (rad, camera axes) from the rate
        estimate: the gyro's last sample less the bias, or the video-only filter's rate."""
        if not exposure_s or self.filter is None:
            return None
        if self.without_gyro:
            omega_body = np.asarray(self.filter.omega_rad_s)  # RateMEKF: its rate state
        elif self._omega_hold is not None:
            omega_body = self._omega_hold - np.asarray(self.filter.bias_rad_s)
        else:
            return None
        return (self.R_body_cam.T @ omega_body) * float(exposure_s)

    def _mag_update(self, mag, rec: StepRecord) -> None:
        try:
            b_body, r_icrs = (np.asarray(x, dtype=np.float64).reshape(3) for x in mag)
        except (TypeError, ValueError):
            rec.rejected.append(("mag", "expected (field_body, field_icrs), two 3-vectors"))
            return
        nb, nr = np.linalg.norm(b_body), np.linalg.norm(r_icrs)
        if not (np.isfinite(nb) and np.isfinite(nr)) or nb == 0 or nr == 0:
            rec.rejected.append(("mag", "zero-norm or non-finite field vector"))
            return
        if self.filter is None:
            rec.rejected.append(("mag", "no attitude estimate yet: a single vector cannot "
                                        "initialise one"))
            return
        rec.sensors.append("mag")
        res = self.filter.update_vector(b_body / nb, r_icrs / nr, self.sigma_mag_rad)
        rec.nis["mag"] = float(res.nis)
        if not res.accepted:
            rec.rejected.append(("mag", res.reason))


    def _finish(self, rec: StepRecord) -> StepRecord:
        if self.filter is not None:
            rec.q_body_icrs = np.array(self.filter.q_body_icrs)
            rec.bias_rad_s = np.array(self.filter.bias_rad_s)
            rec.cov = np.array(self.filter.P, dtype=np.float64)  # a copy, whatever the filter
            if self._outage is not None:  # the bias (and its σ) kept for the gyro's return
                rec.bias_rad_s = self._outage.bias_rad_s.copy()
                # the held bias is uncorrelated with the attitude the rate filter carries
                rec.cov[3:, :] = 0.0
                rec.cov[:3, 3:] = 0.0
                rec.cov[3:, 3:] = self._outage.bias_cov
            rec.sigma_rad = np.sqrt(rec.cov.diagonal())
        return rec
