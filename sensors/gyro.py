"""Rate-integrating gyro model: noise (ARW, RRW), bias, scale factor, misalignment, limits.

The stochastic part is the exact discrete model of a rate-integrating gyro (Farrenkopf 1978;
Crassidis & Junkins, *Optimal Estimation of Dynamic Systems*, 2nd ed., §7.2.1, Eq. 7.37):
for a sample covering the interval Δt that ends at ``t_{k+1}``,

    ω_meas,k+1 = ω_k+1 + ½(β_k+1 + β_k) + sqrt(σv²/Δt + σu²Δt/12) · N_v
    β_k+1      = β_k + σu √Δt · N_u

with ``σv`` the angle random walk (rad/√s), ``σu`` the rate (bias) random walk (rad/s^{3/2})
and N_v, N_u independent standard normals, per axis. The model is exact in the sense that
the integrated angle of the discrete samples has the same statistics as the continuous
model's at every sample time, so the Allan variance of a stationary record is exactly
``σv²/τ + σu²τ/3`` at τ = mΔt (see :func:`allan_deviation`).

The deterministic errors, applied in this order (DESIGN.md: ``omega_meas = omega_body +
bias + noise``, rad/s, body frame):

    ω_meas = clip(quantise((I + diag(s) + M) ω_true + ½(β_k+1 + β_k) + noise), ±saturation)

with ``s`` the scale-factor errors (dimensionless; 1e-4 = 100 ppm), ``M`` the misalignment /
non-orthogonality (small-angle matrix, zero diagonal: M[i, j] is the sensitivity of axis i to
rate about axis j), quantisation to the nearest multiple of ``quantum_rad_s`` and clipping at
``±saturation_rad_s``. The returned true bias is β at the sample time (β_k+1), the state a
filter estimates; it starts at ``bias_rad_s``.

Example:
    >>> import numpy as np
    >>> from adfusion.sensors.gyro import GyroModel
    >>> gyro = GyroModel(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6,
    ...                  bias_rad_s=[1e-3, 0.0, 0.0], rate_hz=100.0, seed=1)
    >>> omega, bias = gyro.measure(0.01, [0.0, 0.0, 0.1])
    >>> omega.shape, bool(abs(omega[2] - 0.1) < 0.01), bias.round(6).tolist()
    ((3,), True, [0.001, 0.0, 0.0])
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["GyroModel", "GyroSample", "allan_deviation"]

Array = NDArray[np.float64]


class GyroSample(NamedTuple):
    """One gyro output (or a stack of them): measured rate and the true bias, rad/s."""

    omega_meas: Array
    bias: Array


def _vec3(x: ArrayLike, name: str) -> Array:
    v = np.broadcast_to(np.asarray(x, dtype=np.float64), (3,)).copy()
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return v


class GyroModel:
    """A three-axis rate-integrating gyro with a seeded noise generator and bias state.

    Args:
        arw_rad_sqrt_s: angle random walk σv, rad/√s (scalar or per axis).
        rrw_rad_s_sqrt_s: rate random walk σu (bias instability as a random walk),
            rad/s^{3/2} (scalar or per axis).
        bias_rad_s: initial (constant) bias β₀, rad/s.
        scale_factor_error: dimensionless scale-factor errors s (measured = (1 + s)·true).
        misalignment: 3×3 small-angle matrix M with zero diagonal (axis misalignment and
            non-orthogonality), dimensionless.
        saturation_rad_s: output clipped to ±this; ``inf`` = none.
        quantum_rad_s: output quantised to multiples of this; 0 = none.
        rate_hz: sample rate; the first sample covers the interval ``1/rate_hz`` before it,
            later ones the time since the previous call (see :meth:`measure`).
        seed: seed of the ``np.random.Generator`` (or a Generator to draw from).

    The model is stateful (bias random walk, time of the last sample); :meth:`reset`
    returns it to its initial state and seed, so a run is reproducible.
    """

    def __init__(
        self,
        arw_rad_sqrt_s: ArrayLike = 0.0,
        rrw_rad_s_sqrt_s: ArrayLike = 0.0,
        bias_rad_s: ArrayLike = 0.0,
        scale_factor_error: ArrayLike = 0.0,
        misalignment: ArrayLike | None = None,
        saturation_rad_s: float = np.inf,
        quantum_rad_s: float = 0.0,
        rate_hz: float = 100.0,
        seed: int | np.random.Generator | None = 0,
    ) -> None:
        self.arw = _vec3(arw_rad_sqrt_s, "arw_rad_sqrt_s")
        self.rrw = _vec3(rrw_rad_s_sqrt_s, "rrw_rad_s_sqrt_s")
        if np.any(self.arw < 0) or np.any(self.rrw < 0):
            raise ValueError("noise densities must be >= 0")
        self.bias0 = _vec3(bias_rad_s, "bias_rad_s")
        self.scale_factor_error = _vec3(scale_factor_error, "scale_factor_error")
        m = np.zeros((3, 3)) if misalignment is None else np.asarray(misalignment, np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise ValueError(f"misalignment must be a finite 3x3 matrix, got shape {m.shape}")
        if np.any(np.diag(m) != 0):
            raise ValueError("misalignment must have a zero diagonal (put scale errors in "
                             "scale_factor_error)")
        self.misalignment = m
        if not saturation_rad_s > 0:
            raise ValueError(f"saturation_rad_s must be > 0, got {saturation_rad_s!r}")
        if not (np.isfinite(quantum_rad_s) and quantum_rad_s >= 0):
            raise ValueError(f"quantum_rad_s must be >= 0, got {quantum_rad_s!r}")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.saturation_rad_s = float(saturation_rad_s)
        self.quantum_rad_s = float(quantum_rad_s)
        self.rate_hz = float(rate_hz)
        self._seed = seed
        self.reset()

    @property
    def sensitivity(self) -> Array:
        """The 3×3 matrix ``I + diag(s) + M`` applied to the true rate."""
        return np.eye(3) + np.diag(self.scale_factor_error) + self.misalignment

    @property
    def bias(self) -> Array:
        """The current true bias β (rad/s)."""
        return self._beta.copy()

    def reset(self) -> None:
        """Back to the initial bias, no previous sample, and the generator re-seeded."""
        seed = self._seed
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self._beta = self.bias0.copy()
        self._t_last: float | None = None

    def measure(self, t: float, omega_true_body: ArrayLike) -> GyroSample:
        """One sample at time ``t`` (s) of the true body rate (rad/s, body frame).

        The sample integrates over ``Δt = t − t_previous`` (``1/rate_hz`` for the first call);
        times must increase. Returns ``(omega_meas, bias)``.
        """
        t = float(t)
        if self._t_last is None:
            dt = 1.0 / self.rate_hz
        else:
            dt = t - self._t_last
            if not dt > 0:
                raise ValueError(f"sample times must increase: {t} after {self._t_last}")
        w = np.asarray(omega_true_body, dtype=np.float64).reshape(3)
        out, beta = self._run(w[None, :], np.array([dt]), self._beta)
        self._beta = beta[-1].copy()
        self._t_last = t
        return GyroSample(out[0], beta[0])

    def measure_many(self, times: ArrayLike, omega_true_body: ArrayLike) -> GyroSample:
        """Vectorised :meth:`measure` over increasing ``times`` (N,) with rates (N, 3) (or
        one (3,) rate for all); continues from the current state. Same numbers as N calls of
        :meth:`measure` with the same seed."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        w = np.broadcast_to(np.asarray(omega_true_body, dtype=np.float64), (t.size, 3))
        if t.size == 0:
            return GyroSample(np.empty((0, 3)), np.empty((0, 3)))
        first = 1.0 / self.rate_hz if self._t_last is None else t[0] - self._t_last
        dt = np.concatenate([[first], np.diff(t)])
        if not np.all(dt > 0):
            raise ValueError("sample times must increase")
        out, beta = self._run(w, dt, self._beta)
        self._beta = beta[-1].copy()
        self._t_last = float(t[-1])
        return GyroSample(out, beta)

    def _run(self, w: Array, dt: Array, beta0: Array) -> tuple[Array, Array]:
        n = dt.size
        # One (n, 2, 3) draw: per sample N_u then N_v, so single and batched calls consume the
        # generator identically.
        z = self._rng.standard_normal((n, 2, 3))
        steps = z[:, 0, :] * (self.rrw * np.sqrt(dt)[:, None])
        # cumsum from β₀ adds in the same order as one call at a time: bit-identical results
        path = np.cumsum(np.vstack([beta0[None, :], steps]), axis=0)
        beta, beta_prev = path[1:], path[:-1]
        sigma = np.sqrt(self.arw**2 / dt[:, None] + self.rrw**2 * dt[:, None] / 12.0)
        out = w @ self.sensitivity.T + 0.5 * (beta + beta_prev) + sigma * z[:, 1, :]
        if self.quantum_rad_s > 0:
            out = np.round(out / self.quantum_rad_s) * self.quantum_rad_s
        out = np.clip(out, -self.saturation_rad_s, self.saturation_rad_s)
        return out, beta


def allan_deviation(
    rate: ArrayLike, dt: float, taus: ArrayLike | None = None
) -> tuple[Array, Array]:
    """Overlapping Allan deviation of a rate record sampled every ``dt`` seconds.

    Args:
        rate: (N,) or (N, k) samples (rad/s); columns are independent channels.
        dt: sample interval, s.
        taus: averaging times (rounded to whole samples); default ~10 per decade from ``dt``
            to a tenth of the record.

    Returns:
        ``(taus, adev)``; adev has shape (len(taus),) or (len(taus), k). For white rate noise
        of density σv (ARW) adev = σv/√τ; for a rate random walk σu, adev = σu·√(τ/3).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> tau, ad = allan_deviation(rng.normal(0, 0.1, 100_000), 0.01, [1.0])
        >>> round(float(ad[0]), 3)   # σv = 0.1 · √0.01 = 0.01 rad/√s
        0.01
    """
    x = np.asarray(rate, dtype=np.float64)
    n = x.shape[0]
    if taus is None:
        m = np.unique(np.round(np.logspace(0, np.log10(max(n // 10, 1)), 10 * 6)).astype(int))
    else:
        m = np.unique(np.maximum(np.round(np.asarray(taus, np.float64) / dt), 1).astype(int))
    m = m[2 * m < n]
    theta = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, axis=0) * dt])
    out = []
    for mi in m:
        d = theta[2 * mi:] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        tau = mi * dt
        out.append(np.sqrt(np.mean(d * d, axis=0) / (2.0 * tau * tau)))
    return m * dt, np.array(out)
