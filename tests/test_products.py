"""Products of `adfusion solve` (JSON, FITS WCS, correspondence table), batch solving,
camera files, and `adfusion calibrate` — against astropy, OpenCV and the real frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from adfusion.starid.camera.files import read_camera_yaml, write_camera_yaml
from adfusion.starid.camera.wcs import camera_wcs, wcs_header

from adfusion import starid
from adfusion.app.cli import main
from adfusion.maths import rotations as rot

astropy_wcs = pytest.importorskip("astropy.wcs")
fits = pytest.importorskip("astropy.io.fits")

DISTORTED = starid.Camera(np.array([[2600.0, 0.4, 530.0], [0, 2590.0, 370.0], [0, 0, 1]]),
                          [-0.25, 0.08, 1e-3, -2e-3, 0.01], 1024, 768)


def _sky(cam, q, xy):
    return rot.rotate(rot.inverse(q), cam.pixels_to_vectors(xy))


@pytest.mark.parametrize("cam", [starid.Camera.pinhole(1024, 768, 11.4), DISTORTED,
                                 DISTORTED.mirrored(),
                                 starid.Camera.pinhole(1920, 1080, 20.3)])
def test_wcs_header_reproduces_the_camera_through_astropy(cam, tmp_path):
    q = rot.q_cam_icrs_from_radec_roll(*np.radians([359.0, 80.0, 123.0]))  # near RA 0, pole
    path = tmp_path / "x.wcs"
    fits.PrimaryHDU(header=wcs_header(cam, q)).writeto(path)
    w = astropy_wcs.WCS(fits.getheader(path))  # what a FITS reader gets back
    xy = np.random.default_rng(0).uniform([0, 0], [cam.width - 1, cam.height - 1], (300, 2))
    r = _sky(cam, q, xy)
    ra, dec = rot.vector_to_radec(r)
    back = np.stack(w.all_world2pix(np.degrees(ra) % 360, np.degrees(dec), 0), -1)
    assert np.max(np.linalg.norm(back - xy, axis=1)) < 0.02
    sky = np.radians(w.all_pix2world(xy, 0))
    ang = np.arccos(np.clip(np.sum(rot.radec_to_vector(sky[:, 0], sky[:, 1]) * r, 1), -1, 1))
    assert np.max(ang) / cam.pixel_scale_rad < 0.02
    assert ("SIP" in w.wcs.ctype[0]) == bool(np.any(cam.D))


def test_wcs_refuses_the_angular_models():
    with pytest.raises(ValueError, match="pinhole"):
        camera_wcs(starid.Camera.renken(), [1.0, 0, 0, 0])


def test_camera_yaml_round_trip_and_foreign_files(tmp_path):
    p = tmp_path / "cam.yaml"
    write_camera_yaml(DISTORTED.mirrored(), p, comment="t", rms_px=0.2)
    assert read_camera_yaml(p) == DISTORTED.mirrored()
    # as OpenCV's calibration sample writes it (no keys of ours)
    opencv = tmp_path / "out_camera_data.yml"
    opencv.write_text("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n"
                      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                      "   data: [ 500., 0., 319.5, 0., 501., 239.5, 0., 0., 1. ]\n"
                      "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n"
                      "   dt: d\n   data: [ -0.1, 0.01, 0., 0., 0. ]\n")
    c = read_camera_yaml(opencv)
    assert (c.width, c.height, c.K[1, 1], c.D[0], c.parity) == (640, 480, 501.0, -0.1, 1)
    ros = tmp_path / "ros.yaml"
    ros.write_text("image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n"
                   "  cols: 3\n  data: [500, 0, 319.5, 0, 500, 239.5, 0, 0, 1]\n"
                   "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n"
                   "  cols: 5\n  data: [0.1, 0, 0, 0, 0]\n")
    assert read_camera_yaml(ros).D.tolist() == [0.1, 0, 0, 0, 0]
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: 640\n")
    with pytest.raises(ValueError, match="image_height"):
        read_camera_yaml(bad)


def test_batch_solve_of_a_folder_writes_every_product(tmp_path, capsys):
    import cv2

    from adfusion.app import examples

    imgs = tmp_path / "frames"
    imgs.mkdir()
    frames = [examples.example_frame(ra_deg=ra, seed=s) for ra, s in ((10.0, 1), (40.0, 2))]
    for k, ex in enumerate(frames):
        assert cv2.imwrite(str(imgs / f"f{k}.png"), ex.image)
    (imgs / "notes.txt").write_text("not an image")
    out = tmp_path / "out"
    assert main(["solve", str(imgs), "--fov", "15", "-o", str(out), "--wcs", "--corr"]) == 0
    text = capsys.readouterr().out
    assert "2 image(s): 2 solved, 0 not" in text and "f0.png" in text
    for k, ex in enumerate(frames):
        rec = json.loads((out / f"f{k}.json").read_text())
        assert rec["ok"] and rec["image"] == f"f{k}.png"
        err = np.degrees(rot.angle_between(np.array(rec["q_cam_icrs"]), ex.q_cam_icrs)) * 3600
        assert err < 10
        # every match: the detection's pixel, and the catalogue star's sky position, which
        # the true attitude puts within a pixel of it
        m = rec["matches"]
        xy = np.array([[r["x"], r["y"]] for r in m])
        r = rot.radec_to_vector(np.radians([r["ra_deg"] for r in m]),
                                np.radians([r["dec_deg"] for r in m]))
        assert np.all(np.linalg.norm(ex.camera.vectors_to_pixels(rot.rotate(ex.q_cam_icrs, r))
                                     - xy, axis=1) < 1.0)
        assert all(np.isfinite(r["mag"]) and r["mag"] < 6.5 for r in m)
        # the table holds the same rows; the WCS header maps the stars onto their pixels
        t = fits.getdata(out / f"f{k}.corr", 1)
        assert t["INDEX_ID"].tolist() == [r["id"] for r in m]
        np.testing.assert_allclose(t["FIELD_X"], xy[:, 0])
        w = astropy_wcs.WCS(fits.getheader(out / f"f{k}.wcs"))
        pix = np.stack(w.all_world2pix(t["INDEX_RA"], t["INDEX_DEC"], 0), -1)
        np.testing.assert_allclose(pix, np.stack([t["INDEX_X"], t["INDEX_Y"]], -1), atol=0.01)
    # --json: one document for the batch
    assert main(["solve", str(imgs / "f0.png"), str(imgs / "f1.png"), "--fov", "15",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["n"] == 2 and doc["solved"] == 2


def test_batch_reports_a_bad_file_and_goes_on(tmp_path, capsys):
    import cv2

    from adfusion.app import examples

    ex = examples.example_frame()
    assert cv2.imwrite(str(tmp_path / "a.png"), ex.image)
    (tmp_path / "b.png").write_bytes(b"not a png")
    assert main(["solve", str(tmp_path), "--fov", "15"]) == 1
    text = capsys.readouterr().out
    assert "1 solved, 1 not (b.png: cannot read image file" in text


# --- the real frames (skipped without ../shared) ----------------------------------------

REAL = "data/real-images"


@pytest.fixture(scope="module")
def calibrated(shared_dir, tmp_path_factory):
    """`adfusion calibrate` on the 8 real frames (one run for the tests below)."""
    out = tmp_path_factory.mktemp("cal") / "camera.yaml"
    rc = main(["calibrate", str(shared_dir / REAL), "--fov", "11.4", "-o", str(out),
               "--epoch", "2019.575", "--json"])
    return rc, out


def _corr(shared_dir):
    return json.loads((shared_dir / REAL / "corr.json").read_text())


@pytest.mark.opencv
def test_calibrate_real_frames_beats_the_pinhole_on_astrometry_net_stars(calibrated,
                                                                         shared_dir):
    """Every frame used; astrometry.net's matched stars (corr.json, its own Tycho-2
    positions and centroids) land closer through the calibrated camera than through the
    pinhole with a fitted focal length, frame by frame; and the radial term agrees with a
    fit to astrometry.net's stars alone."""
    from adfusion.starid.camera.calibrate import fit_camera_model

    rc, path = calibrated
    assert rc == 0
    cam = read_camera_yaml(path)
    corr = _corr(shared_dir)
    cat = starid.Catalog.hipparcos(mag_limit=6.5, epoch=2019.575)
    with_cam = starid.Solver(cat, cam, fit_camera="none")
    pinhole = starid.Solver(cat, starid.Camera.pinhole(1024, 768, 11.4), fov_error_deg=0.5,
                            fit_camera="focal")
    frames = []
    for name, c in sorted(corr.items()):
        xy = np.stack([c["x"], c["y"]], 1)
        r = rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"]))
        frames.append((xy, r))
        det = starid.detect(shared_dir / REAL / f"{name}.tiff")
        err = {}
        for key, s in (("calibrated", with_cam), ("pinhole", pinhole)):
            sol = s.solve(det)
            assert sol.ok, (name, key, sol.reason)
            d = np.linalg.norm(sol.camera.vectors_to_pixels(rot.rotate(sol.q_cam_icrs, r))
                               - xy, axis=1)
            err[key] = (np.median(d), np.percentile(d, 95))
        assert err["calibrated"][0] < err["pinhole"][0], (name, err)
        assert err["calibrated"][1] < 0.5, (name, err)
    ref = fit_camera_model(frames, starid.Camera.pinhole(1024, 768, 11.4), ("focal", "k1"))
    assert cam.D[0] == pytest.approx(ref.camera.D[0], abs=0.03)
    assert cam.fov_x_deg == pytest.approx(ref.camera.fov_x_deg, abs=0.01)


@pytest.mark.opencv
def test_real_frames_wcs_reproduces_our_projection_of_astrometry_net_stars(calibrated,
                                                                           shared_dir,
                                                                           tmp_path, capsys):
    """Batch-solve the folder with the calibrated camera, write .wcs headers; astropy's
    reading of each header puts every astrometry.net star where our solution does."""
    _, cam_path = calibrated
    out = tmp_path / "out"
    assert main(["solve", str(shared_dir / REAL), "--camera", str(cam_path), "-o", str(out),
                 "--wcs", "--corr", "--epoch", "2019.575"]) == 0
    assert "8 image(s): 8 solved, 0 not" in capsys.readouterr().out
    for name, c in sorted(_corr(shared_dir).items()):
        rec = json.loads((out / f"{name}.json").read_text())
        cam = starid.Camera.from_dict(rec["camera"])
        assert np.any(cam.D)  # the distortion made it into the header as SIP
        q = np.array(rec["q_cam_icrs"])
        r = rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"]))
        ours = cam.vectors_to_pixels(rot.rotate(q, r))
        w = astropy_wcs.WCS(fits.getheader(out / f"{name}.wcs"))
        assert "SIP" in w.wcs.ctype[0]
        theirs = np.stack(w.all_world2pix(c["ra_deg"], c["dec_deg"], 0), -1)
        assert np.max(np.linalg.norm(theirs - ours, axis=1)) < 0.05, name
        sky = np.radians(w.all_pix2world(np.stack([c["x"], c["y"]], 1), 0))
        b = rot.rotate(rot.inverse(q), cam.pixels_to_vectors(np.stack([c["x"], c["y"]], 1)))
        ang = np.arccos(np.clip(np.sum(rot.radec_to_vector(sky[:, 0], sky[:, 1]) * b, 1),
                                -1, 1))
        assert np.max(ang) / cam.pixel_scale_rad < 0.05, name


def test_cli_paths(tmp_path):
    assert main(["solve", str(tmp_path), "--fov", "10"]) == 2  # an empty folder
    assert main(["calibrate", str(tmp_path / "none.png"), "-o", str(tmp_path / "c.yaml"),
                 "--fov", "10"]) == 2
    assert not Path(tmp_path / "c.yaml").exists()


@pytest.mark.opencv
def test_solve_takes_a_fov_range(shared_dir, capsys):
    frame = sorted((shared_dir / REAL).glob("*.tiff"))[2]
    assert main(["solve", str(frame), "--fov", "5:40", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] and res["fov_x_deg"] == pytest.approx(11.42, abs=0.02)
    assert len(res["matches"]) >= 20  # the catalogue thinned for 5°, not for the middle
    assert main(["solve", str(frame), "--fov", "5:40", "--fov-error", "1"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["solve", str(frame), "--fov", "40:5"]) == 2
    assert "LO ≤ HI" in capsys.readouterr().err


@pytest.mark.opencv
def test_cedar_frames_wcs_reproduces_our_projection(shared_dir, tmp_path, capsys):
    """The cedar-solve set's 1280×960 frames (another camera, JPEG) as one batch: every
    solved frame's .wcs puts astrometry.net's stars where our solution does. (The whole
    set, five cameras, is a benchmark-sized run: one index per camera.)"""
    folder = shared_dir / "data" / "real-images-cedar"
    names = ["jan1_g90_e100ms", "jan1_g90_e50ms", "test2_g100_e50ms", "test_5mp_g100_e50ms"]
    out = tmp_path / "out"
    assert main(["solve", *(str(folder / f"{n}.jpg") for n in names), "--fov", "10.95",
                 "--fov-error", "0.5", "-o", str(out), "--wcs"]) == 0
    capsys.readouterr()
    corr = json.loads((folder / "corr.json").read_text())
    for name in names:
        c = corr[name]
        rec = json.loads((out / f"{name}.json").read_text())
        cam = starid.Camera.from_dict(rec["camera"])
        r = rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"]))
        ours = cam.vectors_to_pixels(rot.rotate(np.array(rec["q_cam_icrs"]), r))
        w = astropy_wcs.WCS(fits.getheader(out / f"{name}.wcs"))
        theirs = np.stack(w.all_world2pix(c["ra_deg"], c["dec_deg"], 0), -1)
        assert np.max(np.linalg.norm(theirs - ours, axis=1)) < 0.05, name


@pytest.mark.parametrize("text", ["# Notes\n\nSome *Markdown* here: a: b: c\n", "",
                                  "site_name: x\nhooks:\n  - a.py\nnav:\n  - Home: index.md\n"])
def test_a_file_that_is_no_camera_yaml_is_one_line_naming_it(tmp_path, capsys, text):
    """A Markdown, empty or unrelated YAML file given as --camera once ended in
    "internal error: SystemError: <class 'cv2.FileStorage'> returned a result with an
    exception set" (the new-user trial); it is a ValueError naming the file."""
    p = tmp_path / "notes.md"
    p.write_text(text)
    with pytest.raises(ValueError, match=r"notes\.md"):
        read_camera_yaml(p)
    import cv2

    img = tmp_path / "sky.png"
    cv2.imwrite(str(img), np.zeros((48, 64), np.uint8))
    assert main(["solve", str(img), "--camera", str(p)]) in (1, 2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.md" in err[0] and "internal error" not in err[0]
