""":func:`smooth`: the graph solved in one batch (Levenberg–Marquardt, or Gauss–Newton for
video-only logs) or frame by frame (iSAM2), with marginal covariances."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.estimation.smoother.factors import preintegrate, q_of, symbols
from adfusion.estimation.smoother.graph import (
    GraphModel,
    anchored_components,
    fill_by_gyro,
    fill_by_rate,
    frame_rates,
    initial_attitudes,
)
from adfusion.estimation.smoother.inputs import SmootherError, SmootherInput
from adfusion.estimation.smoother.noise import calibrate_star_noise
from adfusion.estimation.smoother.result import SmoothResult

Array = NDArray[np.float64]


#: iSAM2 relinearises a state when it has moved by more than min(this, σ0) (rad; σ0 the
#: calibrated star noise) and back-substitutes changes down to a tenth of that. Robust weights
#: are re-evaluated only on relinearisation, so the threshold must follow the star noise: on
#: the LEO log (σ0 = 9e-6 rad) a fixed 1e-4 left iSAM2 at 0.00073° RMS against the batch
#: 0.00060° (the weights stayed where the filter's estimate put them); σ0 gives 0.00061° at
#: 0.36 ms per update. On the OEDIPUS-like log (σ0 = 2.7e-4) 1e-4 matches the batch at
#: 0.2 ms per update, and 1e-5 costs 20× more for nothing.
ISAM2_RELINEARIZE_MAX = 1e-4


def smooth(
    inp: SmootherInput,
    *,
    mode: str = "batch",
    star_model: str = "stars",
    robust: str = "cauchy",
    robust_k: float = 3.0,
    sigma_star_rad: float | None = None,
    streak_s: float | None = None,
    sigma_bias0_rad_s: float = 1e-2,
    rate_walk_rad_s_sqrt_s: float = 0.003,
    sigma_rate0_rad_s: float = 5.0,
    max_gyro_gap_s: float = 0.25,
    max_iterations: int = 100,
    covariances: bool = True,
) -> SmoothResult:
    """Smooth a recorded log: one state per frame, all measurements at once (module docstring).

    Args:
        inp: the recording.
        mode: ``"batch"`` (Levenberg–Marquardt) or ``"isam2"`` (one update per frame).
        star_model: ``"stars"`` (a direction factor per identified star) or ``"fix"`` (the
            solver's fix as a prior with its covariance).
        robust, robust_k: ``"huber"`` | ``"cauchy"`` | ``"none"`` and the kernel's threshold
            in whitened units, for star, fix and magnetometer factors.
        sigma_star_rad, streak_s: star noise ``σ0`` (rad) and along-motion coefficient ``k``
            (s); None: calibrated from the log (:func:`calibrate_star_noise`).
        sigma_bias0_rad_s: 1σ of the weak prior on the first gyro bias (about the filter's).
        rate_walk_rad_s_sqrt_s, sigma_rate0_rad_s: video-only: rate random-walk density and
            the 1σ of the weak prior on the first rate.
        max_gyro_gap_s: a longer gap in the gyro between two frames is reported in
            ``problems`` and leaves those frames without a gyro factor.
        max_iterations: iteration limit of the batch solve.
        covariances: compute marginal covariances (the dominant cost of a batch solve).

    Raises:
        SmootherError: nothing anchors the attitude, the optimiser failed or did not
            converge, or the system is indeterminate.
        ValueError: bad arguments.
    """
    import gtsam

    if mode not in ("batch", "isam2"):
        raise ValueError(f"mode must be 'batch' or 'isam2', got {mode!r}")
    if star_model not in ("stars", "fix"):
        raise ValueError(f"star_model must be 'stars' or 'fix', got {star_model!r}")
    if robust not in ("huber", "cauchy", "none"):
        raise ValueError(f"robust must be 'huber', 'cauchy' or 'none', got {robust!r}")
    t_build = time.perf_counter()
    frames = inp.frames
    n = len(frames)
    problems: list[str] = list(inp.problems)
    if n == 0:
        raise SmootherError("no camera frames in the log")
    anchored = [f.n_stars >= 2 or (f.q_fix is not None and f.cov_fix is not None)
                for f in frames]
    if not any(anchored):
        raise SmootherError("no frame with ≥ 2 identified stars or a fix: nothing anchors "
                            "the attitude")
    t = np.array([f.t for f in frames])
    video = inp.video_only
    g_t, g_w = inp.gyro
    if not video and len(g_t) < 2:
        raise SmootherError(f"{len(g_t)} gyro samples: a gyro log needs ≥ 2 (or smooth it "
                            "video-only)")
    R_key, B_key, W_key = symbols()

    # starting point: the filter's estimates, gaps filled from their neighbours
    q0, bias0 = initial_attitudes(frames, t)
    pims: list[Any] = [None] * n
    if not video:
        pims = preintegrate(t, g_t, g_w, bias0, inp.arw, max_gyro_gap_s, problems)
        q0 = fill_by_gyro(frames, q0, pims)
    omega = frame_rates(t, q0, bias0, g_t, g_w, video)
    if video:
        q0 = fill_by_rate(frames, t, q0, omega)

    # star noise: calibrated from the log unless given
    if sigma_star_rad is None or streak_s is None:
        s0, k, used = calibrate_star_noise([f.b_body for f in frames],
                                           [f.r_icrs for f in frames], list(omega))
        if used < 20:
            problems.append(f"star noise calibrated from only {used} residuals")
        if not math.isfinite(s0):
            if sigma_star_rad is None:
                raise SmootherError("cannot calibrate the star noise (no frame with ≥ 3 "
                                    "stars): pass sigma_star_rad")
            s0, k = sigma_star_rad, 0.0
        sigma_star_rad = s0 if sigma_star_rad is None else sigma_star_rad
        streak_s = k if streak_s is None else streak_s
    sigma0, kstreak = float(sigma_star_rad), float(streak_s)

    # frames tied to no star data through the motion model cannot be estimated: left out
    linked = np.ones(n, dtype=bool) if video else np.array([p is not None for p in pims])
    keep = anchored_components(anchored, linked)
    if not keep.all():
        drop = np.flatnonzero(~keep)
        problems.append(f"{len(drop)} frame(s) left out, first at t = {t[drop[0]]:.3f} s: no "
                        "identified stars and no motion constraint to a frame with some")
    model = GraphModel(inp, t, q0, bias0, omega, pims, sigma0, kstreak, star_model, robust,
                        robust_k, sigma_bias0_rad_s, rate_walk_rad_s_sqrt_s,
                        sigma_rate0_rad_s)
    steps = model.steps(keep)
    no_stars = [k for k in np.flatnonzero(keep) if not model.star_factors[k]]
    if no_stars:
        problems.append(f"{len(no_stars)} of {int(keep.sum())} frames have no identified "
                        f"stars (first at t = {t[no_stars[0]]:.3f} s): their states rest on "
                        "the motion model")
    build_s = time.perf_counter() - t_build

    t_opt = time.perf_counter()
    graph, result, isam, iterations, err0, err1, update_s = optimize(
        steps, mode, max_iterations, sigma0, python_factors=video)
    optimize_s = time.perf_counter() - t_opt

    t_cov = time.perf_counter()
    idx = np.flatnonzero(keep)
    second = W_key if video else B_key
    cov_att = np.full((len(idx), 3, 3), np.nan)
    cov_diag = np.full((len(idx), 6), np.nan)
    if covariances:
        try:
            marg = gtsam.Marginals(graph, result) if mode == "batch" else None
            for j, k in enumerate(idx):
                if marg is not None:
                    cov = marg.jointMarginalCovariance([R_key(k), second(k)]).fullMatrix()
                    cov_att[j], cov_diag[j] = cov[:3, :3], np.diag(cov)
                else:
                    cov_att[j] = isam.marginalCovariance(R_key(k))
                    cov_diag[j] = np.concatenate([np.diag(cov_att[j]), np.diag(
                        isam.marginalCovariance(second(k)))])
        except (RuntimeError, IndexError) as e:
            raise SmootherError(f"marginal covariances failed (indeterminate system?): {e}") \
                from e
    covariance_s = time.perf_counter() - t_cov

    chi2 = np.full(len(idx), np.nan)
    outliers: list[tuple[float, int, float]] = []
    for j, k in enumerate(idx):
        if model.star_factors[k]:
            chi2[j] = 0.0
        for fac, base, sid in model.star_factors[k]:
            wr = float(np.linalg.norm(base.whiten(fac.unwhitenedError(result))))
            chi2[j] += wr * wr
            if robust != "none" and wr > robust_k:
                outliers.append((float(t[k]), sid, wr))
    return SmoothResult(
        t=t[idx], q_body_icrs=np.array([q_of(result.atRot3(R_key(k))) for k in idx]),
        bias_rad_s=np.zeros((len(idx), 3)) if video else np.array(
            [result.atVector(B_key(k)) for k in idx]),
        omega_rad_s=np.array([result.atVector(W_key(k)) for k in idx]) if video else None,
        cov_attitude=cov_att, cov_diag=cov_diag, n_stars=model.n_star[idx], chi2_stars=chi2,
        mode=mode, video_only=video, outliers=outliers, iterations=int(iterations),
        error_initial=float(err0), error_final=float(err1),
        n_factors=sum(g.size() for g, _ in steps), sigma_star_rad=sigma0, streak_s=kstreak,
        build_s=build_s, optimize_s=optimize_s, covariance_s=covariance_s,
        update_s=update_s, problems=problems)


def optimize(steps: list[tuple[Any, Any]], mode: str, max_iterations: int,
              relinearize_rad: float, python_factors: bool):
    """Batch (LM, or Gauss–Newton with ``python_factors``) or frame-by-frame iSAM2 over
    ``steps``; raises :class:`SmootherError`."""
    import gtsam

    graph, init = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for g, v in steps:
        graph.push_back(g)
        init.insert(v)
    isam, update_s = None, np.empty(0)
    try:
        if mode == "isam2":
            p = gtsam.ISAM2Params()
            threshold = min(ISAM2_RELINEARIZE_MAX, relinearize_rad)
            p.setRelinearizeThreshold(threshold)
            p.relinearizeSkip = 1
            p.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.1 * threshold))
            isam = gtsam.ISAM2(p)
            times = []
            for g, v in steps:
                s = time.perf_counter()
                isam.update(g, v)
                times.append(time.perf_counter() - s)
            update_s = np.array(times)
            result = isam.calculateEstimate()
            iterations = len(steps)
        else:
            if python_factors:
                result, iterations = gauss_newton(graph, init, max_iterations)
            else:
                params = gtsam.LevenbergMarquardtParams()
                params.setMaxIterations(max_iterations)
                params.setRelativeErrorTol(1e-9)
                params.setAbsoluteErrorTol(1e-9)
                opt = gtsam.LevenbergMarquardtOptimizer(graph, init, params)
                result = opt.optimize()
                iterations = opt.iterations()
            if iterations >= max_iterations:
                raise SmootherError(f"the batch solve did not converge in {max_iterations} "
                                    f"iterations (error {graph.error(init):.4g} → "
                                    f"{graph.error(result):.4g})")
    except (RuntimeError, IndexError) as e:  # GTSAM's IndeterminantLinearSystem and friends
        raise SmootherError(f"the graph could not be optimised: {e}") from e
    err0, err1 = graph.error(init), graph.error(result)
    if not math.isfinite(err1):
        raise SmootherError(f"the optimised error is not finite ({err1})")
    return graph, result, isam, iterations, err0, err1, update_s


def gauss_newton(graph: Any, values: Any, max_iterations: int) -> tuple[Any, int]:
    """Gauss–Newton with step halving, driven from Python, for graphs with Python factors.

    GTSAM's own optimisers are slow to call back into Python: on the 1800-frame video-only
    log (1800 ``CustomFactor``s) its Levenberg–Marquardt took 14 s and its Gauss–Newton 7.2 s
    for the six iterations this loop does in 1.4 s (each linearisation 0.13 s, each solve
    0.04 s, when called from here). From the filter's start the full step nearly always
    lowers the error; halving keeps it a descent method when it does not.
    """
    err = graph.error(values)
    for it in range(1, max_iterations + 1):
        delta = graph.linearize(values).optimize()
        step, trial, new = 1.0, values, err
        for _ in range(12):
            trial = values.retract(delta.scale(step) if step != 1.0 else delta)
            new = graph.error(trial)
            if new <= err:
                break
            step *= 0.5
        if not new <= err:  # no descent along the Gauss–Newton direction: at the minimum
            return values, it
        values, decrease, err = trial, err - new, new
        if decrease <= 1e-9 * max(err, 1.0):
            return values, it
    return values, max_iterations
