"""The on-disk cache cannot be turned against its user (issue 33, item 4): every entry
carries a digest of its arrays, checked on load; an entry that was tampered with (its
arrays rewritten, the old digest kept), corrupted (one flipped byte) or truncated is rebuilt
with one warning naming the file — never trusted, never an exception — and the next run
uses the rewritten entry silently. Real Catalog and Solver code, a private cache folder."""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from adfusion.starid import rotations as rot
from adfusion.starid.catalog import cache

from adfusion import starid

EPOCH = 2025.0
MAG = 5.0
CAMERA = starid.Camera.pinhole(640, 480, 20.0)
Q_TRUE = rot.q_cam_icrs_from_radec_roll(math.radians(40.0), math.radians(60.0), 0.3)


def _use_cache(monkeypatch: pytest.MonkeyPatch, folder: Path) -> Path:
    monkeypatch.setenv("ADFUSION_CACHE_DIR", str(folder))
    return folder


def _entry(folder: Path, kind: str) -> Path:
    (path,) = folder.glob(f"{kind}-*.npz")
    return path


def _rewrite(path: Path, change) -> None:
    """Rewrite an entry's arrays as a bug or an attacker would: everything else stored
    (its digest too, whatever its name) is copied as it was."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    change(arrays)
    with path.open("wb") as f:
        np.savez(f, **arrays)


def _solve(catalog: starid.Catalog, xy: np.ndarray):
    return starid.Solver(catalog, CAMERA).solve(xy)


@pytest.fixture(scope="module")
def fresh(tmp_path_factory: pytest.TempPathFactory):
    """Catalogue and solution from an empty cache, and the true stars' pixels."""
    mp = pytest.MonkeyPatch()
    try:
        _use_cache(mp, tmp_path_factory.mktemp("fresh-cache"))
        cat = starid.Catalog.hipparcos(mag_limit=MAG, epoch=EPOCH)
        _, xy = starid.Solver(cat, CAMERA).stars_in_view(Q_TRUE)
        sol = _solve(cat, xy)
    finally:
        mp.undo()
    assert sol.ok and len(xy) >= 6
    return cat, xy[:12], sol


def _run(xy):
    """One run: the catalogue and a solution, with the cache's warnings recorded."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cat = starid.Catalog.hipparcos(mag_limit=MAG, epoch=EPOCH)
        sol = _solve(cat, xy)
    return cat, sol, [str(w.message) for w in caught if "cache" in str(w.message)]


def _same(a: starid.Catalog, b: starid.Catalog) -> None:
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.vectors, b.vectors)
    np.testing.assert_array_equal(a.mag, b.mag)


def _shift_ra(arrays: dict) -> None:
    arrays["ra"] = arrays["ra"] + math.radians(1.0)


def _drop_bv(arrays: dict) -> None:
    del arrays["bv"]


def _scale_pairs(arrays: dict) -> None:
    arrays["pair_cos"] = np.cos(np.arccos(np.clip(arrays["pair_cos"], -1, 1)) * 1.01)


@pytest.mark.parametrize(("kind", "change"), [("hip2-raw", _shift_ra), ("hip2-raw", _drop_bv),
                                              ("pattern-index", _scale_pairs)])
def test_a_tampered_entry_is_rebuilt_not_trusted(fresh, tmp_path, monkeypatch, kind, change):
    fresh_cat, xy, fresh_sol = fresh
    folder = _use_cache(monkeypatch, tmp_path / "cache")
    _run(xy)  # fills the cache
    entry = _entry(folder, kind)
    _rewrite(entry, change)  # every RA 1° off (or an array gone), the old digest kept
    cat, sol, said = _run(xy)
    _same(cat, fresh_cat)
    assert sol.ok and rot.angle_between(sol.q_cam_icrs, fresh_sol.q_cam_icrs) < 1e-9
    assert rot.angle_between(sol.q_cam_icrs, Q_TRUE) < 1e-6  # not 1° off
    assert len(said) == 1 and entry.name in said[0] and "rebuilt" in said[0], said
    # rewritten: the next run is silent and reads the same
    cat2, sol2, said2 = _run(xy)
    assert said2 == [] and sol2.ok
    _same(cat2, fresh_cat)


def _flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])


@pytest.mark.parametrize("damage", [_flip_byte, _truncate], ids=["flipped-byte", "truncated"])
@pytest.mark.parametrize("kind", ["hip2-raw", "pattern-index"])
def test_a_damaged_entry_is_rebuilt_with_one_warning(fresh, tmp_path, monkeypatch, damage,
                                                     kind):
    fresh_cat, xy, fresh_sol = fresh
    folder = _use_cache(monkeypatch, tmp_path / "cache")
    _run(xy)
    entry = _entry(folder, kind)
    damage(entry)
    cat, sol, said = _run(xy)  # no exception: a miss, rebuilt
    assert len(said) == 1 and str(entry) in said[0] and "rebuilt" in said[0], said
    _same(cat, fresh_cat)
    assert sol.ok and rot.angle_between(sol.q_cam_icrs, fresh_sol.q_cam_icrs) < 1e-9
    inode = entry.stat().st_ino
    cat2, sol2, said2 = _run(xy)
    assert said2 == [] and sol2.ok
    _same(cat2, fresh_cat)
    assert entry.stat().st_ino == inode  # the rewritten entry was used, not written again
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        e.path.name for e in cache.cache_info())  # no temporary left behind


def test_an_entry_without_a_digest_is_rebuilt(tmp_path, monkeypatch):
    """An entry from before digests (or one stripped of it) is a miss, never trusted."""
    folder = _use_cache(monkeypatch, tmp_path / "cache")
    build = lambda: {"x": np.arange(5)}  # noqa: E731
    cache.cached_arrays("demo", {"k": 1}, [], build)
    entry = _entry(folder, "demo")
    with entry.open("wb") as f:
        np.savez(f, x=np.arange(5) + 1)  # the old format: arrays only
    assert cache.cached_arrays("demo", {"k": 1}, [], build)["x"].tolist() == [0, 1, 2, 3, 4]
    assert cache.cached_arrays("demo", {"k": 1}, [], lambda: 1 / 0)["x"].tolist() == [
        0, 1, 2, 3, 4]  # rewritten with a digest: a hit now


def test_a_cache_folder_that_cannot_be_made_names_the_variable(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    _use_cache(monkeypatch, blocker / "cache")
    with pytest.raises(OSError, match="ADFUSION_CACHE_DIR"):
        cache.cached_arrays("demo", {"k": 1}, [], lambda: {"x": np.arange(3)})


def test_a_cache_folder_that_cannot_be_written_names_the_variable(tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("permissions are not enforced for this user (root)")
        _use_cache(monkeypatch, ro)
        with pytest.raises(OSError, match="ADFUSION_CACHE_DIR"):
            cache.cached_arrays("demo", {"k": 1}, [], lambda: {"x": np.arange(3)})
    finally:
        ro.chmod(0o700)
