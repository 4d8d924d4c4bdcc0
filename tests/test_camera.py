"""Camera models: round trips, OpenCV agreement, the thesis cameras."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest
from adfusion.starid import Camera
from adfusion.starid.camera.model import yee_separation_rad
from hypothesis import given, settings
from hypothesis import strategies as st
from yee_fixtures import FOV_DEG, IMAGES, to_pixels

# a strongly distorted lens (k1..k3, tangential, rational and thin-prism terms)
D_STRONG = np.array([-0.28, 0.09, 1e-3, -5e-4, -0.012, 0.01, -0.004, 0.002, 1e-4, -2e-5,
                     3e-4, 1e-5])


def grid(cam: Camera, n: int = 41) -> np.ndarray:
    xs = np.linspace(-0.5, cam.width - 0.5, n)
    ys = np.linspace(-0.5, cam.height - 0.5, n)
    return np.array(list(itertools.product(xs, ys)))


CAMERAS = {
    "pinhole": Camera.pinhole(1024, 768, 11.4),
    "pinhole-wide-distorted": Camera.pinhole(1024, 768, 70.0, D=D_STRONG[:5]),
    "pinhole-rational-prism": Camera.pinhole(640, 480, 50.0, D=D_STRONG),
    "mirrored": Camera.pinhole(1024, 768, 20.0, D=D_STRONG[:5]).mirrored(),
    "renken": Camera.renken(),
    "non-square-oedipus": Camera.pinhole(512, 480, 25.84, fov_y_deg=20.33),
    "yee-oedipus": Camera.yee(512, 480, 25.8356, 20.3319),
    "skewed-K": Camera(np.array([[900.0, 0.7, 300.2], [0, 905.0, 241.0], [0, 0, 1]]),
                       D_STRONG[:4], 640, 480),
}


@pytest.mark.parametrize("name", CAMERAS)
def test_pixel_vector_pixel_round_trip_below_1e9_px(name):
    cam = CAMERAS[name]
    xy = grid(cam)
    v = cam.pixels_to_vectors(xy)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-14)
    back = cam.vectors_to_pixels(v)
    assert np.max(np.abs(back - xy)) < 1e-9


@pytest.mark.parametrize("name", CAMERAS)
def test_vector_pixel_vector_round_trip(name):
    cam = CAMERAS[name]
    rng = np.random.default_rng(4)
    xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], size=(500, 2))
    v = cam.pixels_to_vectors(xy)
    v2 = cam.pixels_to_vectors(cam.vectors_to_pixels(v))
    assert np.max(np.linalg.norm(v2 - v, axis=1)) < 1e-12


@pytest.mark.opencv
@pytest.mark.parametrize("n_coeffs", [0, 4, 5, 8, 12])
def test_forward_projection_matches_opencv(n_coeffs):
    cam = Camera.pinhole(800, 600, 60.0, D=D_STRONG[:n_coeffs] if n_coeffs else None)
    rng = np.random.default_rng(n_coeffs)
    v = rng.normal(size=(300, 3)) * [0.3, 0.25, 1.0]
    v[:, 2] = np.abs(v[:, 2]) + 0.5
    ours = cam.vectors_to_pixels(v)
    theirs, _ = cv2.projectPoints(v.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K,
                                  cam.D if cam.D.size else None)
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), atol=1e-8)
    # and the inverse agrees with OpenCV's (looser: its iteration stops early)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    d = cam.D if cam.D.size else None
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        und = cv2.undistortPointsIter(ours.reshape(-1, 1, 2), cam.K, d, None, None, criteria)
    else:  # OpenCV 5 folded the iterative variant into undistortPoints(criteria=...)
        und = cv2.undistortPoints(ours.reshape(-1, 1, 2), cam.K, d, criteria=criteria)
    und = und.reshape(-1, 2)
    expected = v[:, :2] / v[:, 2:]
    np.testing.assert_allclose(und, expected, atol=1e-6)
    mine = cam.pixels_to_vectors(ours)
    np.testing.assert_allclose(mine[:, :2] / mine[:, 2:], expected, atol=1e-12)


def test_pinhole_geometry_and_conventions():
    cam = Camera.pinhole(1024, 768, 11.4)
    assert cam.fov_x_deg == pytest.approx(11.4, abs=1e-9)
    # +x camera is image right, +y camera is image down, +z is the boresight
    v = cam.pixels_to_vectors([[600.0, 383.5], [511.5, 500.0], [511.5, 383.5]])
    assert v[0, 0] > 0 and abs(v[0, 1]) < 1e-15
    assert v[1, 1] > 0 and abs(v[1, 0]) < 1e-15
    np.testing.assert_allclose(v[2], [0, 0, 1], atol=1e-15)
    # mirrored: the same direction lands on the other side of the centre
    m = cam.mirrored()
    p = m.vectors_to_pixels(cam.pixels_to_vectors([[600.0, 300.0]]))
    np.testing.assert_allclose(p, [[1023 - 600.0, 300.0]], atol=1e-9)
    assert np.isnan(cam.vectors_to_pixels([[0, 0, -1.0]])).all()
    assert cam.in_frame([[-0.5, 0], [1023.6, 5], [np.nan, 1]]).tolist() == [True, False, False]
    assert Camera.from_dict(cam.to_dict()) == cam


def test_non_square_pixels_give_both_fields_of_view():
    cam = Camera.pinhole(512, 480, 25.84, fov_y_deg=20.33)
    assert cam.fov_x_deg == pytest.approx(25.84, abs=1e-9)
    assert cam.fov_y_deg == pytest.approx(20.33, abs=1e-9)
    with pytest.raises(ValueError, match="fov_y_deg"):
        Camera.pinhole(512, 480, 25.84, fov_y_deg=-1.0)


def test_renken_camera_matches_thesis_constants():
    # Renken 1998 App. B: atan(0.023/25.84) = 0.0510°, FOV 384·0.051 ≈ 19.58°, 288·0.051 ≈ 14.69°
    cam = Camera.renken()
    scale_deg = np.degrees(1 / cam.K[0, 0])
    assert scale_deg == pytest.approx(0.0510, abs=1e-4)
    assert cam.fov_x_deg == pytest.approx(384 * scale_deg, abs=1e-9)
    assert cam.fov_y_deg == pytest.approx(288 * scale_deg, abs=1e-9)
    assert cam.fov_x_deg == pytest.approx(19.58, abs=0.01)
    # equidistant: the angle from the boresight is proportional to the pixel distance
    c = cam.K[:2, 2]
    for r in (10.0, 100.0, 190.0):
        for phi in np.radians([0, 37, 145, 270]):
            p = c + r * np.array([np.cos(phi), np.sin(phi)])
            ang = np.degrees(np.arccos(cam.pixels_to_vectors(p)[0, 2]))
            assert ang == pytest.approx(r * scale_deg, rel=1e-12)


@pytest.mark.parametrize("name", list(IMAGES))
def test_yee_separation_reproduces_published_tables(name):
    # Yee 1999 Eq. 2.4: scale = FOV/pixels and cos θ = cos χ cos ψ give T4.1, T4.6, T4.11 (±1e-4°)
    w, h = IMAGES[name]["size"]
    cam = Camera.yee(w, h, *FOV_DEG)
    xy = np.array(to_pixels(name))
    for (i, j), published in IMAGES[name]["sep_deg"].items():
        ours = np.degrees(cam.separation_rad(xy[i - 1], xy[j - 1])[0])
        assert ours == pytest.approx(published, abs=1e-4), (name, i, j)
    # N−1 instead of N pixels in the scale is measurably wrong (Yee 1999 §2.3.4)
    sx, sy = np.radians(FOV_DEG[0] / (w - 1)), np.radians(FOV_DEG[1] / (h - 1))
    worst = max(
        abs(np.degrees(yee_separation_rad(xy[i - 1], xy[j - 1], sx, sy)[0]) - p)
        for (i, j), p in IMAGES[name]["sep_deg"].items()
    )
    assert worst > 2e-3


def test_yee_model_angle_from_centre_follows_eq_2_4():
    cam = Camera.yee(512, 480, 25.8356, 20.3319)
    c = cam.K[:2, 2]
    p = c + np.array([[100.0, -80.0]])
    theta = np.arccos(cam.pixels_to_vectors(p)[0, 2])
    assert theta == pytest.approx(cam.separation_rad(c, p)[0], abs=1e-14)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(1.0, 120.0),
    st.integers(16, 4096),
    st.integers(16, 4096),
    st.floats(-0.3, 0.3),
)
def test_round_trip_property_random_pinholes(fov, w, h, k1):
    cam = Camera.pinhole(w, h, fov, D=[k1 * min(1.0, 20.0 / fov) ** 2, 0, 0, 0, 0])
    xy = grid(cam, 9)
    v = cam.pixels_to_vectors(xy)
    ok = np.isfinite(v).all(axis=1)  # NaN where this random lens folds over: no inverse
    assert ok[len(ok) // 2]  # the centre always inverts
    assert np.max(np.abs(cam.vectors_to_pixels(v[ok]) - xy[ok])) < 1e-9


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"K": np.eye(2)}, "3x3"),
        ({"K": np.diag([-1.0, 1.0, 1.0])}, "fx, fy > 0"),
        ({"D": np.zeros(3)}, "0, 4, 5, 8 or 12"),
        ({"D": [np.nan, 0, 0, 0]}, "finite"),
        ({"width": 0}, "image size"),
        ({"width": 10.5}, "image size"),
        ({"model": "fisheye"}, "model must be"),
        ({"parity": 0}, "parity"),
    ],
)
def test_bad_camera_parameters_raise(kwargs, match):
    args = {"K": np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), "D": np.zeros(5),
            "width": 640, "height": 480}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Camera(**args)
    with pytest.raises(ValueError, match="fov_x_deg"):
        Camera.pinhole(640, 480, 0.0)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        Camera.pinhole(640, 480, 10.0).pixels_to_vectors(np.zeros((3, 3)))


def test_distortion_free_fast_path_matches_the_general_model():
    """A pinhole without distortion takes an affine fast path; a negligible distortion
    coefficient forces the general one: both agree, including skew, parity and points
    behind the camera."""
    K = np.array([[900.0, 2.5, 250.0], [0.0, 910.0, 241.0], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(4)
    xy = rng.uniform(-50, 560, (300, 2))
    v = rng.normal(size=(300, 3))
    for parity in (1, -1):
        fast = Camera(K, np.zeros(5), 512, 480, parity=parity)
        general = Camera(K, np.array([1e-300, 0, 0, 0, 0]), 512, 480, parity=parity)
        np.testing.assert_allclose(fast.pixels_to_vectors(xy), general.pixels_to_vectors(xy),
                                   rtol=0, atol=1e-14)
        a, b = fast.vectors_to_pixels(v), general.vectors_to_pixels(v)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_allclose(a[~np.isnan(a)], b[~np.isnan(b)], rtol=1e-12, atol=1e-9)
