"""Is the gyro on the frames' clock? The rotation both see, compared at every lag.

A gyro that runs late or early against the camera (a clock offset, a jump after a gap)
turns the body at the right rates at the wrong times: the filter's prediction and the
star fixes then disagree by the rate change over the offset, and no fault check of either
stream alone can see it (the stream fuzz run found 0.5 s late gyros leaving estimates
0.3° off at σ 0.03°). Consecutive star fixes measure the body rate themselves,
ω = −Log(q₂ ⊗ q₁⁻¹) / Δt (the filter's convention, ``q ← Exp(−ω Δt) ⊗ q``); where that
rate changes, the lag at which the gyro's rates match it best is the offset between the
clocks. :func:`gyro_lags` fits it per window of frames, and :class:`ClockCheck` (a replay
sink) reports every window whose gyro is off as an input problem of the run, so such
estimates are never silently wrong.

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> t_gyro = np.arange(0.0, 4.0, 0.005)
    >>> w_gyro = np.stack([np.sin(2 * t_gyro), np.cos(3 * t_gyro), 0 * t_gyro], axis=1)
    >>> t_fix = np.arange(0.0, 4.0, 1 / 30)
    >>> q, qs = np.array(rot.IDENTITY), []
    >>> for t in t_fix + 1 / 60:  # the body turns at the gyro's rates 0.2 s later
    ...     qs.append(q)
    ...     w = np.array([np.sin(2 * (t + 0.2)), np.cos(3 * (t + 0.2)), 0.0])
    ...     q = rot.multiply(rot.exp_map(-w / 30), q)
    >>> sorted({round(lag, 3) for _, _, lag, _ in gyro_lags(t_fix, np.array(qs), t_gyro, w_gyro)})
    [0.2]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from adfusion.app.replay.stages import FRAME, GYRO, Step
from adfusion.maths import rotations as rot

__all__ = ["ClockCheck", "gyro_lags"]

MAX_LAG_S = 1.0  # the offsets searched: ± this
WINDOW_S = 0.6  # frames fitted together (windows overlap by half)
MIN_PAIRS = 12  # fix pairs a window needs
GAIN = 4.0  # the best lag must fit this many times better than none


def gyro_lags(t_fix: NDArray, q_fix: NDArray, t_gyro: NDArray, w_gyro: NDArray,
              window_s: float = WINDOW_S) -> list[tuple[float, float, float, float]]:
    """Windows (start, end, lag, gain) where the gyro's rates match the star fixes' best
    ``lag`` s later (a positive lag: the gyro is late) and ``gain`` times better than at no
    lag; only those off by more than two gyro samples, fitting ``GAIN`` times better."""
    t_fix, t_gyro = np.asarray(t_fix, float), np.asarray(t_gyro, float)
    if len(t_fix) < MIN_PAIRS + 1 or len(t_gyro) < 4:
        return []
    dt = np.diff(t_fix)
    steps = rot.multiply(q_fix[1:], rot.inverse(q_fix[:-1]))
    w_fix = -rot.log_map(steps) / dt[:, None]
    t_mid = 0.5 * (t_fix[1:] + t_fix[:-1])
    keep = (dt > 0) & (dt <= 0.25)
    t_mid, w_fix = t_mid[keep], w_fix[keep]
    gyro_dt = float(np.median(np.diff(t_gyro)))
    lags = np.arange(-MAX_LAG_S, MAX_LAG_S + gyro_dt / 2, max(gyro_dt, 0.002))
    out = []
    t0 = t_mid[0] if len(t_mid) else 0.0
    while len(t_mid) and t0 <= t_mid[-1]:
        sel = (t_mid >= t0) & (t_mid < t0 + window_s)
        if sel.sum() >= MIN_PAIRS:
            tm, wf = t_mid[sel], w_fix[sel]
            costs = []
            for lag in lags:  # the gyro sample the body turned with, `lag` s later
                tg = tm + lag
                k = np.clip(np.searchsorted(t_gyro, tg), 1, len(t_gyro) - 1)
                # between two samples of the stream, not across a gap of it
                inside = ((tg >= t_gyro[0]) & (tg <= t_gyro[-1])
                          & (t_gyro[k] - t_gyro[k - 1] <= 3 * gyro_dt))
                if inside.sum() < MIN_PAIRS:
                    costs.append(np.inf)
                    continue
                wg = np.stack([np.interp(tg[inside], t_gyro, w_gyro[:, i]) for i in range(3)],
                              axis=1)
                costs.append(float(np.mean(np.sum((wf[inside] - wg) ** 2, axis=1))))
            costs = np.asarray(costs)
            if not np.isfinite(costs).any():  # no lag with enough gyro samples around
                t0 += window_s / 2
                continue
            best = int(np.argmin(costs))
            zero = costs[int(np.argmin(np.abs(lags)))]
            gain = zero / max(costs[best], 1e-300) if np.isfinite(zero) else 0.0
            if (np.isfinite(zero) and gain >= GAIN
                    and abs(lags[best]) > 2 * gyro_dt):
                out.append((float(tm[0]), float(tm[-1]), float(lags[best]), float(gain)))
        t0 += window_s / 2
    return out


class ClockCheck:
    """A replay sink: the primary camera's star fixes and the gyro samples used, compared
    at the end (:func:`gyro_lags`); each window off is a line of the run's problems
    (``Run.notes``), which the output's metadata and the summary carry."""

    def __init__(self) -> None:
        self.t_fix: list[float] = []
        self.q_fix: list[NDArray] = []
        self.t_gyro: list[float] = []
        self.w_gyro: list[list[float]] = []
        self.run = None

    def open(self, run) -> None:
        self.run = run
        self.primary = run.heads[0].index if run.heads else 0

    def take(self, step: Step) -> None:
        if step.kind == GYRO and step.used:
            self.t_gyro.append(float(step.msg.t_s))
            self.w_gyro.append(list(step.msg.payload["omega"]))
        elif step.kind == FRAME and step.record is not None and step.head == self.primary:
            sol = step.record.solution
            if sol is not None and sol.ok:
                self.t_fix.append(float(step.record.t))
                self.q_fix.append(rot.multiply(self.run.q_body_cam, sol.q_cam_icrs))

    def close(self) -> None:
        if self.run is None or not self.t_fix or not self.t_gyro:
            return
        windows = gyro_lags(np.array(self.t_fix), np.array(self.q_fix),
                            np.array(self.t_gyro), np.array(self.w_gyro, dtype=float))
        for start, end, lag, gain in _merged(windows):
            side = "late" if lag > 0 else "early"
            self.run.notes.append(
                f"gyro clock: from {start:.6g} s to {end:.6g} s the gyro's rates match the "
                f"star fixes' {abs(lag):.3g} s {side} ({gain:.3g}× better than on time): "
                "its clock is off there (the filter's σ widened where the star fixes "
                f"disagreed); when the whole run is off, replay with --imu-offset {-lag:+.3g}")

    def abort(self, reason: str) -> None:
        pass


def _merged(windows: list[tuple[float, float, float, float]]) -> list[tuple]:
    """Overlapping or adjacent windows with about one lag (within 25 %, or 10 ms) as one
    (the lag of the first)."""
    out: list[list[float]] = []
    for w in windows:
        if out and abs(out[-1][2] - w[2]) <= max(0.25 * abs(w[2]), 0.01) \
                and w[0] - out[-1][1] <= WINDOW_S:
            out[-1][1], out[-1][3] = w[1], min(out[-1][3], w[3])
        else:
            out.append(list(w))
    return [tuple(w) for w in out]
