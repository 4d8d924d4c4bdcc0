"""Inputs of the hot-path benchmark suite (``python -P -m pytest benchmarks/suite``), built
once per run: the ``adfusion bench starid`` frames, an OEDIPUS-like flight with the
running estimator's priors, a steady MEKF, a real frame from ``../shared/data``.

The suite lies outside ``testpaths`` (pyproject.toml): the default test run never
collects it. See docs/benchmarks.md#hot-path-suite.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench_tracking

REPO = Path(__file__).resolve().parents[2]
# frames per lost-in-space condition; flight seconds of the tracking frames (30 fps)
LIS_FRAMES = 40
FLIGHT_S = 3.0


@pytest.fixture(scope="session")
def lis_case():
    """The ``adfusion bench starid`` camera, catalogue and solver (1024×768, 15°, V < 6,
    σ 0.1 px), warmed up, and its first frames of the conditions ``clean`` and ``false3``."""
    from adfusion.bench.starid import (
        CONDITIONS,
        FrameModel,
        camera_for,
        load_catalog,
        make_frame,
        solver_for,
    )

    m = FrameModel()
    frames = {}
    for name in ("clean", "false3"):
        cond = CONDITIONS[name].resolved(m.sigma_px, m.mag_limit, mag_noise=m.mag_noise,
                                         fov_deg=m.fov_deg)
        cam = camera_for(cond, m.width, m.height, m.fov_deg)
        cat = load_catalog(m.mag_limit, m.epoch)
        frames[name] = [make_frame(cat, cam, cond, m.seed, i) for i in range(LIS_FRAMES)]
    solver = solver_for(m.mag_limit, m.sigma_px, cam, m.epoch)
    solver.warm_up()
    return solver, frames


@pytest.fixture(scope="session")
def flight():
    """``benchmarks/bench_tracking.py``'s inputs for a short flight: the solver, and per
    frame the detections, the running estimator's prior and the truth (rendered
    OEDIPUS-like 512×480 frames, ~30 detections each)."""
    from bench_tracking import _frames

    solver, frames = _frames(FLIGHT_S, seed=1)
    solver.warm_up()
    solver.warm_up_tracking()
    return solver, [f for f in frames if f["prior"] is not None]


@pytest.fixture(scope="session")
def rendered_frame():
    """One rendered OEDIPUS-like frame (512×480, intensified, the tether in view)."""
    from adfusion.sensors.scenarios import oedipus

    for ev in oedipus(duration_s=0.5, seed=1, render=True).events():
        if ev.kind == "frame":
            return ev.data["image"]
    raise AssertionError("the scenario rendered no frame")


@pytest.fixture(scope="session")
def real_frame():
    """The first real 1024×768 16-bit frame of ``../shared/data/real-images`` (skips
    cleanly without ``../shared``)."""
    import importlib.util

    import cv2

    # the tests' finder of ../shared ($ADFUSION_SHARED or beside the checkout)
    spec = importlib.util.spec_from_file_location("_tests_conftest", REPO / "tests" /
                                                  "conftest.py")
    tests_conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tests_conftest)
    shared = tests_conftest.find_shared()
    paths = sorted((shared / "data" / "real-images").glob("*.tiff")) if shared else []
    if not paths:
        pytest.skip("../shared/data/real-images is not beside the checkout "
                    "(set ADFUSION_SHARED to point at shared/)")
    return cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)


@pytest.fixture(scope="session")
def steady_mekf():
    """An MEKF after 60 s of 200 Hz gyro and 1 Hz star fixes (Crassidis & Junkins
    Ex. 7.1's noise), with the next gyro sample and a star fix to apply: (filter, dt,
    omega, fix quaternion, fix covariance, star direction, its reference)."""
    from adfusion.estimation.mekf import MEKF
    from adfusion.maths import rotations as rot

    rng = np.random.default_rng(0)
    arw, rrw = np.sqrt(10) * 1e-7, np.sqrt(10) * 1e-10
    f = MEKF([1.0, 0.0, 0.0, 0.0], np.radians(0.1), 1e-6, arw, rrw)
    omega = np.array([0.0, 0.0, 0.01])
    dt = 0.005
    for k in range(12_000):
        f.propagate(dt, omega + rng.normal(0, arw / np.sqrt(dt), 3))
        if k % 200 == 199:
            f.update_camera_attitude(
                rot.multiply(rot.exp_map(rng.normal(0, 3e-5, 3)), f.q_cam_icrs),
                np.eye(3) * 9e-10)
    fix = rot.multiply(rot.exp_map(rng.normal(0, 3e-5, 3)), f.q_cam_icrs)
    r = rot.radec_to_vector(0.3, 0.2)
    b = rot.rotate(f.q_cam_icrs, r)
    return f, dt, omega, fix, np.eye(3) * 9e-10, b, r


def fresh(f):
    """A copy of a filter, for an update that must not change the fixture's."""
    return copy.deepcopy(f)
