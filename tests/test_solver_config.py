"""SolverConfig: the solver's options as one value, equal to the same keywords."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from adfusion import starid
from adfusion.maths import rotations as rot


@pytest.fixture(scope="module")
def frame():
    cat = starid.Catalog.hipparcos(mag_limit=5.5)
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    q = rot.q_cam_icrs_from_radec_roll(*np.radians([10.0, 60.0, 20.0]))
    v = rot.rotate(q, cat.vectors)
    front = v[:, 2] > 0
    xy = cam.vectors_to_pixels(v[front])
    inside = cam.in_frame(xy)
    xy = xy[inside][np.argsort(cat.mag[front][inside], kind="stable")]
    return cat, cam, q, xy


def test_a_config_and_the_same_keywords_give_the_same_solution(frame) -> None:
    cat, cam, q, xy = frame
    kw = dict(fov_error_deg=0.5, n_max=5, p_false_max=1e-7)
    a = starid.Solver(cat, cam, **kw).solve(xy)
    cfg = starid.SolverConfig(**kw)
    b = starid.Solver(cat, cam, cfg).solve(xy)
    c = starid.Solver(cat, cam, starid.SolverConfig(n_max=5), fov_error_deg=0.5,
                      p_false_max=1e-7).solve(xy)
    assert a.ok and np.degrees(rot.angle_between(a.q_cam_icrs, q)) < 0.01
    for s in (b, c):
        assert s.matches == a.matches and s.p_false == a.p_false
        assert np.array_equal(s.q_cam_icrs, a.q_cam_icrs)
    assert starid.Solver(cat, cam, cfg).config == cfg


def test_bad_options_raise_as_the_keywords_did(frame) -> None:
    cat, cam, _, _ = frame
    with pytest.raises(ValueError, match=r"p_false_max must be in \(0, 1\)"):
        starid.Solver(cat, cam, p_false_max=2.0)
    with pytest.raises(ValueError, match="fov_error_deg must be in"):  # needs the camera
        starid.Solver(cat, cam, fov_error_deg=20.0)
    with pytest.raises(ValueError, match="not both"):
        starid.SolverConfig(fov_error_deg=0.5, fov_range_deg=(10, 20))
    with pytest.raises(TypeError, match="n_mx"):
        starid.Solver(cat, cam, n_mx=4)


def test_replace_and_the_normalised_range() -> None:
    cfg = starid.SolverConfig(fov_range_deg=[10, 20])
    assert cfg.fov_range_deg == (10.0, 20.0)
    assert replace(cfg, n_max=4).n_max == 4 and cfg.n_max == 6
    with pytest.raises(ValueError, match="n_min"):
        replace(cfg, n_min=7)
