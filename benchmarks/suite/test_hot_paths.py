"""The hot paths, timed by pytest-benchmark: lost-in-space, tracking, the MEKF's gyro step
and star updates, detection.

Run (from the repository root; not part of the default test run)::

    python -P -m pytest benchmarks/suite --benchmark-json benchmarks/results/suite.json

Each benchmark cycles through its frames, one frame per round, so the statistics are over
frames (min, median, ...), as in the scripts of ``benchmarks/``. Every benchmark also
checks its answer (a fix that is not ok, a wrong attitude, fails the run), so a speed-up
that breaks the result cannot pass unnoticed. docs/benchmarks.md#hot-path-suite says how
to save a baseline and compare a later run against it.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from conftest import fresh

from adfusion.bench.starid import frame_error_px

ROUNDS = 300


def _rounds(frames, rounds=ROUNDS):
    """pytest-benchmark ``setup``: the next frame's arguments, round after round."""
    it = itertools.cycle(frames)
    return lambda: (next(it), {})


@pytest.mark.parametrize("condition", ["clean", "false3"])
def test_lost_in_space(benchmark, lis_case, condition):
    """``Solver.solve`` without a prior: the ``adfusion bench starid`` frames."""
    solver, frames = lis_case
    benchmark.group = "starid"
    benchmark.pedantic(lambda xy: solver.solve(xy), setup=_rounds(
        [(f.xy,) for f in frames[condition]]), rounds=ROUNDS, warmup_rounds=5)
    ok = 0
    for f in frames[condition]:
        sol = solver.solve(f.xy)
        if sol.ok:
            assert frame_error_px(sol.q_cam_icrs, f.q_cam_icrs, solver.camera) <= 5.0
            ok += 1
    assert ok >= 0.9 * len(frames[condition])


@pytest.mark.parametrize("prior", ["filter", "sigma_0.2"])
def test_tracking(benchmark, flight, prior):
    """``Solver.solve`` with a prior on the OEDIPUS-like frames (bench_tracking.py): the
    running estimator's prior (the compiled tight path), and the truth turned by 0.2° RMS
    (the robust path)."""
    from bench_tracking import CORRECT_PX, _synthetic_prior

    solver, frames = flight
    rng = np.random.default_rng(1)
    priors = [f["prior"] if prior == "filter" else _synthetic_prior(f["q_true"], 0.2, rng)
              for f in frames]
    benchmark.group = "starid"
    benchmark.pedantic(lambda xy, p: solver.solve(xy, prior=p), setup=_rounds(
        [(f["xy"], p) for f, p in zip(frames, priors, strict=True)]), rounds=ROUNDS,
        warmup_rounds=5)
    for f, p in zip(frames, priors, strict=True):
        sol = solver.solve(f["xy"], prior=p)
        assert sol.ok and frame_error_px(sol.q_cam_icrs, f["q_true"], solver.camera) \
            <= CORRECT_PX


def test_mekf_gyro_step(benchmark, steady_mekf):
    """``MEKF.propagate``: one 200 Hz gyro sample."""
    f, dt, omega, *_ = steady_mekf
    f = fresh(f)
    benchmark.group = "filter"
    benchmark(f.propagate, dt, omega)
    assert np.all(np.isfinite(f.P))


def test_mekf_star_fix_update(benchmark, steady_mekf):
    """``MEKF.update_camera_attitude``: one star-camera fix (quaternion + covariance)."""
    f, _, _, fix, cov, _, _ = steady_mekf
    benchmark.group = "filter"
    res = benchmark.pedantic(lambda g: g.update_camera_attitude(fix, cov),
                             setup=lambda: ((fresh(f),), {}), rounds=2000, warmup_rounds=10)
    assert res.accepted


def test_mekf_star_vector_update(benchmark, steady_mekf):
    """``MEKF.update_camera_vector``: one star direction in the camera frame."""
    f, *_, b, r = steady_mekf
    benchmark.group = "filter"
    res = benchmark.pedantic(lambda g: g.update_camera_vector(b, r, 3e-5),
                             setup=lambda: ((fresh(f),), {}), rounds=2000, warmup_rounds=10)
    assert res.accepted


def test_detect_rendered_frame(benchmark, rendered_frame):
    """``starid.detection.detect`` on a rendered OEDIPUS-like frame (512×480, intensified)."""
    from adfusion.starid.detection.detect import detect

    benchmark.group = "detect"
    det = benchmark(detect, rendered_frame)
    assert det.ok and len(det) >= 10


@pytest.mark.shared
def test_detect_real_frame(benchmark, real_frame):
    """``starid.detection.detect`` on a real 1024×768 16-bit night-sky frame (../shared/data)."""
    from adfusion.starid.detection.detect import detect

    benchmark.group = "detect"
    det = benchmark(detect, real_frame)
    assert det.ok and len(det) >= 15
