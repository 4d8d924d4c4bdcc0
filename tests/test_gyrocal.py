"""Gyro calibration from star fixes (issue 35): scale factors, misalignment and bias
recovered inside their reported 3σ over many seeds, and terms the motion does not excite
reported as unobservable."""

from __future__ import annotations

import numpy as np
from adfusion.sensors.gyro import GyroModel

from adfusion.estimation.gyrocal import gyro_calibration
from adfusion.maths import rotations as rot

RATE_HZ = 50.0
SIGMA_FIX = np.radians(10 / 3600)  # 10″ a fix, per axis
ARW = 3e-5  # rad/√s (0.1°/√h)


def _flight(seed: int, duration_s: float = 300.0, axes: int = 3):
    """A tumbling vehicle (rates up to ~3°/s about ``axes`` body axes), its gyro with
    random scale errors (≤ 5000 ppm), misalignment (≤ 3 mrad) and bias, and 1 Hz star
    fixes of 10″."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1 / RATE_HZ)
    f = rng.uniform(0.01, 0.05, (3, 2))
    omega = np.stack([0.05 * np.sin(2 * np.pi * f[i, 0] * t + rng.uniform(0, 6))
                      + 0.02 * np.sin(2 * np.pi * f[i, 1] * t) for i in range(3)], 1)
    omega[:, axes:] = 0.0
    q = np.empty((len(t), 4))
    q[0] = rot.normalize(rng.standard_normal(4))
    for j in range(1, len(t)):  # the truth, held as the gyro samples it
        q[j] = rot.multiply(rot.exp_map(-omega[j - 1] / RATE_HZ), q[j - 1])
    scale = rng.uniform(-5e-3, 5e-3, 3)
    mis = rng.uniform(-3e-3, 3e-3, (3, 3))
    np.fill_diagonal(mis, 0.0)
    bias = rng.uniform(-1e-4, 1e-4, 3)
    gyro = GyroModel(arw_rad_sqrt_s=ARW, bias_rad_s=bias, scale_factor_error=scale,
                     misalignment=mis, rate_hz=RATE_HZ, seed=seed)
    meas = gyro.measure_many(t, omega).omega_meas
    k_true = np.diag(scale) + mis
    every = int(RATE_HZ)
    q_fix = np.array([rot.multiply(rot.exp_map(rng.normal(0, SIGMA_FIX, 3)), qk)
                      for qk in q[::every]])
    return t, meas, t[::every], q_fix, k_true, bias


def test_scale_misalignment_and_bias_inside_their_3_sigma_over_50_seeds():
    """The issue's acceptance for the gyro's terms: over ≥ 50 seeds each term inside the
    reported 3σ in ≥ 97 % of cases, NEES per term in [0.5, 1.5] on average; the fit's
    residual down to the fixes' own noise."""
    z2 = []
    for seed in range(50):
        t, meas, t_fix, q_fix, k_true, bias = _flight(seed)
        cal = gyro_calibration(t, meas, t_fix, q_fix, sigma_fix_rad=SIGMA_FIX,
                               arw_rad_sqrt_s=ARW)
        assert cal.observable, cal.weak
        err = np.concatenate([(cal.K - k_true).ravel(), cal.bias_rad_s - bias])
        z2.append(err**2 / np.diag(cal.cov))
        assert cal.residual_after_rad < 2 * SIGMA_FIX < cal.residual_before_rad
    z2 = np.asarray(z2)
    assert np.mean(z2 <= 9) >= 0.97
    nees = z2.mean(axis=0)
    assert np.all((nees > 0.5) & (nees < 1.5)), nees.round(2)


def test_terms_the_motion_does_not_excite_are_reported_not_fitted():
    """Turning about body x and y only: the scale of z and the sensitivities of every
    axis to a rate about z are not excited. They come out NaN and named, and the rest is
    still fitted to its truth."""
    t, meas, t_fix, q_fix, k_true, bias = _flight(5, axes=2)
    cal = gyro_calibration(t, meas, t_fix, q_fix, sigma_fix_rad=SIGMA_FIX,
                           arw_rad_sqrt_s=ARW)
    assert not cal.observable
    named = {w.split(":")[0] for w in cal.weak}
    assert {"K[02]", "K[12]", "K[22]"} <= named
    assert np.all(np.isnan(cal.K[:, 2]))
    fitted = ~np.isnan(cal.K)
    sd = np.sqrt(np.diag(cal.cov)[:9]).reshape(3, 3)
    assert np.all(np.abs(cal.K - k_true)[fitted] < 4 * sd[fitted])
    assert np.all(np.abs(cal.bias_rad_s - bias) < 4 * np.sqrt(np.diag(cal.cov)[9:]))
