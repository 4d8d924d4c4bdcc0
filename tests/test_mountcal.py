"""Camera mounts from the fixes (issue 35): the relative alignment of star heads, measured
directly from simultaneous fixes."""

from __future__ import annotations

import numpy as np
import pytest

from adfusion.estimation.mountcal import relative_mount
from adfusion.maths import rotations as rot

ARCSEC = np.radians(1 / 3600)
SIGMA_CAM = np.array([5.0, 5.0, 40.0]) * ARCSEC  # a head's fix: pointing 5″, roll 40″


def _heads(seed: int, minutes: float = 10.0):
    """Three heads 90° apart (as leo3), each mount off its nominal by up to 10′, fixes of
    each at 1 Hz while the body turns; every fix's error drawn per camera axis."""
    rng = np.random.default_rng(seed)
    nominal = [rot.exp_map(np.radians(v)) for v in ([0, 0, 0], [90, 0, 0], [0, 90, 0])]
    mounts = [rot.multiply(rot.exp_map(rng.uniform(-1, 1, 3) * np.radians(10 / 60)), q)
              for q in nominal]  # q_cam_body
    n = int(minutes * 60)
    q_body = rot.normalize(rng.standard_normal(4))
    fixes = [[], [], []]
    for _ in range(n):
        q_body = rot.multiply(rot.exp_map(rng.normal(0, 0.01, 3)), q_body)
        for k, m in enumerate(mounts):
            q_cam = rot.multiply(m, q_body)
            fixes[k].append(rot.multiply(rot.exp_map(rng.normal(0, 1, 3) * SIGMA_CAM), q_cam))
    return mounts, [np.array(f) for f in fixes]


def test_three_heads_relative_alignment_within_5_arcsec_from_10_minutes():
    """The issue's acceptance: from 10 min of fixes the relative alignment of each pair
    of heads is recovered to ≤ 5″ (1σ) per axis, its error inside the reported 3σ; over
    50 seeds the NEES per axis is in [0.5, 1.5]."""
    z2 = []
    for seed in range(50):
        mounts, fixes = _heads(seed)
        for a, b in ((0, 1), (0, 2), (1, 2)):
            fit = relative_mount(fixes[a], fixes[b], sigma_a_rad=SIGMA_CAM,
                                 sigma_b_rad=SIGMA_CAM)
            truth = rot.multiply(mounts[a], rot.conjugate(mounts[b]))
            err = rot.log_map(rot.multiply(fit.q_a_b, rot.conjugate(truth)))
            z2.append(err**2 / np.diag(fit.cov))
            assert np.all(fit.sigma_rad <= 5 * ARCSEC), fit.sigma_rad / ARCSEC
            assert fit.pairs == 600
    z2 = np.asarray(z2)
    assert np.mean(z2 <= 9) >= 0.97
    nees = z2.mean(axis=0)
    assert np.all((nees > 0.5) & (nees < 1.5)), nees.round(2)


def test_the_angle_between_boresights_is_the_mounts():
    mounts, fixes = _heads(1, minutes=1)
    fit = relative_mount(fixes[0], fixes[1], sigma_a_rad=SIGMA_CAM, sigma_b_rad=SIGMA_CAM)
    z = [rot.to_matrix(rot.conjugate(m)) @ [0, 0, 1] for m in mounts[:2]]  # in the body
    assert fit.angle_rad == pytest.approx(np.arccos(np.dot(*z)), abs=20 * ARCSEC)


def test_relative_mount_refuses_unpaired_fixes():
    with pytest.raises(ValueError, match="simultaneous pairs"):
        relative_mount(np.ones((3, 4)), np.ones((2, 4)), sigma_a_rad=1e-5, sigma_b_rad=1e-5)
