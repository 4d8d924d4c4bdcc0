"""adfusion.starid.detection.detect against independent truth: Renken's segmentation cases (AC-09,
AC-10), synthetic
frames rendered here (pixel-integrated Gaussian stars, so the true centroid is known exactly),
input handling, and the real frames in ../shared (skipped when absent)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from adfusion.starid.detection.detect import detect
from adfusion.starid.detection.detections import Detections, Rejection
from adfusion.starid.detection.image import read_image
from adfusion.starid.detection.measure import _label
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from scipy.spatial import cKDTree
from scipy.special import erf

pytestmark = pytest.mark.opencv

# Renken's segmentation (Renken 1998 §5.2): a fixed threshold, no minimum size, no hot-pixel or
# shape filter, unweighted centroids rounded to 0.1 px.
RENKEN = dict(threshold=100, min_area=1, max_sharpness=None, max_elongation=None,
              centroid="unweighted")


# ------------------------------------------------------------------------------------------
# A small renderer: stars as pixel-integrated Gaussians, so pixel (i, j) holds the PSF's
# integral over [i - 0.5, i + 0.5] × [j - 0.5, j + 0.5] and the true centroid is (x, y).


def render(shape, stars, *, psf=1.2, background=100.0, noise=5.0, seed=0):
    """Image (float64) and its noise-free star part; stars are rows (x, y, flux)."""
    h, w = shape
    clean = np.zeros(shape)
    s2 = np.sqrt(2.0) * psf
    r = int(np.ceil(5 * psf)) + 1
    for x, y, flux in stars:
        x0, x1 = max(0, round(x) - r), min(w, round(x) + r + 1)
        y0, y1 = max(0, round(y) - r), min(h, round(y) + r + 1)
        gx = np.diff(0.5 * erf((np.arange(x0, x1 + 1) - 0.5 - x) / s2))
        gy = np.diff(0.5 * erf((np.arange(y0, y1 + 1) - 0.5 - y) / s2))
        clean[y0:y1, x0:x1] += flux * np.outer(gy, gx)
    rng = np.random.default_rng(seed)
    img = np.asarray(background, float) + clean + rng.normal(0.0, noise, shape)
    return img, clean


def star_field(rng, shape, n, *, margin=12, min_sep=14):
    """n positions, none closer than min_sep to another or margin to the edge."""
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform([margin, margin], [shape[1] - margin, shape[0] - margin])
        if all(np.hypot(*(p - q)) >= min_sep for q in pts):
            pts.append(p)
    return np.array(pts)


def flux_for_peak(peak, psf):
    """Total flux of a Gaussian star whose continuous PSF peaks at `peak`."""
    return peak * 2 * np.pi * psf**2


def pixel_peaks(clean, xy):
    """Brightest noise-free pixel within 1 px of each true position."""
    h, w = clean.shape
    out = []
    for x, y in xy:
        xi, yi = round(x), round(y)
        out.append(clean[max(yi - 1, 0): min(yi + 2, h), max(xi - 1, 0): min(xi + 2, w)].max())
    return np.array(out)


def match(det_xy, true_xy, radius=1.0):
    """(found mask over truth, offsets of found, number of detections matching no truth)."""
    if len(det_xy) == 0:
        return np.zeros(len(true_xy), bool), np.empty((0, 2)), 0
    d, i = cKDTree(det_xy).query(true_xy)
    found = d < radius
    offsets = det_xy[i[found]] - true_xy[found]
    d2, _ = cKDTree(true_xy).query(det_xy)
    return found, offsets, int(np.sum(d2 >= radius))


def rms(offsets):
    return float(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))


# ------------------------------------------------------------------------------------------
# Pixel convention


def test_single_pixel_sits_at_its_index():
    img = np.zeros((12, 20), np.uint8)
    img[7, 3] = 200  # image[y, x]
    det = detect(img, **RENKEN)
    assert det.xy.tolist() == [[3.0, 7.0]]
    assert det.flux.tolist() == [200.0] and det.area.tolist() == [1]


def test_weighted_centroid_of_a_symmetric_blob_is_its_centre():
    img = np.zeros((30, 40), np.float32)
    img[11, 19:22] = [50, 100, 50]
    img[10, 20] = img[12, 20] = 50
    det = detect(img, threshold=10, centroid="weighted")
    np.testing.assert_allclose(det.xy, [[20.0, 11.0]], atol=1e-12)


def test_fixed_threshold_centroids_ignore_the_sky_level():
    # No background is estimated with a fixed threshold; the weights are the excess over it,
    # so a sky pedestal does not pull the centroid to the middle of the blob's pixels.
    truth = np.array([[20.35, 15.8], [40.6, 30.25]])
    img, _ = render((48, 64), np.column_stack([truth, [20000.0, 20000.0]]), background=500.0,
                    noise=1.0, seed=4)
    det = detect(img, threshold=600.0)
    assert len(det) == 2
    _, off, _ = match(det.xy, truth)
    assert np.abs(off).max() < 0.03


def test_flip_maps_x_to_width_minus_one_minus_x():
    rng = np.random.default_rng(3)
    shape = (128, 160)
    xy = star_field(rng, shape, 8)
    img, _ = render(shape, np.column_stack([xy, np.full(8, 3000.0)]), seed=3)
    a = detect(img, threshold=130.0)
    b = detect(img[:, ::-1].copy(), threshold=130.0)
    assert len(a) == len(b) == 8
    np.testing.assert_allclose(b.xy[:, 0], shape[1] - 1 - a.xy[:, 0], atol=1e-9)
    np.testing.assert_allclose(b.xy[:, 1], a.xy[:, 1], atol=1e-9)


# ------------------------------------------------------------------------------------------
# Renken AC-09 (image-quality check, Cond. 5.1) and AC-10 (segmentation)


def _blobs_image(n_blobs, extra=0):
    """384×288 8-bit image with n_blobs 3-pixel blobs (grey 200) and `extra` lone pixels."""
    img = np.zeros((288, 384), np.uint8)
    for k in range(n_blobs):
        y, x = 10 + 8 * (k // 40), 5 + 9 * (k % 40)
        img[y, x: x + 3] = 200
    for k in range(extra):
        img[280, 5 + 9 * k] = 200
    return img


def test_ac09_150_bright_pixels_pass_151_fail():
    ok = detect(_blobs_image(50), max_bright_pixels=150, **RENKEN)
    assert ok.ok and ok.reason == ""
    assert ok.bright_pixels == 150 and len(ok) == 50

    bad = detect(_blobs_image(50, extra=1), max_bright_pixels=150, **RENKEN)
    assert not bad.ok
    assert len(bad) == 0 and bad.as_array().shape == (0, 3)  # number_is = 0
    assert bad.bright_pixels == 151
    assert "151" in bad.reason and "150" in bad.reason


def _pixels(coords, value=200, shape=(20, 20)):
    img = np.zeros(shape, np.uint8)
    for x, y in coords:  # (x, y), as in Renken
        img[y, x] = value
    return img


def test_ac10_diagonal_neighbours_join_a_gap_separates():
    assert len(detect(_pixels([(5, 5), (6, 6)]), **RENKEN)) == 1
    assert len(detect(_pixels([(5, 6), (6, 5)]), **RENKEN)) == 1
    assert len(detect(_pixels([(5, 5), (7, 5)]), **RENKEN)) == 2
    assert len(detect(_pixels([(5, 5), (7, 7)]), **RENKEN)) == 2


def test_ac10_unweighted_centroid_rounded_to_a_tenth():
    det = detect(_pixels([(10, 10), (11, 10), (10, 11)]), **RENKEN)
    assert det.xy.tolist() == [[10.3, 10.3]]
    assert det.area.tolist() == [3] and det.flux.tolist() == [600.0]


def test_ac10_sorted_by_grey_value_sum_single_pixels_kept():
    img = np.zeros((30, 30), np.uint8)
    img[3, 3] = 250  # brightest pixel, smallest sum: 250
    img[10, 10:12] = 150  # sum 300
    img[20, 20:23] = 120  # sum 360
    det = detect(img, **RENKEN)
    assert det.flux.tolist() == [360.0, 300.0, 250.0]
    assert det.xy.tolist() == [[21.0, 20.0], [10.5, 10.0], [3.0, 3.0]]
    assert det.area.tolist() == [3, 2, 1]
    assert det.peak.tolist() == [120.0, 150.0, 250.0]


def test_ac10_v_shaped_blob_is_one_star():
    det = detect(_pixels([(1, 1), (3, 1), (2, 2)]), **RENKEN)
    assert len(det) == 1
    assert det.xy.tolist() == [[2.0, 1.3]]


def test_equal_fluxes_come_in_scan_order():
    det = detect(_pixels([(15, 4), (4, 9), (9, 4)]), **RENKEN)
    assert det.xy.tolist() == [[9.0, 4.0], [15.0, 4.0], [4.0, 9.0]]


def test_binary_image_with_threshold_zero():
    img = _pixels([(2, 2), (3, 2), (12, 15)], value=1)
    det = detect(img, **{**RENKEN, "threshold": 0})
    assert det.xy.tolist() == [[2.5, 2.0], [12.0, 15.0]]


@settings(max_examples=60, deadline=None)
@given(
    h=st.integers(1, 40),
    w=st.integers(1, 40),
    density=st.floats(0.02, 0.6),
    seed=st.integers(0, 2**31),
)
def test_labels_number_components_in_scan_order(h, w, density, seed):
    """The partition of scipy's labelling, and its numbering: by each component's first
    pixel in row-major order (the ring centroid breaks ties between blobs by label)."""
    mask = np.random.default_rng(seed).random((h, w)) < density
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return
    n, lab = _label(mask, idx)
    ref, n_ref = ndimage.label(mask, structure=np.ones((3, 3), int))
    assert n == n_ref
    assert (lab + 1).tolist() == ref.ravel()[idx].tolist()


@settings(max_examples=80, deadline=None)
@given(
    h=st.integers(1, 70),
    w=st.integers(1, 70),
    dtype=st.sampled_from(["uint8", "uint16", "int16", "float32", "float64"]),
    kind=st.sampled_from(["flat", "noise", "sparse", "tiny"]),
    fixed=st.booleans(),
    block=st.integers(4, 48),
    seed=st.integers(0, 2**31),
)
def test_any_small_image_gives_valid_detections(h, w, dtype, kind, fixed, block, seed):
    rng = np.random.default_rng(seed)
    img = {"flat": np.full((h, w), 17.0), "noise": rng.normal(100, 5, (h, w)),
           "sparse": rng.integers(0, 3, (h, w)) * 50.0,
           "tiny": rng.normal(0, 1e-3, (h, w)) + 1}[kind]
    if np.dtype(dtype).kind in "ui":
        img = np.clip(np.round(img), 0, None)
    det = detect(img.astype(dtype), threshold=50.0 if fixed else None, background_block=block)
    assert det.ok and det.xy.shape == (len(det), 2)
    assert len(det.flux) == len(det.area) == len(det.peak) == len(det)
    if len(det):
        assert np.all(np.isfinite(det.xy))
        assert np.all((det.xy >= -0.5) & (det.xy <= np.array([w, h]) - 0.5))
        assert np.all(np.diff(det.flux) <= 0) and np.all(det.area >= 2)


# ------------------------------------------------------------------------------------------
# Synthetic frames


SHAPE = (384, 512)


def _frame(seed, n, peak_range, *, psf=1.2, noise=5.0, background=100.0):
    rng = np.random.default_rng(seed)
    xy = star_field(rng, SHAPE, n)
    peaks = rng.uniform(*peak_range, n) * noise
    stars = np.column_stack([xy, flux_for_peak(peaks, psf)])
    img, clean = render(SHAPE, stars, psf=psf, background=background, noise=noise, seed=seed)
    return img, clean, xy


def test_centroids_of_bright_stars_within_005_px():
    offsets = []
    for seed in (1, 2):
        img, _, xy = _frame(seed, 40, (100, 400))
        found, off, false = match(detect(img.astype(np.float32)).xy, xy)
        assert found.all() and false == 0
        offsets.append(off)
    off = np.concatenate(offsets)
    assert rms(off) < 0.05, rms(off)
    assert np.abs(off.mean(axis=0)).max() < 0.01  # no bias


def test_centroids_of_moderate_stars_within_02_px():
    offsets = []
    for seed in (3, 4, 5):
        img, _, xy = _frame(seed, 40, (12, 25))
        found, off, false = match(detect(img.astype(np.float32)).xy, xy)
        assert found.mean() > 0.95 and false == 0
        offsets.append(off)
    off = np.concatenate(offsets)
    assert rms(off) < 0.2, rms(off)
    assert np.abs(off.mean(axis=0)).max() < 0.03


@pytest.mark.parametrize("psf", [1.0, 1.5])
def test_every_star_with_an_8_sigma_pixel_is_found(psf):
    n_bright = 0
    for seed in (6, 7, 8):
        img, clean, xy = _frame(seed, 60, (3, 16), psf=psf)
        found, _, false = match(detect(img.astype(np.float32)).xy, xy, radius=1.5)
        bright = pixel_peaks(clean, xy) >= 8 * 5.0
        n_bright += bright.sum()
        assert found[bright].all(), np.flatnonzero(bright & ~found)
        assert false == 0
    assert n_bright > 50


def test_pure_noise_gives_no_detections():
    false = 0
    for seed in range(4):
        img = np.random.default_rng(seed).normal(1000.0, 10.0, (512, 512)).astype(np.float32)
        det = detect(img)
        false += len(det)
        assert det.noise_sigma == pytest.approx(10.0, rel=0.05)
        assert det.background_level == pytest.approx(1000.0, abs=0.5)
    assert false <= 1


def test_gradient_and_intensifier_glow_are_background():
    """A ramp of 50 sigma across the frame plus a 100-sigma glow of 70 px radius (an image
    intensifier's hot spot): no false detections, no lost 8-sigma star."""
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]].astype(float)
    noise = 5.0
    bg = (500.0 + 50 * noise * xx / SHAPE[1]
          + 100 * noise * np.exp(-((xx - 300) ** 2 + (yy - 200) ** 2) / (2 * 70.0**2)))
    for seed in (9, 10):
        rng = np.random.default_rng(seed)
        xy = star_field(rng, SHAPE, 50)
        stars = np.column_stack([xy, flux_for_peak(rng.uniform(8, 40, 50) * noise, 1.2)])
        img, clean = render(SHAPE, stars, background=bg, noise=noise, seed=seed)
        det = detect(img.astype(np.float32))
        found, off, false = match(det.xy, xy)
        assert false == 0
        assert found[pixel_peaks(clean, xy) >= 8 * noise].all()
        assert rms(off) < 0.15


def test_hot_pixels_are_rejected_as_hot_pixels():
    img, _, xy = _frame(11, 30, (20, 60))
    rng = np.random.default_rng(11)
    hot = star_field(rng, SHAPE, 10, min_sep=1)
    hot = hot[cKDTree(xy).query(hot)[0] > 10].round().astype(int)
    img[hot[:, 1], hot[:, 0]] += 1000.0  # 200 sigma, one pixel each
    for min_area in (1, 2):
        det = detect(img.astype(np.float32), min_area=min_area)
        found, _, false = match(det.xy, xy)
        assert found.all() and false == 0  # no hot pixel among the detections
        rejected = {(round(r.x), round(r.y)): r for r in det.rejected}
        for x, y in hot:
            r = rejected[(x, y)]
            assert r.reason == "hot_pixel" and r.area == 1
            assert isinstance(r, Rejection) and tuple(r)[3] == "hot_pixel"


def test_a_tether_line_is_rejected_as_elongated():
    img, _, xy = _frame(12, 25, (20, 60))
    keep = np.abs(xy[:, 1] - (0.3 * xy[:, 0] + 50)) > 8  # stars clear of the line
    line_x = np.arange(150, 350)
    img[np.round(0.3 * line_x + 50).astype(int), line_x] += 400.0  # 80 sigma, 1 px wide
    det = detect(img.astype(np.float32))
    assert match(det.xy, xy[keep])[0].all()
    assert match(det.xy, xy)[2] == 0  # nothing but stars; the line is gone
    elongated = [r for r in det.rejected if r.reason == "elongated"]
    assert len(elongated) == 1 and elongated[0].area >= 150
    assert 150 < elongated[0].x < 350


def test_saturated_and_too_large_blobs():
    img, _, _ = _frame(13, 10, (200, 400))
    top = float(np.percentile(img, 99.9))
    clipped = np.minimum(img, top).astype(np.float32)
    assert len(detect(clipped)) == 10  # kept by default
    det = detect(clipped, saturation=top)
    sat = [r for r in det.rejected if r.reason == "saturated"]
    assert len(sat) + len(det) == 10 and len(sat) > 0
    small = detect(img.astype(np.float32), max_area=4)
    assert {r.reason for r in small.rejected} >= {"too_large"}


def test_same_values_in_any_dtype_give_the_same_detections():
    img, _, _ = _frame(14, 30, (8, 40), noise=3.0, background=40.0)
    u8 = np.clip(np.round(img), 0, 255).astype(np.uint8)
    ref = detect(u8)
    assert len(ref) >= 25
    for dt in (np.uint16, np.int16, np.float32, np.float64, np.int32):
        d = detect(u8.astype(dt))
        np.testing.assert_array_equal(d.xy, ref.xy, err_msg=str(dt))
        np.testing.assert_array_equal(d.flux, ref.flux)
    assert ref.noise_sigma == pytest.approx(3.0, rel=0.1)  # 8-bit levels, interpolated

    # 12-bit data stored as multiples of 16 in 16 bits (like the real frames): compared as
    # integers, the threshold may move by one grey level; the stars do not.
    u16 = (np.clip(np.round(img * 8), 0, 4095).astype(np.uint16) * 16)
    a, b = detect(u16), detect(u16.astype(np.float32))
    assert abs(len(a) - len(b)) <= 1
    found, off, _ = match(a.xy, b.xy, radius=0.5)
    assert found.mean() > 0.95 and np.abs(off).max() < 0.02


def test_nan_and_inf_pixels_are_missing():
    img, _, xy = _frame(15, 30, (20, 60))
    img = img.astype(np.float32)
    clean = detect(img)
    holed = img.copy()
    holed[200:230, 40:70] = np.nan  # a dead patch
    holed[5, 5] = np.inf
    holed[100, 300] = -np.inf
    before = holed.copy()
    det = detect(holed)
    np.testing.assert_array_equal(np.isnan(holed), np.isnan(before))  # input untouched
    assert not np.any((det.xy[:, 0] > 38) & (det.xy[:, 0] < 71)
                      & (det.xy[:, 1] > 198) & (det.xy[:, 1] < 231))
    away = ~((xy[:, 0] > 30) & (xy[:, 0] < 80) & (xy[:, 1] > 190) & (xy[:, 1] < 240))
    found, _, false = match(det.xy, xy[away])
    assert found.all() and false == 0
    _, off, _ = match(det.xy, clean.xy)
    assert np.abs(off).max() < 0.02


def test_h_w_1_array_and_max_detections():
    img, _, _ = _frame(16, 20, (20, 60))
    img = img.astype(np.float32)
    full = detect(img)
    np.testing.assert_array_equal(detect(img[:, :, None]).xy, full.xy)
    top5 = detect(img, max_detections=5)
    np.testing.assert_array_equal(top5.xy, full.xy[:5])
    assert np.all(np.diff(full.flux) <= 0)  # brightest first


def test_detections_api():
    det = detect(_pixels([(2, 2), (3, 2), (12, 15)]), **RENKEN)
    assert isinstance(det, Detections) and len(det) == 2
    arr = det.as_array()
    assert arr.shape == (2, 3) and arr.dtype == np.float64
    np.testing.assert_array_equal(arr[:, :2], det.xy)
    np.testing.assert_array_equal(arr[:, 2], det.flux)
    assert det.shape == (20, 20) and det.ok and det.reason == ""
    with pytest.raises(dataclasses.FrozenInstanceError):
        det.ok = False  # type: ignore[misc]
    empty = detect(np.zeros((8, 8), np.uint8), **RENKEN)
    assert len(empty) == 0 and empty.ok and empty.as_array().shape == (0, 3)
    assert repr(det).startswith("Detections(2 stars, ok, 0 rejected")


def test_camera_shape_is_checked():
    img = np.zeros((48, 64), np.uint8)
    assert len(detect(img, SimpleNamespace(width=64, height=48), **RENKEN)) == 0
    with pytest.raises(ValueError, match="camera"):
        detect(img, SimpleNamespace(width=48, height=64), **RENKEN)


# ------------------------------------------------------------------------------------------
# Files


@pytest.mark.parametrize(
    "suffix, dtype, scale",
    [(".png", np.uint8, 1), (".png", np.uint16, 100), (".tiff", np.uint16, 100),
     (".tiff", np.float32, 1)],
)
def test_file_round_trip(tmp_path, suffix, dtype, scale):
    img, _, _ = _frame(17, 20, (20, 60), noise=3.0, background=40.0)
    top = np.iinfo(dtype).max if np.dtype(dtype).kind == "u" else None
    arr = np.clip(np.round(img * scale), 0, top).astype(dtype)
    path = tmp_path / f"frame{suffix}"
    assert cv2.imwrite(str(path), arr)
    back = read_image(path)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, arr)
    ref = detect(arr)
    for p in (path, str(path)):
        np.testing.assert_array_equal(detect(p).xy, ref.xy)


def test_colour_and_jpeg_files_become_grey(tmp_path):
    img, _, xy = _frame(18, 20, (40, 100), noise=3.0, background=40.0)
    u8 = np.clip(np.round(img), 0, 255).astype(np.uint8)
    ref = detect(u8)
    path = tmp_path / "colour.png"
    cv2.imwrite(str(path), np.dstack([u8, u8, u8]))
    np.testing.assert_array_equal(detect(path).xy, ref.xy)
    jpg = tmp_path / "frame.jpg"
    cv2.imwrite(str(jpg), u8, [cv2.IMWRITE_JPEG_QUALITY, 95])
    found, off, _ = match(detect(jpg).xy, xy)
    assert found.mean() > 0.9 and rms(off) < 0.2


# ------------------------------------------------------------------------------------------
# Bad input


@pytest.mark.parametrize(
    "image, error, message",
    [
        (np.zeros((0, 0)), ValueError, "empty"),
        (np.zeros((5, 0), np.uint8), ValueError, "empty"),
        (np.zeros(10), ValueError, "2-D"),
        (np.zeros((2, 3, 4, 5)), ValueError, "2-D"),
        (np.zeros((8, 8, 3), np.uint8), ValueError, "colour"),
        (np.zeros((8, 8), bool), TypeError, "bool"),
        (np.zeros((8, 8), complex), TypeError, "complex"),
        (np.zeros((8, 8), object), TypeError, "object"),
        (np.full((8, 8), np.nan), ValueError, "finite"),
        (np.full((8, 8), np.inf, np.float32), ValueError, "finite"),
        ([[1, 2], [3, 4]], TypeError, "numpy array or a file path"),
    ],
)
def test_bad_images_raise_and_say_why(image, error, message):
    with pytest.raises(error, match=message):
        detect(image)


def test_bad_files_raise_and_name_the_path(tmp_path):
    missing = tmp_path / "nope.tiff"
    with pytest.raises(FileNotFoundError, match=r"nope\.tiff"):
        detect(missing)
    junk = tmp_path / "junk.png"
    junk.write_text("not an image")
    with pytest.raises(ValueError, match=r"cannot read.*junk\.png"):
        detect(str(junk))
    with pytest.raises(ValueError, match="not a file"):
        detect(tmp_path)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"sigma": 0}, "sigma"),
        ({"sigma": float("nan")}, "sigma"),
        ({"min_area": 0}, "min_area"),
        ({"min_area": 5, "max_area": 4}, "max_area"),
        ({"centroid": "median"}, "centroid"),
        ({"background_block": 2}, "background_block"),
        ({"max_sharpness": 1.5}, "max_sharpness"),
        ({"max_elongation": 0.5}, "max_elongation"),
        ({"threshold": float("inf")}, "threshold"),
        ({"max_bright_pixels": -1}, "max_bright_pixels"),
    ],
)
def test_bad_parameters_raise(kwargs, message):
    with pytest.raises(ValueError, match=message):
        detect(np.zeros((16, 16), np.uint8), **kwargs)


# ------------------------------------------------------------------------------------------
# Real frames (../shared/data/real-images)


@pytest.fixture(scope="module")
def real_frames(shared_dir):
    paths = sorted((shared_dir / "data" / "real-images").glob("*.tiff"))
    if not paths:
        pytest.skip("no real frames in shared/data/real-images")
    return paths


@pytest.mark.shared
def test_real_frames(real_frames: list[Path]):
    counts = {}
    fixed = {}
    for path in real_frames:
        arr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert arr.dtype == np.uint16 and arr.shape == (768, 1024)
        det = detect(path)
        assert det.ok and len(det) >= 15, (path.name, len(det))
        from_array = detect(arr)
        np.testing.assert_array_equal(from_array.xy, det.xy)
        np.testing.assert_array_equal(from_array.flux, det.flux)
        assert np.all(np.diff(det.flux) <= 0)
        counts[path.stem] = (len(det), len(det.rejected))
        for x, y in det.xy:
            fixed[(round(x), round(y))] = fixed.get((round(x), round(y)), 0) + 1
    # The frames point at different sky: a detection at the same pixel in 3 or more of them
    # would be a hot pixel that slipped through.
    assert max(fixed.values()) < 3
    print("\nframe: detections (rejected blobs)")
    for name, (n, n_rej) in counts.items():
        print(f"  {name}: {n} ({n_rej})")


def test_histogram_quantiles_equal_the_sorted_ones():
    """Integer data on few grey levels take a counting path in the background estimate; it
    must give exactly what sorting gives (order statistics and the in-level interpolation),
    for 8/16-bit and signed residual data, on or off a 16-level lattice."""
    import importlib

    det = importlib.import_module("adfusion.starid.detection.background")
    rng = np.random.default_rng(0)
    for _ in range(200):
        rows, n = int(rng.integers(1, 40)), int(rng.choice([5, 64, 127, 128, 129, 256]))
        step = int(rng.choice([0, 1, 16]))
        data = rng.poisson(rng.uniform(1, 60), (rows, n)) * max(step, 1)
        dtype = rng.choice([np.uint8, np.uint16, np.int32])
        if dtype == np.int32:
            data -= int(rng.integers(0, 100)) * max(step, 1)
        data = data.astype(dtype)
        for interpolate_lo in (True, False):
            fast = det._quantiles(data.copy(), step, interpolate_lo)
            saved = det._HIST_MAX_LEVELS, det._SIMD_SORT16
            det._HIST_MAX_LEVELS, det._SIMD_SORT16 = 0, False  # force the plain sort
            try:
                slow = det._quantiles(data.copy(), step, interpolate_lo)
            finally:
                det._HIST_MAX_LEVELS, det._SIMD_SORT16 = saved
            np.testing.assert_array_equal(fast[0], slow[0])
            np.testing.assert_array_equal(fast[1], slow[1])



def test_the_int16_sort_gives_the_histograms_quantiles():
    """The shifted uint16 sort (the fast path where numpy has a SIMD 16-bit sort) gives
    exactly the histogram's order statistics and in-level interpolation — also for data
    whose shift wraps around 2¹⁶ (uint16 near 65535, int32 far from 0)."""
    from adfusion.starid.detection.background import _quantiles_by_histogram, _quantiles_by_sort16

    rng = np.random.default_rng(3)
    for base, dtype in ((0, np.uint8), (60000, np.uint16), (-100000, np.int32),
                        (2**30, np.int32), (-3, np.int8)):
        for n in (5, 127, 128, 256):
            data = (rng.poisson(rng.uniform(2, 60), (20, n)) + base).astype(dtype)
            if dtype not in (np.uint8, np.int8):
                data[0, :3] -= 50000  # a 50000-level span: still within uint16 after the shift
            first, last = int(data.min()), int(data.max())
            k_med = (n - 1) // 2
            k_lo = round(0.1587 * (n - 1))
            for step in (0, 1):
                for interp in (False, True):
                    got = _quantiles_by_sort16(data.copy(), first, k_lo, k_med, step, interp)
                    ref = _quantiles_by_histogram(data.copy(), first, last - first + 1, k_lo,
                                                  k_med, step, interp)
                    for g, r in zip(got, ref, strict=True):
                        np.testing.assert_array_equal(g, r)

# --- issue 14 item 1 and issue 16 item 11: frames from real sensors -------------------------


def test_a_mostly_nan_frame_is_not_ok():
    """Issue 16 #11: a 99.9 % NaN frame gave thousands of "stars" from the few finite pixels
    (noise measured as 0) with ok=True."""
    img, _, _ = _frame(21, 30, (20, 60))
    img = img.astype(np.float64)
    img[np.random.default_rng(0).random(img.shape) < 0.999] = np.nan
    det = detect(img)
    assert not det.ok and len(det) == 0
    assert "finite pixels" in det.reason


def test_a_float64_frame_keeps_its_precision_at_a_large_offset():
    """Issue 16 #11: the maps were float32, so an offset of 1e12 (float32 spacing 65536) lost
    every star; the frame is now measured relative to its median."""
    img, _, _ = _frame(22, 40, (20, 100))
    ref = detect(img.astype(np.float64))
    det = detect(img.astype(np.float64) + 1e12)
    assert len(ref) >= 38
    assert len(det) == len(ref)
    np.testing.assert_allclose(det.xy, ref.xy, atol=1e-6)
    assert det.background_level == pytest.approx(1e12 + ref.background_level, abs=1e-3)


def _clipped(img):
    """8 bits, the black level at the median: half the sky is 0."""
    a = np.round(img).astype(np.int64)
    return np.clip(a - int(np.median(a)), 0, 255).astype(np.uint8)


def test_a_clipped_background_gives_the_noise_from_above_the_clip():
    """Issue 14 #1: with the dark half of the sky clipped at 0 the lower-half spread is 0 and
    the threshold sat in the noise (thousands of "stars"); the censored estimate measures
    σ from the quantiles above the clip, and the same stars come out."""
    img, _, xy = _frame(23, 40, (15, 60), noise=1.5, background=20.0)
    det = detect(_clipped(img))
    assert det.ok and det.noise_model == "censored"
    assert det.noise_sigma == pytest.approx(1.5, rel=0.2)
    found, _, false = match(det.xy, xy)
    assert found.mean() >= 0.9 and false <= 2, (found.mean(), false)
    assert detect(np.round(img).astype(np.uint8)).noise_model == "lower-half"


def test_an_absurd_number_of_blobs_is_an_unreliable_threshold():
    """A threshold in the noise (here sigma=1 on white noise) is reported, not returned as
    tens of thousands of stars."""
    img = np.random.default_rng(4).normal(100.0, 3.0, (600, 800)).astype(np.float32)
    det = detect(img, sigma=1.0, min_area=1, max_sharpness=None, max_elongation=None)
    assert not det.ok and len(det) == 0
    assert det.reason.startswith("unreliable threshold")
    assert detect(img).ok  # the default 5σ finds (almost) nothing, correctly


def test_matched_filter_finds_fainter_stars():
    """The PSF-matched filter lifts stars at a peak of ~2.5σ above the threshold that single
    pixels miss at the same false-detection level."""
    img, _, xy = _frame(24, 40, (2.0, 3.0), psf=1.5)
    plain = match(detect(img.astype(np.float32)).xy, xy)
    mf_det = detect(img.astype(np.float32), matched_filter=1.5)
    mf = match(mf_det.xy, xy)
    assert mf_det.noise_model == "lower-half+matched-filter"
    assert mf[0].mean() >= plain[0].mean() + 0.3, (plain[0].mean(), mf[0].mean())
    assert mf[2] <= 3
    with pytest.raises(ValueError, match="matched_filter"):
        detect(img, matched_filter=0.0)


def test_foreground_clutter_comes_after_the_sky_stars():
    """Bright, crowded blobs on a noisy foreground (a lit tree) no longer lead the list: the
    stars on clean sky come first."""
    img, _, xy = _frame(25, 15, (30, 60), noise=2.0, background=20.0)
    rng = np.random.default_rng(5)
    tree = np.zeros_like(img)
    tree[:, 400:] = rng.gamma(0.3, 40.0, (img.shape[0], img.shape[1] - 400))
    tree = cv2.GaussianBlur(tree.astype(np.float32), (0, 0), 1.0) * 4.0
    frame = img + tree
    sky = xy[:, 0] < 390
    plain = detect(frame.astype(np.float32), clutter_noise_factor=None)
    det = detect(frame.astype(np.float32))
    n_sky = int(sky.sum())
    lead = det.xy[:n_sky]
    assert np.mean(lead[:, 0] < 395) >= 0.9
    assert np.mean(plain.xy[:n_sky, 0] < 395) < 0.9  # without it the tree leads


def test_diffuse_blobs_come_after_the_stars():
    """Blobs far broader than the stars (lit leaves, a roof's texture, a coma) with more
    flux than the stars no longer lead the list — on clean sky, where the clutter test
    (local noise and crowding) does not see them; a saturated star (flat top, as broad)
    keeps its place."""
    img, _, xy = _frame(26, 15, (30, 60), noise=2.0, background=20.0)
    rng = np.random.default_rng(6)
    blobs = rng.uniform([40, 40], [SHAPE[1] - 40, SHAPE[0] - 40], (10, 2))
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    extra = np.zeros_like(img, dtype=np.float64)
    for bx, by in blobs:  # peak 12σ, σ 6 px: ~20× a star's flux/peak, and brighter
        extra += 24.0 * np.exp(-((xx - bx) ** 2 + (yy - by) ** 2) / (2 * 6.0**2))
    sat_xy = (xy[0] + 0.3).round().astype(int)
    frame = img + extra
    frame[sat_xy[1] - 2: sat_xy[1] + 3, sat_xy[0] - 2: sat_xy[0] + 3] = 2000.0  # saturated
    frame = frame.astype(np.float32)
    plain = detect(frame, max_diffuseness=None)
    det = detect(frame)
    n = len(xy)
    near_star = lambda p: np.min(np.hypot(*(xy - p).T)) < 3.0  # noqa: E731
    assert np.mean([near_star(p) for p in plain.xy[:n]]) < 0.5  # without it the blobs lead
    assert np.mean([near_star(p) for p in det.xy[:n]]) >= 0.9
    assert np.hypot(*(det.xy[0] - sat_xy)) < 1.0  # the saturated star is still first
    assert len(det) == len(plain)  # reordered, nothing dropped
    with pytest.raises(ValueError, match="max_diffuseness"):
        detect(frame, max_diffuseness=1.0)


def test_the_clipped_histogram_gives_the_full_histograms_quantiles():
    """The background's quantiles from a histogram clipped to where nearly all samples lie
    are exactly those of the full range and of a plain sort — also for a row (a glow, a
    dark corner) whose statistics fall on a clipped end and are recomputed."""
    from adfusion.starid.detection.background import (
        _quantiles,
        _quantiles_by_clipped_histogram,
        _quantiles_by_histogram,
    )

    rng = np.random.default_rng(7)

    def check(s):
        n = s.shape[1]
        k_med = (n - 1) // 2
        k_lo = round(0.1587 * (n - 1))
        first, last = int(s.min()), int(s.max())
        for interp in (False, True):
            got = _quantiles_by_clipped_histogram(s.copy(), first, last, k_lo, k_med, 1.0,
                                                  interp)
            full = _quantiles_by_histogram(s.copy(), first, last - first + 1, k_lo, k_med,
                                           1.0, interp)
            ref = _quantiles(s.astype(np.float64), 1.0, interp)  # the sort path
            for g, f, r in zip(got, full, ref, strict=True):
                np.testing.assert_array_equal(g, f)
                np.testing.assert_allclose(g, r, rtol=0, atol=1e-12)
        return got

    def frame(rows, dtype):
        v = rng.normal(rng.uniform(20, 120), rng.uniform(0.7, 5), (rows, 256))
        stars = rng.random(v.shape) < 0.03
        v[stars] += rng.uniform(30, 300, stars.sum())
        v[rng.random(v.shape) < 0.01] = 0  # dead pixels
        return v

    for dtype in (np.uint8, np.int32):
        for _ in range(30):
            v = frame(int(rng.integers(3, 40)), dtype)
            v[0] += 90.0  # a glow
            v[1] -= 60.0  # a dark corner
            s = np.clip(np.round(v), 0, 255).astype(dtype)
            check(s - int(np.median(s)) if dtype is np.int32 else s)
    # one glow row among many: beyond the range the clip keeps, so it is recomputed
    v = frame(800, np.int32)
    v[0] += 600.0
    s = np.round(v).astype(np.int32) - 60
    _, med = check(s)
    sub = s.ravel()[::37]
    top = np.sort(sub)[int(0.998 * (sub.size - 1))]
    assert med[0] > top + 2 and med[0] == pytest.approx(np.median(s[0]), abs=1.0)


def test_the_lower_quartile_is_numpys_percentile():
    """The diffuse-blob reference quartile, computed without np.percentile's overhead, is
    exactly np.percentile(v, 25) (linear) for 1-30 values of any scale, NaN included."""
    from adfusion.starid.detection.detect import _lower_quartile

    rng = np.random.default_rng(11)
    for _ in range(2000):
        v = rng.lognormal(1, 1, int(rng.integers(1, 31))) * 10 ** rng.uniform(-3, 3)
        assert _lower_quartile(v) == float(np.percentile(v, 25))
    v = np.array([1.0, np.nan, 3.0])
    assert np.isnan(_lower_quartile(v)) and np.isnan(np.percentile(v, 25))


def test_the_small_median_is_numpys_median():
    """The grids' median, computed without np.median's overhead, is exactly
    float(np.median(v)) for float32/float64/integer arrays of odd and even size, NaN too."""
    from adfusion.starid.detection.background import _median

    rng = np.random.default_rng(12)
    for _ in range(3000):
        n = int(rng.integers(1, 300))
        dtype = rng.choice([np.float32, np.float64, np.uint8, np.uint16, np.int32])
        v = rng.normal(100, 30, n).clip(0, 255).astype(dtype).reshape(1, -1)
        assert _median(v) == float(np.median(v))
    v = np.array([[1.0, np.nan], [3.0, 4.0]], np.float32)
    assert np.isnan(_median(v)) and np.isnan(np.median(v))
