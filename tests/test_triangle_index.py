"""The catalogue's triangles looked up (starid.catalog.triangle_index, kernels._triangles_looked_up)
against the scan of the pair windows they replace, and the sky map that lets the
association skip empty sky (kernels.sky_map) against a KD-tree: the same rows in the same
order, the same solutions, every star's neighbourhood marked."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from adfusion.starid.catalog import triangle_index
from adfusion.starid.catalog.pair_index import REUSE_DRIFT_RAD, PatternIndex
from adfusion.starid.identify import kernels
from test_frame_kernels import _same
from test_solver import sky_frame

from adfusion import starid


@pytest.fixture(scope="module")
def solver():
    s = starid.Solver(starid.Catalog.hipparcos(mag_limit=6.0, epoch=2025.0),
                      starid.Camera.pinhole(1024, 768, 15.0))
    s.search._with_triangles()
    assert s.view.ix[13] > 0, "no triangle table for V < 6 in a 15° field"
    return s


def _rows_both_ways(ix_table, ix_scan, b, pats, tolerance_rad, rel_tol, work):
    """kernels._triangles of every pattern (detections ``pats`` of directions ``b``) with
    the table and by scanning: the number of patterns compared, those looked up and the
    most rows one gave."""
    looked_up = most = 0
    for pat in pats:
        _, _, _, lo, hi, chir = kernels.pattern_windows(np.asarray(pat, np.int64), b,
                                                          tolerance_rad, rel_tol)
        got = kernels._triangles(ix_table, lo, hi, chir, 10**6, work)
        want = kernels._triangles(ix_scan, lo, hi, chir, 10**6, work)
        assert got[1:] == want[1:]
        np.testing.assert_array_equal(got[0], want[0])
        looked_up += bool(kernels._looked_up(ix_table, lo))
        most = max(most, len(got[0]))
    assert (work == -1).all()
    return len(pats), looked_up, most


def test_looked_up_triangles_are_the_scans_rows(solver):
    """Noise and sky frames, narrow and wide windows, with and without the focal
    widening, mirror sign or none: every pattern's first three stars get the rows the
    pair-window scan gives, in its order (a wrong margin, cell or sort fails here)."""
    ix_scan = kernels.index_arrays(solver.index)
    cat, cam = solver.catalog, solver.camera
    work = kernels.scratch(ix_scan)
    rng = np.random.default_rng(5)
    rows = looked_up = most = 0
    for f in range(16):
        if f % 2:
            xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (12, 2))
        else:
            xy, _ = sky_frame(cat, cam, rng, sigma_px=0.3, n_false=2)
            xy = xy[:12]
        b = cam.pixels_to_vectors(xy)
        pats = [*list(itertools.combinations(range(len(b)), 3))[::3], tuple(range(6))]
        tol = solver.tolerance_rad * (1, 3)[f % 4 // 2]
        n, k, m = _rows_both_ways(solver.view.ix, ix_scan, b, pats, tol, 0.005 * (f % 3 == 0),
                                  work)
        rows, looked_up, most = rows + n, looked_up + k, max(most, m)
    assert looked_up > 0.9 * rows  # most looked up; those reaching past the list scanned
    assert most > 16  # the wide windows' rows are merge-sorted (kernels._in_scan_order)


@pytest.mark.parametrize("k", [0, 1, 16, 17, 200, 613])
def test_the_looked_up_rows_are_put_in_the_scans_order_however_many(k):
    """kernels._in_scan_order (insertion for a few rows, a merge sort past 16: σ = 2 px
    finds hundreds) against Python's sort of the same keys, with the leading keys tied
    often, as the scan's order ties rows on their first pair."""
    rng = np.random.default_rng(k)
    keys = np.column_stack([rng.integers(0, 2, k), -rng.choice([0.1, 0.2, 0.3], k),
                            rng.integers(0, 3, k), rng.integers(3, 6, k),
                            -rng.choice([0.4, 0.5], k), rng.integers(0, 3, k),
                            rng.permutation(k) + 10]).astype(float)
    cur = rng.integers(0, 5000, (max(k, 1), 3))
    want = cur[sorted(range(k), key=lambda r: tuple(keys[r]))]
    got = kernels._in_scan_order(cur.copy(), keys.copy(), k)
    np.testing.assert_array_equal(got, want.reshape(-1, 3))


def _triangle_with_sides(d01, d02, d12, sign):
    """Three unit vectors at pairwise angles d01, d02, d12 (spherical law of cosines),
    the third on the side ``sign`` of the great circle through the first two."""
    cos_az = (np.cos(d12) - np.cos(d01) * np.cos(d02)) / (np.sin(d01) * np.sin(d02))
    az = sign * np.arccos(np.clip(cos_az, -1, 1))
    return np.array([[0.0, 0.0, 1.0], [np.sin(d01), 0.0, np.cos(d01)],
                     [np.sin(d02) * np.cos(az), np.sin(d02) * np.sin(az), np.cos(d02)]])


def test_a_reused_index_looks_up_what_it_scans():
    """An index reused at a later epoch keeps its stored cosines while its stars have
    moved (by up to REUSE_DRIFT_RAD): the scan tests pairs (0, 1) and (0, 2) on the stored
    cosines and pair (1, 2) on the stars' dot product now. Triangles seen exactly so —
    two sides as stored, the third as it is now, windows far narrower than the drift —
    must be found by the look-up too (its cosine and cell margins cover the drift)."""
    rng = np.random.default_rng(2)
    v0 = rng.normal(size=(1500, 3))
    v0 /= np.linalg.norm(v0, axis=1)[:, None]
    index0 = PatternIndex.from_vectors(v0, 0.3)
    drift = rng.normal(size=v0.shape)
    drift *= 0.9 * REUSE_DRIFT_RAD / np.linalg.norm(drift, axis=1)[:, None]
    v1 = v0 + drift
    v1 /= np.linalg.norm(v1, axis=1)[:, None]
    index1 = dataclasses.replace(index0, vectors=v1)
    tolerance = 1e-7
    ix_table = kernels.index_arrays(index1, triangle_index.triangles_for(index1, tolerance))
    ix_scan = kernels.index_arrays(index1)
    work = kernels.scratch(ix_scan)
    stored = {(i, j): c for i, j, c in zip(index0.pair_i.tolist(), index0.pair_j.tolist(),
                                           index0.pair_cos.tolist(), strict=True)}
    tri = triangle_index.triangle_table(index1, 1e-3)["tri"]
    found = made = 0
    for x, y, z in tri[rng.choice(len(tri), 300, replace=False), :3].astype(int):
        th = {p: np.arccos(stored[tuple(sorted(p))]) for p in ((x, y), (x, z), (y, z))}
        (a, b), _ = min(th.items(), key=lambda kv: kv[1])  # the closest pair first
        c = ({x, y, z} - {a, b}).pop()
        d01, d02 = th[(a, b)], np.arccos(stored[tuple(sorted((a, c)))])
        d12 = np.arccos(np.clip(v1[b] @ v1[c], -1, 1))
        if min(d02, d12) < d01 + 1e-4 or max(d02, d12) > d01 + min(d02, d12) - 1e-4:
            continue  # the closest pair must stay the first; no flat triangles
        sign = np.sign(np.linalg.det(v1[[a, b, c]]))
        dirs = _triangle_with_sides(d01, d02, d12, sign)
        _rows_both_ways(ix_table, ix_scan, dirs, [(0, 1, 2)], tolerance, 0.0, work)
        _, _, _, lo, hi, chir = kernels.pattern_windows(np.arange(3), dirs, tolerance,
                                                          0.0)
        rows = kernels._triangles(ix_scan, lo, hi, chir, 10**6, work)[0].tolist()
        found += [a, b, c] in rows
        made += 1
    assert made > 100 and found == made  # the scan finds every one; so does the look-up


def test_the_table_holds_every_triangle_of_the_index_in_its_cell():
    """Every three stars whose three pairs are in the index, once, in the cell of its
    sorted side angles, with each side's quantum within its cell (counted by brute force
    on a small catalogue)."""
    rng = np.random.default_rng(4)
    v = rng.normal(size=(250, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    index = PatternIndex.from_vectors(v, 0.45)
    t = triangle_index.triangle_table(index, 0.01)
    pairs = set(zip(index.pair_i.tolist(), index.pair_j.tolist(), strict=True))
    truth = {(i, j, k) for i, j, k in itertools.combinations(range(len(v)), 3)
             if (i, j) in pairs and (i, k) in pairs and (j, k) in pairs}
    stored = [tuple(r) for r in t["tri"][:, :3].tolist()]
    quanta = t["tri"][:, 3].astype(int)
    assert len(stored) == len(truth) and set(stored) == truth
    n, h = int(t["n_cells"]), float(t["cell_rad"])
    cells = np.repeat(np.arange(len(t["offs"]) - 1), np.diff(t["offs"]))
    Q = triangle_index.QUANTA
    for (i, j, k), cell, qs in zip(stored[::7], cells[::7], quanta[::7], strict=True):
        s1, s2, s3 = sorted(np.arccos(np.clip([v[i] @ v[j], v[i] @ v[k], v[j] @ v[k]],
                                              -1, 1)))
        c = [min(int(x / h), n - 1) for x in (s1, s2, s3)]
        assert cell == c[2] * (c[2] + 1) * (c[2] + 2) // 6 + c[1] * (c[1] + 1) // 2 + c[0]
        for x, ci, q in zip((s1, s2, s3), c, (qs & 31, (qs >> 5) & 31, qs >> 10),
                            strict=True):
            u = x / h
            assert ci + q / Q - 1e-9 <= u
            assert u < ci + (q + 1) / Q + 1e-9 or (ci == n - 1 and q == Q - 1)
    est = triangle_index.estimate_triangles(index)
    assert 0.5 * len(truth) < est < 2 * len(truth)


def test_no_table_past_its_size_bound(monkeypatch):
    rng = np.random.default_rng(3)
    v = rng.normal(size=(400, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    index = PatternIndex.from_vectors(v, 0.5)
    assert triangle_index.triangles_for(index, 1e-3) is not None
    monkeypatch.setenv("ADFUSION_TRIANGLES_MAX_MB", "0")
    assert triangle_index.triangles_for(index, 1e-3) is None


def test_the_sky_map_marks_every_direction_near_a_star():
    """Directions up to the map's radius from a star — anywhere on the sky, on cube
    edges and corners too — fall in marked cells; most of the sky does not."""
    rng = np.random.default_rng(8)
    corners = np.array(list(itertools.product((-1, 1), repeat=3)), float) / np.sqrt(3)
    edges = np.array([[1, 1, 0], [0, -1, 1], [-1, 0, -1]], float) / np.sqrt(2)
    v = np.vstack([rng.normal(size=(3000, 3)), corners, edges])
    v /= np.linalg.norm(v, axis=1)[:, None]
    radius = 1e-3
    words = kernels.sky_map(v, radius, 256)
    for _ in range(20):
        star = v[rng.integers(len(v))]
        # a direction at 0.999 radius from the star, any bearing
        e1 = np.cross(star, rng.normal(size=3))
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(star, e1)
        for phi in np.linspace(0, 2 * np.pi, 24, endpoint=False):
            a = 0.999 * radius
            r = np.cos(a) * star + np.sin(a) * (np.cos(phi) * e1 + np.sin(phi) * e2)
            assert kernels._sky_marked(words, 256, r)
    far = rng.normal(size=(20000, 3))
    marked = np.mean([kernels._sky_marked(words, 256, r) for r in far])
    assert marked < 0.5


def test_noise_frames_end_as_they_did_without_the_table_and_the_map(solver):
    """Frames of random detections spend the whole budget: with the triangle table and
    the sky map the same trials, weak candidates and p_false as without them."""
    bare = starid.Solver(solver.catalog, solver.camera)
    bare.search._triangles_done = True
    bare.search._ix = kernels.index_arrays(bare.index)
    rng = np.random.default_rng(21)
    cam = solver.camera
    for _ in range(25):
        xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1],
                         (int(rng.integers(4, 25)), 2))
        _same(solver.solve(xy), bare.solve(xy))
