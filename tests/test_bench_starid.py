"""Smoke tests of ``adfusion.bench.starid`` (the ``adfusion bench starid`` benchmark).

Small on purpose (a few seconds): 2 conditions × 5 frames with our solver, the JSON layout,
the statistics helpers, and — when tetra3rs is installed — its centroid/attitude conversion.
"""

from __future__ import annotations

import contextlib
import doctest
import io
import json

import numpy as np
import pytest

from adfusion.bench import starid as bench


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str, str]:
    """One run through the command-line entry point: clean + false3, 5 frames, ours only."""
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = bench.main(["--frames", "5", "--conditions", "clean,false3", "--solvers", "ours",
                         "--seed", "3", "--no-progress", "--json", str(out)])
    assert rc == 0
    return json.loads(out.read_text()), buf.getvalue(), str(out)


def test_json_structure(smoke: tuple[dict, str, str]) -> None:
    doc, _, _ = smoke
    assert doc["schema"] == "adfusion.bench.starid/1"
    assert {"machine", "config", "solvers", "conversion_check", "conditions"} <= set(doc)
    assert doc["config"]["frames"] == 5 and doc["config"]["solvers"] == ["ours"]
    assert [c["name"] for c in doc["conditions"]] == ["clean", "false3"]
    ours = doc["solvers"]["ours"]
    assert ours["status"] == "ok"
    idx = next(iter(ours["indexes"].values()))
    assert idx["index_nbytes"] > 0 and idx["index_build_s"] >= 0
    assert doc["conversion_check"]["ours"]["passed"]
    for c in doc["conditions"]:
        assert c["frames"] == 5
        r = c["results"]["ours"]
        assert r["n_frames"] == 5
        assert r["n_correct"] + r["n_wrong"] + r["n_failed"] == 5
        assert set(r["time_ms"]) == {"median", "p95", "max"}
        assert 0 < r["time_ms"]["median"] <= r["time_ms"]["p95"] <= r["time_ms"]["max"]
        assert 0.0 <= r["error_rate_pct"] <= r["error_rate_upper95_pct"] <= 100.0
        assert {"availability_ge3_pct", "availability_ge4_pct", "frames_ge3_stars",
                "wrong_frames", "failed_frames", "slowest_frames"} <= set(r)
        assert c["time_ratio_ours_over_peer"] == {}
    false3 = doc["conditions"][1]
    assert false3["params"]["n_false"] == 3


def test_clean_condition_solves(smoke: tuple[dict, str, str]) -> None:
    doc, _, _ = smoke
    clean = doc["conditions"][0]["results"]["ours"]
    assert clean["n_correct"] >= 4, clean
    assert clean["n_wrong"] == 0, clean["wrong_frames"]


def test_table_printed(smoke: tuple[dict, str, str]) -> None:
    _, text, _ = smoke
    assert "Star identification benchmark" in text
    assert "clean" in text and "false3" in text and "index" in text


def test_frames_are_reproducible_and_shared() -> None:
    from adfusion import starid
    cat = bench.load_catalog(6.0, 2025.0)
    cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    clean = bench.CONDITIONS["clean"].resolved(0.1, 6.0)
    false8 = bench.CONDITIONS["false8"].resolved(0.1, 6.0)
    a = bench.make_frame(cat, cam, clean, seed=1, index=4)
    b = bench.make_frame(cat, cam, clean, seed=1, index=4)
    c = bench.make_frame(cat, cam, false8, seed=1, index=4)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.q_cam_icrs, c.q_cam_icrs)  # same sky in every condition
    assert int(np.count_nonzero(c.cat_ids < 0)) == 8
    assert cam.in_frame(c.xy).all()


def test_clopper_pearson() -> None:
    assert bench.clopper_pearson_upper(0, 200) == pytest.approx(1 - 0.05 ** (1 / 200))
    assert bench.clopper_pearson_upper(3, 100) == pytest.approx(0.0757, abs=5e-4)
    assert bench.clopper_pearson_upper(7, 7) == 1.0


def test_unknown_names_rejected() -> None:
    with pytest.raises(ValueError, match="unknown condition"):
        bench.run_benchmark(bench.BenchConfig(frames=1, conditions=["nope"], solvers=["ours"]))
    with pytest.raises(ValueError, match="unknown solver"):
        bench.run_benchmark(bench.BenchConfig(frames=1, conditions=["clean"],
                                              solvers=["nope"], progress=False))


def test_tetra3rs_conversion() -> None:
    """Centroid and attitude conventions of the tetra3rs adapter (skipped without the
    ``bench`` extra)."""
    pytest.importorskip("tetra3rs", reason="tetra3rs (the 'bench' extra) is not installed")
    doc = bench.run_benchmark(bench.BenchConfig(frames=3, conditions=["clean"],
                                                solvers=["ours", "tetra3rs"], progress=False))
    chk = doc["conversion_check"]["tetra3rs"]
    assert chk["passed"] and chk["max_error_arcsec"] < 10.0, chk
    r = doc["conditions"][0]["results"]["tetra3rs"]
    assert r["n_correct"] >= 2 and r["n_wrong"] == 0
    assert doc["conditions"][0]["time_ratio_ours_over_peer"]["tetra3rs"] > 0
    db = next(iter(doc["solvers"]["tetra3rs"]["databases"].values()))
    assert db["file_bytes"] > 0


def test_doctests() -> None:
    for module in (bench, bench.frames, bench.peers, bench.report, bench.driver):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.failed == 0, module.__name__


def test_methods_compares_our_matchers_on_the_same_frames() -> None:
    """``--methods nstar,bleif``: both of our matchers on the same frames, one table row
    each, and neither accepts a wrong attitude on clean frames."""
    p = __import__("argparse").ArgumentParser()
    bench.add_arguments(p)
    args = p.parse_args(["--frames", "3", "--conditions", "clean", "--methods", "nstar,bleif",
                         "--seed", "5", "--no-progress"])
    cfg = bench.config_from_args(args)
    assert cfg.solvers == ["ours", "ours_bleif"]
    doc = bench.run_benchmark(cfg)
    res = doc["conditions"][0]["results"]
    assert set(res) == {"ours", "ours_bleif"}
    for r in res.values():
        assert r["n_frames"] == 3 and r["error_rate_pct"] == 0.0
    assert res["ours_bleif"]["availability_pct"] == 100.0
    assert "ours_bleif" in bench.format_table(doc)
    with pytest.raises(ValueError, match="unknown method"):
        bench.config_from_args(p.parse_args(["--methods", "nstar,pyramid"]))


def test_hot_repeats_leave_the_first_solves_as_they_were() -> None:
    """``--hot N``: each frame solved N more times, the last one's CPU time reported per
    condition beside the ratio to the peers — the frames, outcomes and error counts of the
    first solves (the table's) are those of a run without it."""
    p = __import__("argparse").ArgumentParser()
    bench.add_arguments(p)
    base = ["--frames", "4", "--conditions", "clean,false3", "--solvers", "ours",
            "--seed", "11", "--no-progress"]
    cold = bench.run_benchmark(bench.config_from_args(p.parse_args(base)))
    hot = bench.run_benchmark(bench.config_from_args(p.parse_args([*base, "--hot", "2"])))
    assert hot["config"]["hot_repeats"] == 2
    for c0, c1 in zip(cold["conditions"], hot["conditions"], strict=True):
        assert "hot_cpu_time_ms" not in c0
        r0, r1 = c0["results"]["ours"], c1["results"]["ours"]
        for key in ("n_correct", "n_wrong", "n_failed", "availability_pct"):
            assert r0[key] == r1[key], key
        t = c1["hot_cpu_time_ms"]["ours"]
        assert 0 < t["median"] <= t["p95"] <= t["max"]
    assert "solved again (2×" in bench.format_table(hot)
