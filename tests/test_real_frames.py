"""The 8 real frames (shared/data/real-images) against astrometry.net's reference solutions."""

from __future__ import annotations

import numpy as np
import pytest
from real_frames import (
    OBS_EPOCH,
    clipped_8bit,
    corr_frames,
    corr_offsets_px,
    grid_errors_deg,
    load_frames,
    projected_stars,
)
from scipy.spatial import cKDTree

from adfusion import starid


@pytest.fixture(scope="module")
def frames(shared_dir):
    return load_frames(shared_dir)


@pytest.fixture(scope="module")
def hip6():
    return starid.Catalog.hipparcos(mag_limit=6.0, epoch=OBS_EPOCH, mag_system="Hp")


@pytest.fixture(scope="module")
def hip9():
    return starid.Catalog.hipparcos(mag_limit=9.0, epoch=OBS_EPOCH, mag_system="Hp")


def test_reference_grid_fits_a_pinhole_camera(frames):
    # the truth grid itself is consistent with our camera model: a pinhole with a fitted
    # focal length reproduces every reference direction to < 0.01° (≤ 19″ seen) (the
    # astrometry.net solution carries SIP distortion terms we do not model)
    for f in frames:
        errs = grid_errors_deg(f, f.fit.camera, f.fit.q_cam_icrs)
        assert errs.max() < 0.01, (f.name, errs.max())
        assert f.fit.camera.parity == 1
        assert f.fit.camera.fov_x_deg == pytest.approx(f.fov_x_deg, abs=0.02)


@pytest.mark.opencv
def test_detect_finds_catalogue_stars_in_real_frames(frames, hip6, hip9):
    """Issue acceptance: ≥ 90 % of the Hp < 6 stars in the frame found within 2 px, and
    most detections are catalogue stars (Hp < 9: the camera sees fainter than 6)."""
    rows = []
    for f in frames:
        det = starid.detect(f.path)
        assert det.ok, det.reason
        _, xy6 = projected_stars(f, hip6)
        assert len(xy6) >= 3
        d6, _ = cKDTree(det.xy).query(xy6)
        found = float(np.mean(d6 < 2.0))
        _, xy9 = projected_stars(f, hip9)
        d9, _ = cKDTree(xy9).query(det.xy)
        purity = float(np.mean(d9 < 2.0))
        rows.append((f.name, len(det), len(xy6), found, purity))
        assert found >= 0.90, (f.name, found)
        assert purity > 0.5, (f.name, purity)
    print("\nframe                                   det  Hp<6  found  catalogue-stars")
    for name, n, n6, found, purity in rows:
        print(f"{name:38s} {n:5d} {n6:5d} {found:6.0%} {purity:8.0%}")


@pytest.mark.opencv
def test_detect_file_and_array_agree(frames):
    import cv2

    f = frames[0]
    img = cv2.imread(str(f.path), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (768, 1024)
    a, b = starid.detect(img), starid.detect(f.path)
    np.testing.assert_array_equal(a.xy, b.xy)


@pytest.fixture(scope="module")
def real_solver():
    cat = starid.Catalog.hipparcos(mag_limit=6.5, epoch=OBS_EPOCH)
    return starid.Solver(cat, starid.Camera.pinhole(1024, 768, 11.4), fov_error_deg=0.5)


@pytest.mark.opencv
def test_lost_in_space_on_real_frames_matches_astrometry_net(frames, real_solver):
    """Issue acceptance: every frame identified from the image file and a FOV estimate of
    11.4° ± 0.5°; every grid point within 0.02° of the reference, the centre within 0.01°."""
    for f in frames:
        sol = real_solver.solve(starid.detect(f.path))
        assert sol.ok, (f.name, sol.reason)
        assert sol.p_false < 1e-6
        errs = grid_errors_deg(f, sol.camera, sol.q_cam_icrs)
        assert errs.max() < 0.02, (f.name, errs)
        assert errs[4] < 0.01, (f.name, errs[4])  # the grid's middle point is the centre
        assert sol.camera.fov_x_deg == pytest.approx(f.fit.camera.fov_x_deg, abs=0.01)


@pytest.mark.opencv
def test_the_attitude_is_the_given_cameras_frame_after_self_calibration(frames, real_solver):
    """With an uncertain FOV the solver fits the camera to each frame, but the attitude it
    reports stays that of the camera it was given: the given camera's optical axis (its
    principal point, the frame centre here) lands on astrometry.net's centre. A principal
    point fitted per frame (10–12 px off on three of these frames) turned the reported
    frame by 0.13–0.16° while the stars still fitted — a wrong attitude for any filter
    holding a fixed camera mounting."""
    from adfusion.maths import rotations as rot

    cam = real_solver.camera
    for f in frames:
        sol = real_solver.solve(starid.detect(f.path))
        assert sol.ok, (f.name, sol.reason)
        np.testing.assert_allclose(sol.camera.K[:2, 2], cam.K[:2, 2], err_msg=f.name)
        # the grid's middle point (the frame centre) through the *given* camera
        sight = rot.rotate(rot.inverse(sol.q_cam_icrs), cam.pixels_to_vectors(f.grid_xy[4:5]))
        err_arcsec = np.degrees(np.arccos(np.clip(sight[0] @ f.grid_icrs[4], -1, 1))) * 3600
        assert err_arcsec < 30.0, (f.name, err_arcsec)


@pytest.mark.opencv
def test_cli_solve_on_a_real_frame(frames, tmp_path, capsys):
    import json

    from adfusion.app.cli import main

    f = frames[2]
    out = tmp_path / "overlay.png"
    assert main(["solve", str(f.path), "--fov", "11.4", "--fov-error", "0.5", "--json",
                 "--overlay", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] and len(res["matches"]) >= 10
    ra, dec = res["ra_deg"], res["dec_deg"]
    import numpy as np

    from adfusion.maths import rotations as rot
    centre = rot.radec_to_vector(np.radians(ra), np.radians(dec))
    # the boresight is the principal point, the image centre: compare with grid point 4
    assert np.degrees(np.arccos(np.clip(centre @ f.grid_icrs[4], -1, 1))) < 0.01
    import cv2

    img = cv2.imread(str(out))
    assert img is not None and img.shape == (768, 1024, 3)


# --- issue 14: both real sets from the image and a FOV range, nothing else known -------------

# frames on which the acceptance is still short, with the reason (docs/decisions.md,
# "Checking against astrometry.net"); strict, so that a change that makes one pass shows up
# as "now good". Empty since corr.json left out astrometry.net's seven pairs that are not
# stars (shared/data/README.md): all 21 frames meet 1 px median / 3 px p95.
_SHORT: dict[str, str] = {}


@pytest.fixture(scope="module")
def hip65():
    return starid.Catalog.hipparcos(mag_limit=6.5, epoch=2020.0)


def _solve(frame, cat, fov_range, image=None):
    from adfusion.starid.detection.image import read_image

    img = read_image(frame.path) if image is None else image
    cam = starid.Camera.pinhole(frame.width, frame.height, frame.fov_x_deg)
    sol = starid.Solver(cat, cam, fov_range_deg=fov_range).solve(starid.detect(img, cam))
    off = corr_offsets_px(frame, sol.camera, sol.q_cam_icrs) if sol.ok else None
    return sol, off


@pytest.mark.opencv
def test_both_real_sets_from_a_fov_range_of_25_percent(shared_dir, hip65):
    """Every frame of both sets from the image file and FOV ±25 %: identified, never wrong
    (astrometry.net's matched stars land within 1 px median), and within 1 px median and
    3 px p95 with the fitted camera (the frames listed in _SHORT, if any, must still never
    be wrong)."""
    rows, short_now = [], []
    for f in corr_frames(shared_dir):
        sol, off = _solve(f, hip65, (0.75 * f.fov_x_deg, 1.25 * f.fov_x_deg))
        if not sol.ok:
            rows.append((f.name, None, None))
            short_now.append(f.name)
            continue
        med, p95 = float(np.median(off)), float(np.percentile(off, 95))
        rows.append((f.name, med, p95))
        assert med <= 1.0, (f.name, med, p95)  # never wrong, nor loose in the middle
        assert sol.camera.fov_x_deg == pytest.approx(f.fov_x_deg, rel=0.02)
        if p95 > 3.0:
            short_now.append(f.name)
    print("\n".join(f"{n:40s} {m if m is None else f'{m:.2f}'} {p if p is None else f'{p:.2f}'}"
                    for n, m, p in rows))
    assert set(short_now) <= set(_SHORT), rows
    assert set(short_now) == set(_SHORT), f"now good: {set(_SHORT) - set(short_now)}"


@pytest.mark.opencv
def test_real_frames_from_a_fov_range_of_5_to_40_degrees(shared_dir, hip65):
    """The 8 frames of real-images with nothing known but 5°–40° (one index for the
    camera size; the 13 cedar frames need five more, ~1 min each to build: they run in
    benchmarks/real_frames.py --fov 5:40)."""
    for f in corr_frames(shared_dir):
        if f.set != "real-images":
            continue
        sol, off = _solve(f, hip65, (5.0, 40.0))
        assert sol.ok, (f.name, sol.reason)
        assert np.median(off) <= 1.0 and np.percentile(off, 95) <= 3.0, (f.name, off)


@pytest.mark.opencv
def test_clipped_8bit_frames_identify_with_default_settings(shared_dir, hip65):
    """The same frames at 8 bits with the background clipped at 0 (black level at the
    median): the noise is measured above the clip ("censored"), not from the empty dark
    half, and every frame identified before still identifies, never wrong."""
    from adfusion.starid.detection.image import read_image

    for f in corr_frames(shared_dir):
        img = clipped_8bit(read_image(f.path))
        assert np.mean(img == 0) > 0.4
        det = starid.detect(img)
        assert det.ok and det.noise_model == "censored", (f.name, det)
        assert len(det) < 1000, (f.name, len(det))
        sol, off = _solve(f, hip65, (0.75 * f.fov_x_deg, 1.25 * f.fov_x_deg), img)
        assert sol.ok, (f.name, sol.reason)
        assert np.median(off) <= 1.0, (f.name, np.median(off))


@pytest.mark.opencv
def test_cli_solve_with_a_fov_range(shared_dir, capsys):
    import json

    from adfusion.app.cli import main

    f = next(f for f in corr_frames(shared_dir) if f.name == "orion2")
    assert main(["solve", str(f.path), "--fov", "8:13", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] and res["fov_x_deg"] == pytest.approx(f.fov_x_deg, rel=0.01)
    assert main(["solve", str(f.path), "--fov", "13:8"]) != 0
