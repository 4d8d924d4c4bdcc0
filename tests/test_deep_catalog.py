"""Deep catalogues and the cache: the pattern index against brute force, its memory bound,
epoch reuse, uniform sky coverage, LRU eviction, and the `cache` / `solve` commands."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from adfusion.starid.camera.view import stars_in_view
from adfusion.starid.catalog import cache
from adfusion.starid.catalog.coverage import coverage_indices, sky_cells, uniform_coverage
from adfusion.starid.catalog.pair_index import IndexTooLarge, PatternIndex, estimate_pairs

from adfusion import starid
from adfusion.app.cli import main
from adfusion.maths import rotations as rot


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("ADFUSION_CACHE_DIR", str(d))
    return d


def _random_sky(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_index_is_every_pair_within_the_separation_sorted():
    v = _random_sky(600)
    sep = math.radians(20.0)
    idx = PatternIndex.from_vectors(v, sep)
    cos = v @ v.T
    i, j = np.nonzero(np.triu(cos > math.cos(sep), k=1))
    assert {*zip(i.tolist(), j.tolist(), strict=True)} == \
        {*zip(idx.pair_i.tolist(), idx.pair_j.tolist(), strict=True)}
    assert np.all(np.diff(idx.pair_cos) <= 0)
    np.testing.assert_allclose(idx.pair_cos, cos[idx.pair_i, idx.pair_j], rtol=0, atol=1e-15)
    # CSR: row k holds k's neighbours in descending cosine; the bin table points at the
    # first entry of each angle bin
    step = sep / (idx.nbr_bin.shape[1] - 1)
    for k in (0, 17, 599):
        a, b = idx.nbr_ptr[k], idx.nbr_ptr[k + 1]
        row = idx.nbr_idx[a:b]
        assert sorted(row.tolist()) == sorted(np.flatnonzero(
            (cos[k] > math.cos(sep)) & (np.arange(600) != k)).tolist())
        assert np.all(np.diff(idx.nbr_cos[a:b]) <= 0)
        ang = np.arccos(np.clip(idx.nbr_cos[a:b], -1, 1))
        for e in (0, 100, 300, 511):
            assert idx.nbr_bin[k, e] == a + np.sum(ang < e * step)
        assert idx.nbr_bin[k, -1] == b


def test_index_too_large_fails_at_once_with_the_fix_named():
    cat = starid.Catalog.hipparcos(mag_limit=99.0)
    t0 = time.perf_counter()
    with pytest.raises(IndexTooLarge) as e:
        PatternIndex.from_vectors(cat.vectors, math.radians(45.0))
    assert time.perf_counter() - t0 < 10  # estimated from a sample, nothing allocated
    msg = str(e.value)
    assert "\n" not in msg and "GB" in msg and "ADFUSION_INDEX_MAX_GB" in msg
    assert "stars-per-fov" in msg


def test_pair_estimate_is_close_to_the_count():
    cat = starid.Catalog.hipparcos(mag_limit=6.0)
    sep = math.radians(12.0)
    true = PatternIndex.from_vectors(cat.vectors, sep).n_pairs
    assert estimate_pairs(cat.vectors, sep) == pytest.approx(true, rel=0.1)


def test_a_later_epoch_reuses_the_index_and_a_far_one_rebuilds_it(fresh_cache):
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    a = starid.Catalog.hipparcos(mag_limit=5.0, epoch=2026.0)
    b = starid.Catalog.hipparcos(mag_limit=5.0, epoch=2026.3)
    sa = starid.Solver(a, cam)
    files = sorted(fresh_cache.glob("pattern-index-*.npz"))
    assert len(files) == 1
    sb = starid.Solver(b, cam)
    assert sorted(fresh_cache.glob("pattern-index-*.npz")) == files
    np.testing.assert_array_equal(sb.index.pair_i, sa.index.pair_i)
    np.testing.assert_array_equal(sb.index.vectors, b.vectors)  # today's positions
    # a century on, stars moved by far more than 1″: rebuilt, in the same single file
    far = starid.Catalog.hipparcos(mag_limit=5.0, epoch=2126.0)
    assert np.degrees(np.max(np.linalg.norm(far.vectors - a.vectors, axis=1))) * 3600 > 100
    sf = starid.Solver(far, cam)
    assert sorted(fresh_cache.glob("pattern-index-*.npz")) == files
    np.testing.assert_allclose(
        sf.index.pair_cos, np.sum(far.vectors[sf.index.pair_i] * far.vectors[sf.index.pair_j],
                                  axis=1), atol=1e-15)
    # and the solution is the same star set's
    q = rot.q_cam_icrs_from_radec_roll(1.0, 0.4, 0.3)
    _, xy = stars_in_view(b, cam, q)
    assert sb.solve(xy).ok


def test_sky_cells_have_nearly_equal_area():
    cells = sky_cells(_random_sky(600_000, seed=1), 8)
    counts = np.bincount(cells, minlength=6 * 64)
    assert counts.min() > 0.7 * counts.mean() and counts.max() < 1.3 * counts.mean()


def test_coverage_keeps_the_brightest_per_cell():
    v = _random_sky(5000, seed=2)
    mag = np.random.default_rng(3).uniform(0, 10, 5000)
    keep = coverage_indices(v, mag, math.radians(10), 4)
    n_side = math.ceil(90 / 10)
    cells = sky_cells(v, n_side)
    for c in np.unique(cells)[:50]:
        members = np.flatnonzero(cells == c)
        expect = members[np.argsort(mag[members], kind="stable")[:4]]
        assert sorted(expect.tolist()) == sorted(np.intersect1d(keep, members).tolist())


def test_uniform_coverage_bounds_dense_fields_and_keeps_sparse_ones():
    full = starid.Catalog.hipparcos(mag_limit=9.0)
    cam = starid.Camera.pinhole(1280, 960, 6.0)
    sel = uniform_coverage(full, cam, 30)
    rng = np.random.default_rng(4)
    n_full, n_sel = [], []
    for _ in range(300):
        d = rng.normal(size=3)
        q = rot.q_cam_icrs_from_radec_roll(np.arctan2(d[1], d[0]),
                                           np.arcsin(d[2] / np.linalg.norm(d)), 0.0)
        n_full.append(len(stars_in_view(full, cam, q)[0]))
        n_sel.append(len(stars_in_view(sel, cam, q)[0]))
    n_full, n_sel = np.array(n_full), np.array(n_sel)
    # the Milky Way capped near 30 a field (a field overlaps parts of 6–12 cells), while
    # the full catalogue runs from ~25 to well over 100
    assert n_full.max() > 2.5 * n_sel.max() / 1.2 and n_sel.max() <= 2 * 30
    assert np.all(n_sel >= np.minimum(n_full, 20))  # no field left bare
    # and what is kept of a field are its brightest stars, not a random pick
    assert np.all(np.isin(sel.ids, full.ids))
    assert sel.mag.mean() < full.mag.mean()


def test_cache_evicts_the_least_recently_used(fresh_cache, monkeypatch):
    monkeypatch.setenv("ADFUSION_CACHE_MAX_MB", "2.5")  # room for two 1-MB entries

    def entry(k: int) -> dict:
        return cache.cached_arrays("demo", {"k": k}, [], lambda: {"x": np.zeros(125_000)})

    entry(1)
    time.sleep(0.02)
    entry(2)
    time.sleep(0.02)
    entry(1)  # used again: now 2 is the least recently used
    time.sleep(0.02)
    entry(3)
    kept = {e.path.name for e in cache.cache_info()}
    assert len(kept) == 2
    names = {k: f"demo-{cache.cache_key('demo', {'k': k}, [])}.npz" for k in (1, 2, 3)}
    assert kept == {names[1], names[3]}
    total = sum(e.size for e in cache.cache_info())
    assert total > 2_000_000 and cache.cache_clear() == (2, total)
    assert cache.cache_info() == []


def test_an_entry_over_the_cap_is_not_kept(fresh_cache, monkeypatch):
    monkeypatch.setenv("ADFUSION_CACHE_MAX_MB", "0.5")
    out = cache.cached_arrays("demo", {"k": 9}, [], lambda: {"x": np.ones(125_000)})
    assert out["x"].sum() == 125_000 and cache.cache_info() == []


def test_two_solves_leave_one_index_and_cache_commands(fresh_cache, capsys):
    for _ in range(2):  # the epoch defaults to "now": different on each call
        assert main(["solve", "--example", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["ok"]
    assert len(list(fresh_cache.glob("pattern-index-*.npz"))) == 1
    assert main(["cache", "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {e["kind"] for e in info["entries"]} >= {"pattern-index", "hip2-raw"}
    assert info["total_bytes"] == sum(e["bytes"] for e in info["entries"])
    assert main(["cache", "clear", "--kind", "pattern-index"]) == 0
    assert "removed 1 cache entry" in capsys.readouterr().out
    assert not list(fresh_cache.glob("pattern-index-*.npz"))
    # a kind that is not there is a usage error naming the kinds present, not "removed 0"
    assert main(["cache", "clear", "--kind", "pattern-indx"]) == 2
    err = capsys.readouterr().err
    assert "pattern-indx" in err and "hip2-raw" in err


def test_solve_with_every_hipparcos_star_fits_in_memory(capsys):
    # `--mag-limit 99` died in std::bad_alloc: the deep catalogue is thinned per sky cell
    assert main(["solve", "--example", "--mag-limit", "99", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] and res["error_vs_truth_arcsec"] < 10


@pytest.mark.parametrize("text, want", [("inf", 2**63 - 1), ("Infinity", 2**63 - 1),
                                        ("2", 2_000_000_000), ("nan", None), ("-1", None),
                                        ("lots", None)])
def test_a_size_limit_of_inf_is_no_limit_and_nan_an_error(monkeypatch, text, want):
    """``ADFUSION_INDEX_MAX_GB=inf`` ended a solve in an ``OverflowError`` (issue 33)."""
    from adfusion.starid.catalog.pair_index import max_index_bytes

    monkeypatch.setenv("ADFUSION_INDEX_MAX_GB", text)
    if want is None:
        with pytest.raises(ValueError, match="ADFUSION_INDEX_MAX_GB"):
            max_index_bytes()
    else:
        assert max_index_bytes() == want
