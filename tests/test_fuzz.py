"""Fuzzing in the suite (issue 16, item 15): a reduced, derandomised run of the properties
of :mod:`adfusion.app.fuzz` — the long run is ``benchmarks/fuzz.py --minutes N``.

* the MCAP reader under truncation, byte flips, zeroed and cut-out spans: never a
  traceback, never a message the file does not hold, every loss reported, and never more
  lost than the damaged chunk when the summary survived;
* the solver on random frames, priors and cameras: only documented exceptions, never an
  accepted attitude the truth contradicts;
* the sources on random CSV text and image bytes;
* the CLI on random command lines over a corpus of damaged and foreign files, and every
  command on every corpus file: exit 0/1/2, one line, never a traceback.
"""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from adfusion.app import fuzz


def fuzz_settings(n: int) -> settings:
    """A small derandomised run (the same cases every time; no example database)."""
    return settings(max_examples=n, derandomize=True, database=None, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> fuzz.ReaderCorpus:
    return fuzz.ReaderCorpus(tmp_path_factory.mktemp("reader"))


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory, corpus) -> dict[str, str]:
    return fuzz.cli_corpus(tmp_path_factory.mktemp("cli"), corpus)


@pytest.fixture(scope="module")
def bank() -> fuzz.SolverBank:
    return fuzz.SolverBank(fovs_deg=(20.0,))


@fuzz_settings(80)
@given(data=st.data(), kind=st.sampled_from(["flip", "zero", "truncate", "cutout"]))
def test_reader_survives_damage(corpus, data, kind):
    if data.draw(st.booleans()):  # inside one chunk
        s, e, _ = data.draw(st.sampled_from(corpus.chunks))
        offset = data.draw(st.integers(s, e - 1))
        length = data.draw(st.integers(1, e - offset))
    else:
        offset = data.draw(st.integers(0, len(corpus.data) - 1))
        length = data.draw(st.integers(1, 64))
    assert fuzz.check_reader(corpus, kind, offset, length) in ("ok", "reported")


def test_reader_fuzz_property_has_teeth(corpus):
    """The property fails where it should: a reader that stopped at the first bad chunk
    would lose every later chunk — the check counts it (here: the intact file passes and
    a flip in chunk 1 is reported, costing that chunk only)."""
    assert fuzz.check_reader(corpus, "flip", 0, 0) == "ok"
    s = corpus.chunks[1][0]
    assert fuzz.check_reader(corpus, "flip", s + 40, 8) == "reported"


@fuzz_settings(25)
@given(seed=st.integers(0, 2**32 - 1), n_false=st.integers(0, 12),
       drop=st.sampled_from([0.0, 0.3, 0.7]), sigma_px=st.sampled_from([0.1, 0.5, 1.5]),
       prior=st.sampled_from(["none", "prior"]),
       prior_error=st.sampled_from([0.0, 0.05, 1.0, 10.0]),
       prior_sigma=st.sampled_from([0.05, 0.5, 3.0]))
def test_solver_never_accepts_an_attitude_the_truth_contradicts(
        bank, seed, n_false, drop, sigma_px, prior, prior_error, prior_sigma):
    assert fuzz.check_solver(bank, seed, 20.0, n_false, drop, sigma_px, prior, prior_error,
                             prior_sigma) in ("ok", "reported")


@fuzz_settings(40)
@given(seed=st.integers(0, 2**32 - 1))
def test_sources_raise_only_documented_errors(tmp_path, seed):
    assert fuzz.check_sources(tmp_path, seed) in ("ok", "reported")


@fuzz_settings(12)
@given(seed=st.integers(0, 2**32 - 1))
def test_cli_command_lines_exit_with_one_line(cli_files, tmp_path_factory, seed):
    out = tmp_path_factory.mktemp("out")
    argv = fuzz.cli_argv(random.Random(seed), cli_files, str(out))
    assert fuzz.check_cli(argv) in ("ok", "reported")


def test_every_command_on_the_fuzz_corpus(cli_files, tmp_path):
    """Acceptance: no user-reachable input ends in a traceback — every command on the
    corpus files, exit codes 0/1/2 and one line. (Two cases build a pattern index for an
    odd camera, 25–40 s each — solving the tiny PNG, replaying the reader corpus' 32×24
    log: they are left to the long run, ``benchmarks/fuzz.py``.)"""
    slow = {("solve", "png"), ("replay", "reader-intact")}
    for name, path in cli_files.items():
        out = tmp_path / name
        for argv in (["detect", path], ["solve", path, "--fov", "20"],
                     ["report", path, "-o", str(out)], ["replay", path, "-o", f"{out}.mcap"]):
            if (argv[0], name) not in slow:
                fuzz.check_cli(argv)


def test_a_two_star_fix_with_a_false_star_under_a_loose_prior_is_not_accepted():
    """The long fuzz run's wrong attitude (seed 16): a loose prior (0.5°), one false star
    among two tracked detections; the fix was accepted 1.08° off at p_false 2.6e-7 because
    only the wrong pairing fitted. The chance bound for wide gates refuses it."""
    bank = fuzz.SolverBank(fovs_deg=(12.0,))
    assert fuzz.check_solver(bank, 2908631232, 12.0, 1, 0.7, 0.1, "prior", 0.0, 0.5) in (
        "ok", "reported")


def test_a_three_star_fix_near_a_wrong_loose_prior_is_not_accepted():
    """The 32-minute fuzz run's wrong attitude (seed 23): a 30° field, a prior 10° wrong at
    σ 0.5°, 7 false stars among 50 detections; tracking fitted 3 of them near the prior and
    accepted the fix 10.9° off at p_false 8.9e-5. The shift-and-roll search under a loose
    prior is counted in p_false (look-elsewhere), so the frame goes to lost-in-space."""
    bank = fuzz.SolverBank(fovs_deg=(30.0,))
    assert fuzz.check_solver(bank, 1663394242, 30.0, 7, 0.3, 0.1, "prior", 10.0, 0.5) in (
        "ok", "reported")


# Wrong attitudes the long fuzz runs accepted: seed 37 (at da72860; also wrong at dbf07b3)
# before the cross-checks of a fix that explains few stars, seed 41 before the
# alternatives of a star the others do not pin
_LONG_RUN_WRONG = [
    # tracking under a tight prior 20σ wrong: 2–4 chance pairs near the prior, fixes
    # 0.9–1.2° off at p_false 1e-6–7e-5 (Solver._cross_checked)
    (2629140815, 20.0, 5, 0.3, 0.1, "prior", 1.0, 0.05),
    (3704101671, 30.0, 11, 0.0, 1.5, "prior", 1.0, 0.05),
    (1632021284, 30.0, 9, 0.0, 1.5, "prior", 1.0, 0.05),
    # lost in space, 11 false stars, 70 % dropped: 7 stars matched 162° off, p_false 5.9e-7
    # (Solver._rest_checked)
    (1875421584, 20.0, 11, 0.7, 0.1, "none", 10.0, 3.0),
    # seed 41 (at af4f38c): a right prior of σ 0.5°, 4 stars, the roll resting on one of
    # them paired with its Pleiades neighbour: 1.67° off at p_false 3.5e-6
    # (Tracker._alternatives_of_critical_stars)
    (996432571, 12.0, 2, 0.7, 1.5, "prior", 0.05, 0.5),
    # seed 59 (at c8d9d57): a prior 20σ wrong, 70 % dropped, 9 false: tracking fitted 3 of
    # 29 detections 1.14° off at p_false 8.4e-5 and lost in space found nothing
    # (Solver._cross_checked: such a fix must pass the lost-in-space threshold)
    (1043982730, 30.0, 9, 0.7, 1.5, "prior", 1.0, 0.05),
]


@pytest.mark.parametrize("case", _LONG_RUN_WRONG, ids=lambda c: str(c[0]))
def test_the_long_fuzz_runs_wrong_attitudes_are_not_accepted(case):
    bank = fuzz.SolverBank(fovs_deg=(case[1],))
    assert fuzz.check_solver(bank, *case) in ("ok", "reported")


def _fuzz_frame(solver, seed, n_false, drop_frac, sigma_px):
    """The detections and truth of fuzz.check_solver's frame for ``seed`` (its draws)."""
    from adfusion.maths import rotations as rot

    cam = solver.camera
    rng = np.random.default_rng(seed)
    q = rot.normalize(rng.normal(size=4))
    _, xy = solver.stars_in_view(q)
    xy = xy + rng.normal(0.0, sigma_px, xy.shape)
    xy = xy[rng.random(len(xy)) >= drop_frac]
    false_xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n_false, 2))
    dets = np.vstack([xy, false_xy])
    return dets[rng.permutation(len(dets))], q, rng


def test_a_prior_20_sigma_wrong_is_overruled_by_the_stars_it_leaves_unexplained():
    """Prior 1° off at σ 0.05° over a 30° frame of 55 stars: tracking alone fitted 4 chance
    pairs near it (0.87° off, p_false 1.1e-6). The solver now hands back the lost-in-space
    fix of the whole frame, near the truth, and says the prior was contradicted."""
    from adfusion.starid.solver import Prior

    from adfusion.maths import rotations as rot

    solver = fuzz.SolverBank(fovs_deg=(30.0,)).get(30.0)
    dets, q, rng = _fuzz_frame(solver, 3704101671, 11, 0.0, 1.5)
    axis = rng.normal(size=3)
    q_prior = rot.multiply(rot.exp_map(np.radians(1.0) * axis / np.linalg.norm(axis)), q)
    sol = solver.solve(dets, prior=Prior(q_prior, 0.05))
    assert sol.ok and sol.mode == "lost-in-space"
    assert "prior contradicted" in sol.note
    assert np.degrees(rot.angle_between(sol.q_cam_icrs, q)) < 0.1
    assert len(sol.matches) > 40


def test_a_lost_in_space_fix_explaining_few_detections_yields_to_the_rest():
    """11 false stars, 70 % of the stars dropped: the first accepted candidate (a 5-star
    sub-pattern with a false star in it) explained 7 of 30 detections, 162° off. The rest
    of the frame holds the right attitude with far stronger evidence; it wins, named."""
    from adfusion.maths import rotations as rot

    solver = fuzz.SolverBank(fovs_deg=(20.0,)).get(20.0)
    dets, q, _ = _fuzz_frame(solver, 1875421584, 11, 0.7, 0.1)
    sol = solver.solve(dets)
    assert sol.ok and "two attitudes" in sol.note
    assert np.degrees(rot.angle_between(sol.q_cam_icrs, q)) < 0.05
    assert len(sol.matches) >= 20
    # its first 30 detections, none past the search's: Solver.solve's lean path decides
    # whether the rest is searched without the general path's call
    sol30 = solver.solve(np.ascontiguousarray(dets[:30]))
    assert sol30.ok and "two attitudes" in sol30.note
    assert np.degrees(rot.angle_between(sol30.q_cam_icrs, q)) < 0.05


@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    from adfusion.app import fuzz_streams

    return fuzz_streams.StreamCorpus(tmp_path_factory.mktemp("streams"), duration_s=2.0)


@fuzz_settings(10)
@given(seed=st.integers(0, 2**32 - 1),
       fault=st.sampled_from(["stop", "pause", "ms", "offset", "repeat", "nan", "jump"]))
def test_gyro_stream_faults_are_reported_never_wrong(streams, seed, fault):
    """Issue 33's stream faults, forward clock jumps included (the 32-min run's 110 wrong
    attitudes): every estimate within max(10σ, 0.2°) of the truth, and a silent gyro said
    so."""
    from adfusion.app import fuzz_streams

    _, a, b = fuzz_streams.random_case(random.Random(seed), streams.duration_s, fault)
    assert fuzz_streams.check_streams(streams, fault, a, b) in ("ok", "reported")


@fuzz_settings(5)
@given(seed=st.integers(0, 2**32 - 1))
def test_two_writers_of_one_output_leave_one_whole_log(tmp_path_factory, seed):
    from adfusion.app import fuzz_streams

    assert fuzz_streams.check_writers(tmp_path_factory.mktemp("w"), seed) == "ok"


def test_stream_fuzz_has_teeth(streams):
    """Held at its last sample for ever (the old estimator), a gyro that stops is the
    wrong attitude the check exists to catch."""
    from adfusion.app import fuzz_streams
    from adfusion.estimation.estimator import Estimator

    assert fuzz_streams.check_streams(streams, "stop", 0.5, 0.0) == "reported"
    defaults = Estimator.__init__.__kwdefaults__
    old = defaults["gyro_max_age_s"]
    defaults["gyro_max_age_s"] = float("inf")
    try:
        with pytest.raises(fuzz.FuzzViolation, match=r"wrong-attitude|silent-loss"):
            fuzz_streams.check_streams(streams, "stop", 0.5, 0.0)
    finally:
        defaults["gyro_max_age_s"] = old
