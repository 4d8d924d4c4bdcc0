"""Random sensor errors for a simulated flight (issue 35): what a real log's sensors carry
and a calibration from the flight must find — magnetometer hard and soft iron, gyro scale
factors and misalignment — drawn per seed and stated in the scenario's configuration
(``config["sensor_errors"]``, the truth the calibration is checked against).

Example:
    >>> from adfusion.sensors.scenarios import leo
    >>> sc = with_sensor_errors(leo(duration_s=1.0, render=False))
    >>> sorted(sc.config["sensor_errors"]), len(sc.config["sensor_errors"]["gyro"])
    (['gyro', 'mag'], 2)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["random_sensor_errors", "with_sensor_errors"]

#: the issue's ranges: hard iron up to 20 % of the field, soft iron up to 10 %, gyro scale
#: 5000 ppm, misalignment 3 mrad (each term uniform within ±)
HARD_IRON_FRACTION = 0.2
SOFT_IRON = 0.1
GYRO_SCALE = 5e-3
GYRO_MISALIGNMENT_RAD = 3e-3


def random_sensor_errors(seed: int, field_nT: float) -> dict[str, Any]:
    """Errors of one seed: ``{"gyro": {scale_factor_error, misalignment}, "mag":
    {hard_iron_nT, soft_iron}}`` (the keyword arguments of
    :class:`~adfusion.sensors.gyro.GyroModel` and
    :class:`~adfusion.sensors.magnetometer.MagnetometerModel`); ``field_nT`` the field's
    magnitude the hard iron is a fraction of."""
    rng = np.random.default_rng([int(seed), 35])
    mis = rng.uniform(-GYRO_MISALIGNMENT_RAD, GYRO_MISALIGNMENT_RAD, (3, 3))
    np.fill_diagonal(mis, 0.0)
    return {
        "gyro": {"scale_factor_error": rng.uniform(-GYRO_SCALE, GYRO_SCALE, 3).tolist(),
                 "misalignment": mis.tolist()},
        "mag": {"hard_iron_nT": (rng.uniform(-1, 1, 3) * HARD_IRON_FRACTION * field_nT
                                 / np.sqrt(3)).tolist(),
                "soft_iron": (np.eye(3) + rng.uniform(-SOFT_IRON, SOFT_IRON, (3, 3))).tolist()},
    }


def with_sensor_errors(scenario: Any, errors: dict[str, Any] | None = None) -> Any:
    """``scenario`` with ``errors`` (default: :func:`random_sensor_errors` of its seed, the
    field's magnitude at its start) in its gyro and magnetometer, and stated in its
    configuration; returns the same scenario."""
    if errors is None:
        b = scenario._mag_reference[0]
        field = float(np.median(np.linalg.norm(b, axis=1))) if len(b) else 50_000.0
        errors = random_sensor_errors(scenario.seed, field)
    scenario._gyro_kw.update(errors["gyro"])
    scenario._mag_kw.update(errors["mag"])
    scenario.config["sensor_errors"] = errors
    return scenario
