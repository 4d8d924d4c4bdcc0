"""A lost-in-space frame in one compiled call (frame_kernels.solve_frame) against the same
search, verification and refit called one by one from Python (Solver._frame_kernel =
False): the same solutions, field by field, on frames that end every way a frame can —
identified, refitted with pairs rejected, checked on the rest of the frame, weak candidates
shown, nothing found — and the pair list's coarse table against a plain search of the
pair list. benchmarks/compiled_equivalence.py runs both comparisons on the benchmark's
frames, and against a recording of the code before a change."""

from __future__ import annotations

import numpy as np
import pytest
from adfusion.starid.identify import frame_kernels, kernels
from test_solver import sky_frame

from adfusion import starid


@pytest.fixture(scope="module")
def cat():
    return starid.Catalog.hipparcos(mag_limit=6.0, epoch=2025.0)


def _same(a, b, fitted: bool = False) -> None:
    """Two solutions of one frame: every field equal (the same arithmetic runs in both);
    ``fitted``: each solve fitted a camera of its own (equal, not the same object)."""
    for f in ("ok", "reason", "path", "patterns_tried", "matches", "matching_counter",
              "note", "sigma_px", "n_detections", "mode"):
        assert getattr(a, f) == getattr(b, f), f
    assert [c.matches for c in a.candidates] == [c.matches for c in b.candidates]
    assert [a.p_false] + [c.p_false for c in a.candidates] == \
        [b.p_false] + [c.p_false for c in b.candidates]
    if a.ok:
        np.testing.assert_array_equal(a.q_cam_icrs, b.q_cam_icrs)
        np.testing.assert_array_equal(a.covariance, b.covariance)
        np.testing.assert_array_equal(a.residuals_rad, b.residuals_rad)
        if fitted:
            assert a.camera.fov_x_deg == b.camera.fov_x_deg
        else:
            assert a.camera is b.camera


@pytest.mark.parametrize("sigma_px, n_false, drop, kind", [
    (0.3, 0, 0.0, "sky"), (0.3, 8, 0.0, "sky"), (0.3, 3, 0.3, "sky"), (2.0, 0, 0.0, "sky"),
    (0.3, 25, 0.0, "sky"), (0.3, 0, 0.0, "noise")])
def test_one_compiled_call_solves_a_frame_as_the_pieces_do(cat, sigma_px, n_false, drop,
                                                           kind):
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam, centroid_sigma_px=max(0.5, sigma_px))
    rng = np.random.default_rng(139 + n_false)
    outcomes = set()
    for _ in range(12):
        xy, _ = sky_frame(cat, cam, rng, sigma_px=sigma_px, n_false=n_false, drop=drop)
        if kind == "noise":
            xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (9, 2))
        solver._frame_kernel = True
        a = solver.solve(xy)
        solver._frame_kernel = False
        b = solver.solve(xy)
        _same(a, b)
        outcomes.add("ok" if a.ok else a.reason.split(":")[0])
        if "rejected" in a.note:
            outcomes.add("rejected")
        if len(xy) > solver.max_detections and a.ok:
            outcomes.add("beyond the search's detections")
    if kind == "noise":
        # weak candidates verified and shown; chance explains them: "no match" (a noise
        # frame was once reported "ambiguous: weak evidence … p_false 1")
        assert outcomes == {"no match"}
    else:
        assert "ok" in outcomes
    if sigma_px > 1:
        assert "rejected" in outcomes  # the refit's residual rejection ran in the kernel


def test_the_pair_lists_coarse_table_finds_the_rows_a_plain_search_finds(cat):
    """kernels._pair_window brackets each edge with the coarse table (kernels.pair_bins)
    and checks the bracket: its rows must be those of a plain scan of the pair list, for
    windows anywhere, narrow or wide, with edges on stored cosines (ties) and beyond the
    list's reach."""
    solver = starid.Solver(cat, starid.Camera.pinhole(1024, 768, 15.0))
    ix = solver.view.ix
    pc, bins, max_sep = ix[3], ix[9], ix[8]
    rng = np.random.default_rng(3)
    lows = np.concatenate([rng.uniform(0, max_sep * 1.2, 300),
                           np.arccos(np.clip(pc[rng.integers(0, len(pc), 100)], -1, 1)),
                           [0.0, max_sep]])
    for lo_rad in lows:
        for width in (1e-6, 5e-4, 0.05):
            cmax, cmin = np.cos(lo_rad), np.cos(min(lo_rad + width, np.pi))
            if rng.uniform() < 0.3:  # an edge exactly on a stored cosine
                cmax = pc[rng.integers(0, len(pc))]
                cmin = min(cmin, cmax - 1e-9)
            inside = np.flatnonzero((pc > cmin) & (pc < cmax))
            want = (inside[0], inside[-1] + 1) if len(inside) else None
            lo, hi = kernels._pair_window(pc, cmin, cmax, bins, max_sep)
            assert (lo, hi) == want if want else lo == hi


def test_without_a_refit_the_one_call_path_leaves_the_verified_fit(cat):
    """_solve_at (the rest-of-frame check's search, the warm-up's) returns the verified fit,
    not a refit: on the one-call path as on the pieces' (review finding: the detections the
    kernel would refit on had replaced the caller's, so a refit ran on the search's own)."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    rng = np.random.default_rng(5)
    for _ in range(4):
        xy, _ = sky_frame(cat, cam, rng)
        xy = np.ascontiguousarray(xy[: solver.max_detections])
        solver._frame_kernel = True
        a, tried_a = solver.search.solve_at(xy, [cam])
        solver._frame_kernel = False
        b, tried_b = solver.search.solve_at(xy, [cam])
        assert a.ok and a.sigma_px is None
        _same(a, b)
        assert tried_a == tried_b


def test_a_fitted_camera_is_refitted_on_every_detection(cat):
    """With a camera fitted after identification the refit runs in Python, on every
    detection — also those beyond the ``max_detections`` the search used."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam, fit_camera="focal", max_detections=10)
    rng = np.random.default_rng(6)
    beyond = frames = 0
    while frames < 4:
        xy, _ = sky_frame(cat, cam, rng)
        if len(xy) <= 14:  # too few beyond the search's 10
            continue
        frames += 1
        solver._frame_kernel = True
        a = solver.solve(xy)
        solver._frame_kernel = False
        b = solver.solve(xy)
        assert a.ok
        assert (a.matches, a.p_false, a.note) == (b.matches, b.p_false, b.note)
        beyond += any(d >= solver.max_detections for d, _ in a.matches)
    assert beyond == 4


@pytest.mark.parametrize("tol", [float("nan"), -0.01, 0.0, float("inf")])
def test_a_tolerance_that_is_not_an_angle_is_refused(cat, tol):
    with pytest.raises(ValueError, match="tolerance_deg"):
        starid.Solver(cat, starid.Camera.pinhole(1024, 768, 15.0), tolerance_deg=tol)


@pytest.mark.parametrize("path", ["one call", "pieces", "fitted camera"])
def test_a_detection_outside_the_frame_beyond_the_search_keeps_the_others_rows(cat, path):
    """Detections past ``max_detections`` only join the final refit, and one outside the
    frame is left out of it — even within the match radius of a star just inside the
    edge — but every match must still name the caller's row: leaving them out once
    shifted every later detection's index by one, pairing stars with detections hundreds
    of pixels away."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam, max_detections=10,
                           fit_camera="focal" if path == "fitted camera" else "auto")
    solver._frame_kernel = path != "pieces"  # a fitted camera: refitted in Python
    rng = np.random.default_rng(8)
    frames = 0
    for _ in range(400):
        if frames == 3:
            break
        xy, q = sky_frame(cat, cam, rng)
        pxy, _, _ = solver.view.project_idx(q, cam)
        near = np.flatnonzero((pxy[:, 0] < 1.0) & (pxy[:, 1] > 5) & (pxy[:, 1] < 760))
        if len(xy) < 16 or not len(near):
            continue
        star = pxy[near[0]]  # within 1.5 px of the left edge, inside the frame
        own = np.argmin(np.hypot(*(xy - star).T))
        if own < 12 or np.hypot(*(xy[own] - star)) > 1.5:
            continue
        frames += 1
        xy = np.delete(xy, own, axis=0)  # its own detection gone: only ours is near it
        # row 12 just outside the left edge, 1.6 px or less from that star; row 13 far out
        xy = np.insert(xy, 12, [[-0.6, star[1]], [-400.0, 100.0]], axis=0)
        sol = solver.solve(xy)
        assert sol.ok
        ids, pred = solver.stars_in_view(sol.q_cam_icrs)
        at = dict(zip(ids.tolist(), pred, strict=True))
        assert not [d for d, _ in sol.matches if d in (12, 13)]
        far = [(d, h) for d, h in sol.matches if np.hypot(*(xy[d] - at[h])) > 3.0]
        assert not far
        assert any(d > 13 for d, _ in sol.matches)  # rows after them matched, by their rows
    assert frames == 3


def test_the_packed_result_reads_back_as_the_kernels_own(cat, monkeypatch):
    """solve_frame_packed hands solve_frame's result to Python as two flat arrays; unpack
    must give back every field — pairs with the catalogue's ids, weak rows — for frames
    identified, refitted with pairs rejected, and weak."""
    from adfusion.starid.identify import frame_kernels as fk
    calls = []
    real = fk.solve_frame_packed

    def spy(*a):
        mutable = (13, 17, 18)  # state, no_match, n_no_match: the kernel writes them
        calls.append([x.copy() if i in mutable else x for i, x in enumerate(a)])
        return real(*a)

    monkeypatch.setattr(fk, "solve_frame_packed", spy)
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam, centroid_sigma_px=2.0)
    rng = np.random.default_rng(12)
    seen = set()
    for k in range(30):
        if seen == {"refitted", "rejected", "weak"}:
            break
        xy, _ = sky_frame(cat, cam, rng, sigma_px=2.0)
        if k == 0:  # noise
            xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (9, 2))
        calls.clear()
        solver.solve(xy.tolist())  # the general path (the lean one calls it compiled)
        for a in calls:
            ids, args = a[0], a[1:]
            fresh = [x.copy() if i in (12, 16, 17) else x for i, x in enumerate(args)]
            outcome, sel, counter, n_acc, order, cands, refit, (wp, wi), _, _ = fk.unpack(
                *real(ids, *fresh))
            fresh = [x.copy() if i in (12, 16, 17) else x for i, x in enumerate(args)]
            o2, sel2, c2, cands2, order2, n_acc2, refit2, (wp2, wi2) = fk.solve_frame(*fresh)
            assert (outcome, sel, counter, n_acc, order) == (
                o2, sel2.tolist(), c2, n_acc2, order2.tolist())
            n, det, cat_rows, q, cov, res, p = cands2
            assert len(cands) == len(n)
            for i, (d, h, qi, ci, ri, pi) in enumerate(cands):
                assert d == det[i, :n[i]].tolist()
                assert h == ids[cat_rows[i, :n[i]]].tolist()
                np.testing.assert_array_equal(qi, q[i])
                np.testing.assert_array_equal(ci, cov[i])
                np.testing.assert_array_equal(ri, res[i, :n[i]])
                assert pi == p[i]
            assert refit[0] == refit2[0] and refit[7] == refit2[7]
            if refit[0] == 1:
                assert refit[1] == refit2[1].tolist()
                assert refit[2] == ids[refit2[2]].tolist()
                for j in (3, 4, 5):
                    np.testing.assert_array_equal(refit[j], refit2[j])
                assert refit[6] == refit2[6]
                seen.add("rejected" if refit[7] else "refitted")
            np.testing.assert_array_equal(wp, wp2)
            for r, r2 in zip(wi, wi2, strict=True):  # pattern, guess, trial, n, sel, assignment
                n_r = r2[3]
                assert r[:4].tolist() == r2[:4].tolist()
                assert r[4:4 + n_r].tolist() == r2[4:4 + n_r].tolist()
                assert r[12:12 + n_r].tolist() == r2[12:12 + n_r].tolist()
            if len(wp):
                seen.add("weak")
    assert seen == {"refitted", "rejected", "weak"}


def _search(solver, b, budget, store):
    """kernels.search of directions ``b`` (N, 3) at the solver's own camera, from a frame's
    first trial through its whole pattern list: (state, sel, rows)."""
    pix = solver.camera.pixel_scale_rad
    pats, plen, _ = solver.search._pattern_list(len(b), True)
    state = np.array([0, 0, 0, -1, 0, kernels.NOTE_NONE, 0, 0], dtype=np.int64)
    sel, rows, _, _, _ = kernels.search(
        solver.view.ix, state, pats, plen, budget,
        np.zeros((1, solver.max_patterns + 2), dtype=np.int64), np.zeros(1, dtype=np.int64),
        b[None], solver.tolerance_rad, 0.0, np.array([solver.verifier.match_radius_px() * pix]),
        np.array([np.sqrt(2.0) * solver.centroid_sigma_px * pix]), solver.p_false_max,
        solver.work_budget, solver.search._scratch(), store)
    return state, sel, rows


def test_the_search_keeps_first_three_star_assignments_without_changing_a_trial(cat):
    """kernels.search reuses a pattern's first three stars' assignments for every later
    pattern that starts with the same three detections (most Not-Modus trials): its walk
    must stop at the trial, with the rows and counts, that matching every pattern afresh
    (kernels.match) gives — on frames with false stars, where the reuse happens."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    rng = np.random.default_rng(21)
    pix = cam.pixel_scale_rad
    radius = np.array([solver.verifier.match_radius_px() * pix])
    floor = np.array([np.sqrt(2.0) * solver.centroid_sigma_px * pix])
    reused = 0
    for _ in range(8):
        xy, _ = sky_frame(cat, cam, rng, n_false=8)
        xy = np.ascontiguousarray(xy[: solver.max_detections])
        b = cam.pixels_to_vectors(xy)
        pats, plen, _ = solver.search._pattern_list(len(xy), True)
        state, sel, rows = _search(solver, b, 200, kernels.triangle_store())
        # the same walk, every pattern matched afresh
        masks, seen, stop = [], set(), None
        for p in range(min(len(pats), 200)):
            pat = pats[p, :plen[p]]
            mask = sum(1 << int(i) for i in pat)
            if any(m & mask == m for m in masks):
                continue
            s2, ang, tol, lo, hi, chir = kernels.pattern_windows(pat, b, solver.tolerance_rad,
                                                                 0.0)
            key = (*s2[:3].tolist(), chir)
            reused += key in seen
            seen.add(key)
            r2, over, _ = kernels.match(solver.view.ix, lo, hi, chir, solver.work_budget,
                                        solver.search._scratch())
            if over:
                continue
            if not len(r2):
                masks.append(mask)
                continue
            q = kernels.quick_checks(solver.view.ix, b, s2, r2, ang, tol, chir != 0, p + 1,
                                     radius[0], floor[0])
            if any(ok and pf <= solver.p_false_max for ok, pf in zip(q[0], q[1],
                                                                      strict=True)):
                stop = (p, s2.tolist(), r2.tolist())
                break
        assert stop is not None and state[4] == kernels.STRONG
        assert (state[0], sel.tolist(), rows.tolist()) == stop
        assert state[2] == stop[0] + 1  # trials counted alike
    assert reused > 0


def test_the_kept_first_three_star_assignments_are_bounded():
    """Windows a degree wide (tolerance_deg 0.3, V < 6.5, 25°) give noise frames ~10 000
    first-three-star rows a pattern: kept unbounded, one frame held ~2.5 million (60 MB).
    The store keeps no more than its max_rows (kernels.TRIANGLES_KEPT_MAX by default),
    and a pattern's rows past max_partials as their count alone."""
    cat = starid.Catalog.hipparcos(mag_limit=6.5, epoch=2025.0)
    cam = starid.Camera.pinhole(1024, 768, 25.0)
    rng = np.random.default_rng(4)
    xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (30, 2))
    b = cam.pixels_to_vectors(xy)

    def walk(work_budget, max_rows):
        solver = starid.Solver(cat, cam, tolerance_deg=0.3, work_budget=work_budget)
        store = kernels.triangle_store(max_rows)
        assert _search(solver, b, 40, store)[0][2] == 40
        return store

    # 40 trials, ~10 000 rows for each new triple (~120 000 in all): more than it keeps
    store = walk(200_000, 50_000)
    rows = [len(v) - 1 for v in store[0].values()]
    assert len(rows) >= 3 and max(rows) >= 5000
    assert sum(rows) == store[1][0] <= 50_000
    # with max_partials 12 000, the patterns past it: their count (level 3), no rows
    store = walk(12_000, 10**9)
    past = [v for v in store[0].values() if v[0, 0] > 12_000 and v[0, 1] == 3]
    assert past and all(len(v) == 1 for v in past)
    assert max(len(v) - 1 for v in store[0].values()) <= 12_000


def test_the_lean_path_solves_every_frame_as_the_general_path_does(cat):
    """Solver.solve takes a short path for an (N, 2) float64 array without a prior
    (PatternSearch.solve_lean); the same detections as a list go the general way. Every
    field alike, on frames that end every way: identified (refit, rest of the frame
    checked), several attitudes, weak candidates, nothing found, more detections than
    the search uses (some outside the frame), and input the check refuses."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    rng = np.random.default_rng(57)
    outcomes, calls = set(), []
    orig = solver.search._frame_solution

    def counted(*a, **k):
        calls.append("first" in k)
        return orig(*a, **k)

    solver.search._frame_solution = counted
    frames = []
    for k in range(40):
        kind = k % 5
        if kind == 4:  # noise: weak candidates or nothing
            xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1],
                             (int(rng.integers(3, 12)), 2))
        else:
            xy, _ = sky_frame(cat, cam, rng, n_false=(0, 3, 8, 25)[kind], drop=0.2 * kind)
        if kind == 3 and len(xy) > solver.max_detections:
            xy[-1] = (-300.0, 50.0)  # past the search's detections, outside the frame
        frames.append(np.ascontiguousarray(xy))
    frames.append(np.array([[1.0, 2.0], [1.0, 2.0], [300.0, 40.0], [50.0, 500.0]]))
    frames.append(np.array([[1.0, 2.0], [np.nan, 2.0], [300.0, 40.0]]))
    for xy in frames:
        a = solver.solve(xy)
        b = solver.solve(xy.tolist())
        _same(a, b)
        assert a.n_detections == b.n_detections and a.patterns_tried == b.patterns_tried
        outcomes.add("ok" if a.ok else a.reason.split(":")[0])
        if a.ok and len(xy) > solver.max_detections:
            outcomes.add("beyond the search's detections")
    assert {"ok", "no match", "bad input", "beyond the search's detections"} <= outcomes
    assert isinstance(solver.search._lean[0], frame_kernels.LeanState)  # the lean path ran
    assert any(calls)  # and some frames continued from its first call


def test_the_lean_state_is_made_once_and_each_thread_gets_its_own_work_arrays(cat):
    """The lean path's compiled state is made on the first solve and kept by every later
    one (a solve that dropped it would make it again each frame, ~1 ms); an assignment to
    the solver drops it. A thread's first lean call, and a solver whose walk needs more
    room than the thread's arrays give, get arrays of the right size: the same results
    as the general path."""
    import threading

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    rng = np.random.default_rng(21)
    frames = [np.ascontiguousarray(sky_frame(cat, cam, rng, n_false=k % 4)[0])
              for k in range(8)]
    frames.append(rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (10, 2)))
    solver.warm_up()  # the triangles join the index (a new index: a new state)
    solver.solve(frames[0])
    state = solver.search._lean
    for xy in frames:
        _same(solver.solve(xy), solver.solve(xy.tolist()))
    assert solver.search._lean is state
    out = []
    worker = threading.Thread(target=lambda: out.append(solver.solve(frames[1])))
    worker.start()
    worker.join()
    _same(out[0], solver.solve(frames[1].tolist()))
    wide = starid.Solver(cat, cam, max_patterns=4 * solver.max_patterns)
    for xy in frames[-3:]:
        _same(wide.solve(xy), wide.solve(xy.tolist()))
    solver.n_min = solver.n_min  # any assignment
    assert "_lean" not in vars(solver.search)


def test_a_setting_assigned_while_the_state_is_made_is_not_lost(cat, monkeypatch):
    """Another thread assigns a setting while a solve is making the lean state from the old
    value: that state must not be kept, or every later lean solve would use the old value.
    (The state's constructor waits for the assignment, to make the interleaving sure.)"""
    import threading

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    solver.warm_up()  # the triangles have joined the index: no solve assigns it later
    solver.p_false_max = solver.p_false_max  # the state dropped
    xy = np.ascontiguousarray(sky_frame(cat, cam, np.random.default_rng(3), n_false=2)[0])
    making, assigned = threading.Event(), threading.Event()
    real = frame_kernels.lean_state

    def slow(*a):  # the old settings already read
        making.set()
        assigned.wait()
        return real(*a)

    monkeypatch.setattr(frame_kernels, "lean_state", slow)
    worker = threading.Thread(target=solver.solve, args=(xy,))
    worker.start()
    making.wait()
    solver.p_false_max = 1e-300  # nothing may pass now
    assigned.set()
    worker.join()
    monkeypatch.setattr(frame_kernels, "lean_state", real)
    a = solver.solve(xy)
    _same(a, solver.solve(xy.tolist()))
    assert not a.ok


def test_deleting_an_attribute_drops_the_state_and_a_solver_pickles_and_copies(cat):
    """``del`` restores a class default (here: the one-call path itself), so it drops the
    lean state as an assignment does; a solver that has solved on an array can still be
    pickled and deep-copied (its compiled state is made again where it is used), and the
    copies solve alike."""
    import copy
    import pickle

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    solver.warm_up()  # the triangles have joined the index: no solve assigns it later
    xy = np.ascontiguousarray(sky_frame(cat, cam, np.random.default_rng(5), n_false=1)[0])
    solver._frame_kernel = False
    solver.solve(xy)
    assert solver.search._lean is False  # the lean path does not apply
    del solver._frame_kernel
    a = solver.solve(xy)
    assert isinstance(solver.search._lean[0], frame_kernels.LeanState)
    for twin in (pickle.loads(pickle.dumps(solver)), copy.deepcopy(solver)):
        assert "_lean" not in vars(twin.search)
        _same(twin.solve(xy), a, fitted=True)
        assert isinstance(twin.search._lean[0], frame_kernels.LeanState)


def test_the_compiled_paths_solutions_are_made_as_their_classes_make_them(cat):
    """The compiled path builds its Solution and Candidates without their __init__
    (solution.made): every field present, each the object __init__ would keep."""
    import dataclasses

    from adfusion.starid.identify.solution import Candidate, Solution

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    xy, _ = sky_frame(cat, cam, np.random.default_rng(3), n_false=2)
    sol = solver.solve(np.ascontiguousarray(xy))
    assert sol.ok and sol.candidates
    for obj, cls in [(sol, Solution)] + [(c, Candidate) for c in sol.candidates]:
        names = [f.name for f in dataclasses.fields(cls)]
        assert sorted(vars(obj)) == sorted(names)
        again = dataclasses.replace(obj)  # through __init__
        assert all(getattr(again, n) is getattr(obj, n) for n in names)
        with pytest.raises(dataclasses.FrozenInstanceError):
            obj.p_false = 0.0
    assert sol.candidates[0].predicted_xy.shape[1] == 2  # the cached property still works


def test_a_lean_solutions_candidates_are_made_on_first_use_and_kept(cat, monkeypatch):
    """The lean path leaves a solution's candidate list unmade until it is read; then it
    is the general path's, made once, and a pickled or copied solution carries it made
    (not the arrays it is made from). A failure while making it is no missing attribute."""
    import copy
    import dataclasses
    import pickle


    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    xy, _ = sky_frame(cat, cam, np.random.default_rng(2), n_false=3)
    arr = np.ascontiguousarray(xy)
    general = solver.solve(xy.tolist())
    sol = solver.solve(arr)
    assert sol.ok and "candidates" not in vars(sol)
    first = sol.candidates  # made here, through Solution.__getattr__
    assert sol.candidates is first and "_candidates_from" not in vars(sol)
    assert sorted(vars(sol)) == sorted(f.name for f in dataclasses.fields(sol))
    _same(sol, general)
    for make_twin in (lambda s: pickle.loads(pickle.dumps(s)), copy.copy):
        unmade = solver.solve(arr)
        assert "candidates" not in vars(unmade)
        twin = make_twin(unmade)
        assert "_candidates_from" not in vars(twin)
        _same(twin, general, fitted=True)
    with pytest.raises(AttributeError, match="no attribute 'candidate'"):
        sol.candidate  # noqa: B018

    def broken(*args):
        raise AttributeError("a bug inside")

    from adfusion.starid.identify import candidates

    monkeypatch.setattr(candidates, "_candidates_of", broken)
    with pytest.raises(RuntimeError, match="a bug inside"):
        hasattr(solver.solve(arr), "candidates")


def test_a_lean_call_that_keeps_asking_for_room_stops_with_an_error(cat, monkeypatch):
    """The lean path makes its arrays longer when the call asks, twice at most: a call
    that asks again (a bug) ends in an error that says so, not in an endless loop."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    monkeypatch.setattr(frame_kernels, "lean_call",
                        lambda st: lambda *a: (frame_kernels.NO_ROOM, 10, 10))
    xy, _ = sky_frame(cat, cam, np.random.default_rng(2))
    with pytest.raises(RuntimeError, match="asked for larger arrays"):
        solver.solve(np.ascontiguousarray(xy))


def test_a_result_longer_than_the_lean_paths_arrays_grows_them(cat, monkeypatch):
    """The lean call writes its result into the thread's arrays; a result that does not
    fit has them made as long as it needs and the frame solved again: the same
    solution, on a thread's first call too."""
    from adfusion.starid.identify import lost_in_space

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    xy, _ = sky_frame(cat, cam, np.random.default_rng(4), n_false=8)
    general = solver.solve(xy.tolist())
    monkeypatch.setattr(lost_in_space, "_LEAN_OUT", 8)
    solver.search._drop_scratch()
    _same(solver.solve(np.ascontiguousarray(xy)), general)
    assert len(lost_in_space._SCRATCH.lean[2]) > 8


def test_the_lean_path_follows_settings_changed_after_the_first_solve(cat):
    """The lean path keeps only what it takes of the camera: a threshold, a budget, a
    camera fit or the numpy matchers set after a solve apply to the next one, on an
    array as on a list, as in a solver made with them."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    rng = np.random.default_rng(8)
    sky = [np.ascontiguousarray(sky_frame(cat, cam, rng, n_false=3)[0]) for _ in range(3)]
    noise = [rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (12, 2)) for _ in range(2)]
    for name, value in (("p_false_max", 1e-40), ("max_patterns", 5), ("fit_camera", "focal"),
                        ("_compiled", False)):
        solver = starid.Solver(cat, cam)
        solver.solve(sky[0])  # the lean path set up
        setattr(solver, name, value)
        fresh = starid.Solver(cat, cam)
        setattr(fresh, name, value)
        fitted = name == "fit_camera"
        for xy in sky + noise:
            a = solver.solve(xy)
            _same(a, solver.solve(xy.tolist()), fitted)
            _same(a, fresh.solve(xy.tolist()), fitted)


def test_kept_pair_windows_are_the_fresh_ones() -> None:
    """A frame's pair windows kept across its patterns (``pattern_windows_kept``, as the
    search keeps them) give every later pattern — overlapping ones, in any order, at a
    relative tolerance too — the very windows, order and mirror sign a fresh
    ``pattern_windows`` computes."""
    rng = np.random.default_rng(5)
    b = rng.normal(size=(24, 3))
    b[:, 2] = np.abs(b[:, 2]) + 6.0  # a 20°-ish field
    b /= np.linalg.norm(b, axis=1)[:, None]
    for rel_tol in (0.0, 1e-3):
        kept = np.empty((4, len(b), len(b)))
        done = np.zeros((len(b), len(b)), dtype=np.bool_)
        for _ in range(300):
            pat = rng.choice(len(b), size=int(rng.integers(3, 9)), replace=False)
            fresh = kernels.pattern_windows(pat, b, 3e-4, rel_tol)
            again = kernels.pattern_windows_kept(pat, b, 3e-4, rel_tol, kept, done)
            for x, y in zip(fresh, again, strict=True):
                assert np.array_equal(x, y)
        assert done.sum() > 0.5 * len(b) ** 2  # later patterns did read kept pairs


def test_a_read_only_or_unaligned_frame_solves_as_a_writable_one(cat):
    """Detections in a read-only array (a memory-mapped log, ``np.frombuffer``) take the
    lean path's compiled call as they are — the same solution, and no other compiled
    version of the kernel (the dispatcher would compile one for read-only arrays, ~1 min);
    an unaligned array goes the general way, with the same solution."""
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam)
    xy, _ = sky_frame(cat, cam, np.random.default_rng(8), n_false=2)
    xy = np.ascontiguousarray(xy)
    fresh = solver.solve(xy)
    assert fresh.ok
    versions = len(frame_kernels.solve_lean.overloads)
    ro = xy.copy()
    ro.flags.writeable = False
    buf = np.zeros(xy.nbytes + 1, dtype=np.uint8)
    unaligned = np.frombuffer(buf[1:].data, dtype=np.float64).reshape(xy.shape)
    unaligned[...] = xy
    assert not unaligned.flags.aligned
    for arr in (ro, unaligned):
        _same(fresh, solver.solve(arr))
    assert len(frame_kernels.solve_lean.overloads) == versions


def test_a_sky_map_of_other_cells_per_edge_finds_the_same_stars(cat, monkeypatch):
    """``kernels.SKY_CELLS`` set before a solver is made: its sky map is drawn at those
    cells per face edge and read at them (the map's default cells were bound when
    ``sky_map`` was defined, so a map drawn at 1024 was read at 512 and missed stars)."""
    from adfusion.starid.identify import kernels

    cam = starid.Camera.pinhole(1024, 768, 15.0)
    frames = [np.ascontiguousarray(sky_frame(cat, cam, np.random.default_rng(s), n_false=2)[0])
              for s in range(6)]
    want = [starid.Solver(cat, cam).solve(xy) for xy in frames]
    monkeypatch.setattr(kernels, "SKY_CELLS", 512)
    solver = starid.Solver(cat, cam)
    assert solver._sky[1] == 512 and len(solver._sky[0]) < len(kernels.sky_map(
        solver.vectors, solver._sky[2]))
    for xy, w in zip(frames, want, strict=True):
        _same(w, solver.solve(xy))
