"""Rotation conventions pinned against GTSAM and scipy, plus property tests."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from adfusion.maths import rotations as rot

TOL = 1e-12

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
quats = arrays(np.float64, 4, elements=finite).filter(lambda q: np.linalg.norm(q) > 1e-3)
vecs = arrays(np.float64, 3, elements=st.floats(-10, 10, allow_nan=False))
rotvecs = arrays(np.float64, 3, elements=st.floats(-3.0, 3.0, allow_nan=False)).filter(
    lambda v: np.linalg.norm(v) < np.pi - 1e-6
)


def random_quats(n: int, seed: int = 0) -> np.ndarray:
    return rot.normalize(np.random.default_rng(seed).normal(size=(n, 4)))


# --- pinned against GTSAM ---------------------------------------------------------------


def test_matrix_matches_gtsam_quaternion_constructor():
    for q in random_quats(200):
        r_gtsam = gtsam.Rot3.Quaternion(*q).matrix()
        np.testing.assert_allclose(rot.to_matrix(q), r_gtsam, atol=TOL)
        np.testing.assert_allclose(rot.from_gtsam(rot.to_gtsam(q)), q, atol=TOL)


def test_compose_rotate_exp_log_match_gtsam():
    rng = np.random.default_rng(1)
    for _ in range(100):
        qa, qb = random_quats(2, int(rng.integers(1 << 30)))
        ra, rb = rot.to_gtsam(qa), rot.to_gtsam(qb)
        np.testing.assert_allclose(
            rot.to_matrix(rot.multiply(qa, qb)), ra.compose(rb).matrix(), atol=TOL
        )
        v = rng.normal(size=3)
        np.testing.assert_allclose(rot.rotate(qa, v), ra.rotate(v), atol=TOL)
        phi = rng.normal(size=3)
        phi *= rng.uniform(0, 3.0) / np.linalg.norm(phi)
        np.testing.assert_allclose(
            rot.to_matrix(rot.exp_map(phi)), gtsam.Rot3.Expmap(phi).matrix(), atol=TOL
        )
        np.testing.assert_allclose(rot.log_map(qa), gtsam.Rot3.Logmap(ra), atol=1e-10)


def test_tiny_rotation_exp_log_match_gtsam():
    for scale in (1e-3, 1e-7, 1e-10, 0.0):
        phi = np.array([0.3, -0.2, 0.9]) * scale
        np.testing.assert_allclose(
            rot.to_matrix(rot.exp_map(phi)), gtsam.Rot3.Expmap(phi).matrix(), atol=TOL
        )
        np.testing.assert_allclose(rot.log_map(rot.exp_map(phi)), phi, atol=1e-15)


# --- pinned against scipy ---------------------------------------------------------------


def test_matrix_rotate_compose_match_scipy():
    qs = random_quats(300, seed=2)
    r = Rotation.from_quat(qs[:, [1, 2, 3, 0]])
    np.testing.assert_allclose(rot.to_matrix(qs), r.as_matrix(), atol=TOL)
    v = np.random.default_rng(3).normal(size=(300, 3))
    np.testing.assert_allclose(rot.rotate(qs, v), r.apply(v), atol=TOL)
    # scipy's r1 * r2 applies r2 first, as R1 @ R2 — the same as our Hamilton product
    np.testing.assert_allclose(
        rot.to_matrix(rot.multiply(qs[:-1], qs[1:])), (r[:-1] * r[1:]).as_matrix(), atol=TOL
    )
    np.testing.assert_allclose(rot.from_scipy(rot.to_scipy(qs)), qs, atol=TOL)
    rv = r.as_rotvec()
    np.testing.assert_allclose(rot.to_matrix(rot.exp_map(rv)), r.as_matrix(), atol=TOL)
    np.testing.assert_allclose(rot.log_map(qs), rv, atol=1e-10)
    np.testing.assert_allclose(rot.from_matrix(r.as_matrix()), qs, atol=TOL)


def test_from_matrix_handles_every_branch_and_180_degrees():
    for axis in np.eye(3):
        for angle in (np.pi, np.pi - 1e-9, 1e-9, 2.0):
            q = rot.exp_map(axis * angle)
            q2 = rot.from_matrix(rot.to_matrix(q))
            assert rot.angle_between(q, q2) < 1e-8


def test_from_matrix_rejects_reflection():
    with pytest.raises(ValueError, match="reflection"):
        rot.from_matrix(np.diag([1.0, 1.0, -1.0]))


# --- frame naming convention ----------------------------------------------------------------


def test_q_a_b_rotates_b_into_a_and_composes_left_to_right():
    # frame b is frame a turned +90° about z: b's x axis is a's y axis
    q_a_b = rot.exp_map([0, 0, np.pi / 2])
    np.testing.assert_allclose(rot.rotate(q_a_b, [1, 0, 0]), [0, 1, 0], atol=TOL)
    q_b_c = rot.exp_map([np.pi / 2, 0, 0])
    q_a_c = rot.multiply(q_a_b, q_b_c)
    v_c = np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(
        rot.rotate(q_a_c, v_c), rot.rotate(q_a_b, rot.rotate(q_b_c, v_c)), atol=TOL
    )


def test_normalize_canonicalises_and_rejects_garbage():
    assert rot.normalize([-2, 0, 0, 0]).tolist() == [1, 0, 0, 0]
    for bad in ([0, 0, 0, 0], [np.nan, 1, 0, 0], [np.inf, 0, 0, 0]):
        with pytest.raises(ValueError):
            rot.normalize(bad)
    with pytest.raises(ValueError, match="4 components"):
        rot.to_matrix([1, 0, 0])


# --- property tests -------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(quats, quats, quats)
def test_compose_is_associative_and_inverse_cancels(a, b, c):
    a, b, c = rot.normalize(a), rot.normalize(b), rot.normalize(c)
    left = rot.multiply(rot.multiply(a, b), c)
    right = rot.multiply(a, rot.multiply(b, c))
    assert rot.angle_between(left, right) < 1e-12
    assert rot.angle_between(rot.multiply(a, rot.inverse(a)), rot.IDENTITY) < 1e-7
    assert rot.angle_between(rot.multiply(rot.inverse(b), b), rot.IDENTITY) < 1e-7


@settings(max_examples=200, deadline=None)
@given(quats, vecs)
def test_rotation_preserves_length_and_inverts(q, v):
    v2 = rot.rotate(q, v)
    assert np.isclose(np.linalg.norm(v2), np.linalg.norm(v), atol=1e-12)
    np.testing.assert_allclose(rot.rotate(rot.inverse(q), v2), v, atol=1e-11)


@settings(max_examples=200, deadline=None)
@given(quats)
def test_matrix_round_trip(q):
    q = rot.normalize(q)
    q2 = rot.from_matrix(rot.to_matrix(q))
    assert rot.angle_between(q, q2) < 1e-12
    assert q2[0] >= 0
    if q[0] > 1e-9:  # at w ≈ 0 (180°) the sign is decided by round-off; elsewhere exact
        np.testing.assert_allclose(q2, q, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(rotvecs)
def test_exp_log_round_trip(phi):
    np.testing.assert_allclose(rot.log_map(rot.exp_map(phi)), phi, atol=1e-11)


@settings(max_examples=100, deadline=None)
@given(
    st.floats(0, 2 * np.pi - 1e-9),
    st.floats(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6),
    st.floats(0, 2 * np.pi - 1e-9),
)
def test_radec_roll_round_trip(ra, dec, roll):
    q = rot.q_cam_icrs_from_radec_roll(ra, dec, roll)
    ra2, dec2, roll2 = rot.radec_roll_from_q_cam_icrs(q)
    assert abs(np.angle(np.exp(1j * (ra2 - ra)))) < 1e-9
    assert abs(dec2 - dec) < 1e-9
    assert abs(np.angle(np.exp(1j * (roll2 - roll)))) < 1e-9
    # the boresight (+z camera) points at (ra, dec)
    b_icrs = rot.rotate(rot.inverse(q), [0, 0, 1])
    np.testing.assert_allclose(b_icrs, rot.radec_to_vector(ra, dec), atol=1e-12)


def test_roll_zero_puts_north_up_and_east_left():
    ra, dec = np.radians(40.0), np.radians(25.0)
    q_cam_icrs = rot.q_cam_icrs_from_radec_roll(ra, dec, 0.0)
    step = np.radians(0.5)
    north = rot.rotate(q_cam_icrs, rot.radec_to_vector(ra, dec + step))
    east = rot.rotate(q_cam_icrs, rot.radec_to_vector(ra + step, dec))
    assert north[1] < 0 and abs(north[0]) < 1e-12  # up in the image (−y)
    assert east[0] < 0  # left in the image (−x)
    # roll +90°: image up points east
    q90 = rot.q_cam_icrs_from_radec_roll(ra, dec, np.pi / 2)
    east90 = rot.rotate(q90, rot.radec_to_vector(ra + step, dec))
    assert east90[1] < 0 and abs(east90[0]) < 0.01 * abs(east90[1])


def test_radec_vector_unit_cases():
    # Renken AC-03
    np.testing.assert_allclose(rot.radec_to_vector(0, 0), [1, 0, 0], atol=TOL)
    np.testing.assert_allclose(rot.radec_to_vector(np.pi / 2, 0), [0, 1, 0], atol=TOL)
    np.testing.assert_allclose(rot.radec_to_vector(1.234, np.pi / 2), [0, 0, 1], atol=TOL)
    ra, dec = rot.vector_to_radec(np.array([[0, -1, 0], [1, 0, 1]]))
    np.testing.assert_allclose(ra, [1.5 * np.pi, 0], atol=TOL)
    np.testing.assert_allclose(dec, [0, np.pi / 4], atol=TOL)


def test_vectorised_shapes():
    qs = random_quats(7)
    assert rot.to_matrix(qs).shape == (7, 3, 3)
    assert rot.rotate(qs[0], np.zeros((5, 3))).shape == (5, 3)
    assert rot.rotate(qs, np.ones((7, 3))).shape == (7, 3)
    assert rot.multiply(qs, qs[0]).shape == (7, 4)
    assert rot.exp_map(np.zeros((4, 3))).shape == (4, 4)
    assert rot.skew(np.ones((2, 3))).shape == (2, 3, 3)
    a, b = np.random.default_rng(0).normal(size=(2, 3))
    np.testing.assert_allclose(rot.skew(a) @ b, np.cross(a, b), atol=TOL)


def test_multiply_one_pair_equals_the_batched_product_bit_for_bit():
    rng = np.random.default_rng(11)
    p, q = rng.normal(size=(500, 4)), rng.normal(size=(500, 4))
    batch = rot.multiply(p, q)
    assert np.array_equal(np.array([rot.multiply(a, b) for a, b in zip(p, q, strict=True)]), batch)
    # and the Hamilton convention: R(p ⊗ q) = R(p) R(q)
    assert np.allclose(rot.to_matrix(rot.multiply(p[0], q[0])),
                       rot.to_matrix(p[0]) @ rot.to_matrix(q[0]))
