"""``adfusion bench sweep`` at a tiny size: every field of the JSON, the error-bound math,
the streaked-frame scoring, the tables and plots, the command line.

In-process (``workers=0``) and without cedar-solve (its venv is a pip install on first use);
tetra3rs joins when the ``bench`` extra is installed. A few seconds.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from adfusion.app.cli import main as cli_main
from adfusion.bench import starid as bs
from adfusion.bench import sweep as bench_sweep


def _solvers() -> list[str]:
    try:
        import tetra3rs  # noqa: F401
    except ImportError:
        return ["ours", "ours_tracking"]
    return ["ours", "ours_tracking", "tetra3rs"]


@pytest.fixture(scope="module")
def doc() -> dict:
    cfg = bench_sweep.SweepConfig(
        trials=3, chunk=2, sweeps=["n_false", "mag_limit", "rate_deg_s"],
        values={"n_false": (0.0, 3.0), "mag_limit": (4.0,), "rate_deg_s": (1.0,)},
        solvers=_solvers(), workers=0, progress=False)
    return bench_sweep.run_sweep(cfg)


def test_every_field(doc: dict) -> None:
    assert doc["schema"] == "adfusion.bench.sweep/1"
    assert {"machine", "code", "config", "solvers", "conversion_check", "campaign", "sweeps",
            "summary", "wall_s"} <= set(doc)
    assert doc["campaign"]["backend"] == "serial"
    assert [s["name"] for s in doc["sweeps"]] == ["n_false", "mag_limit", "rate_deg_s"]
    names = [p["name"] for s in doc["sweeps"] for p in s["points"]]
    assert names == ["n_false=0", "n_false=3", "mag_limit=4", "rate_deg_s=1"]
    for s in doc["sweeps"]:
        for p in s["points"]:
            assert p["trials"] == 3 and p["tolerance_px"] == 5.0
            assert set(p["results"]) == set(_solvers())
            for r in p["results"].values():
                assert r["n_frames"] == 3
                assert r["n_correct"] + r["n_wrong"] + r["n_failed"] == 3
                assert 0.0 <= r["availability_pct"] <= 100.0
                assert 0.0 <= r["error_rate_pct"] <= r["error_rate_upper95_pct"] <= 100.0
                assert set(r["time_ms"]) == {"median", "p95", "max"}
                t = r["time_ms"]
                assert 0.0 <= t["median"] <= t["p95"] <= t["max"]
    p3 = doc["sweeps"][0]["points"][1]
    assert p3["params"]["n_false"] == 3 and p3["centroids_per_frame_median"] >= 3
    assert doc["sweeps"][2]["points"][0]["params"]["rate_deg_s"] == 1.0
    assert doc["conversion_check"]["ours"]["passed"]
    s = doc["summary"]
    assert {"ours_wrong", "ours_max_error_rate_upper95_pct", "ours_off_mid_exposure",
            "points_where_a_peer_is_better"} <= set(s)
    assert s["ours_wrong"] == []


def test_clean_point_solves(doc: dict) -> None:
    clean = doc["sweeps"][0]["points"][0]["results"]
    assert clean["ours"]["n_correct"] == 3 and clean["ours_tracking"]["n_correct"] == 3


def test_error_bound_math(doc: dict) -> None:
    # 0 wrong of n: the one-sided 95 % Clopper–Pearson bound is 1 − 0.05^(1/n)
    r = doc["sweeps"][0]["points"][0]["results"]["ours"]
    assert r["error_rate_upper95_pct"] == pytest.approx(100 * (1 - 0.05 ** (1 / 3)), abs=1e-3)
    assert bs.clopper_pearson_upper(0, 1000) == pytest.approx(0.002991, abs=1e-6)
    from scipy.stats import binom

    for k, n in ((1, 1000), (4, 200)):  # P(X ≤ k | p = bound) = 5 %
        assert binom.cdf(k, n, bs.clopper_pearson_upper(k, n)) == pytest.approx(0.05, rel=1e-6)


def test_streaked_frame_scored_along_the_exposure() -> None:
    """A fix equal to the attitude at the end of the exposure (a fragment's instant) is the
    right identification: correct, but counted as off mid-exposure."""
    from adfusion import starid
    from adfusion.maths import rotations as rot

    cat = bs.load_catalog(5.0, 2025.0)
    cam = starid.Camera.pinhole(512, 384, fov_x_deg=15.0)
    f = bs.render_frame_for(cat, cam, bs.Condition("r", rate_deg_s=5.0), seed=0, index=2)
    q_end = rot.multiply(rot.exp_map(-f.omega_cam_rad_s * f.exposure_s / 2), f.q_cam_icrs)
    t = bs.score(f, bs.Outcome(True, q_end, 0.001), cam, 5.0)
    assert t.verdict == "correct" and t.error_px > 5.0 and t.error_path_px < 0.5
    a = bs.aggregate([t])
    assert a["n_off_mid_exposure"] == 1 and a["n_wrong"] == 0
    q_far = rot.multiply(rot.exp_map([0.0, 0.0, 0.05]), f.q_cam_icrs)  # 2.9° of roll
    assert bs.score(f, bs.Outcome(True, q_far, 0.001), cam, 5.0).verdict == "wrong"


def test_tables_and_plots(doc: dict, tmp_path: Path) -> None:
    text = bench_sweep.format_table(doc)
    assert "false stars per frame" in text and "wrong attitudes accepted" in text
    md = bench_sweep.markdown_tables(doc)
    assert md.count("| n_false |") == 1 and "ours (tracking)" in md
    files = bench_sweep.write_plots(doc, tmp_path)
    assert [f.name for f in files] == ["sweep-n_false.png", "sweep-mag_limit.png",
                                       "sweep-rate_deg_s.png"]
    assert all(f.stat().st_size > 10_000 for f in files)


def test_grid_and_estimate() -> None:
    full, quick = bench_sweep.SweepConfig(), bench_sweep.SweepConfig(quick=True)
    assert len(bench_sweep.points(full)) == 44 and len(bench_sweep.points(quick)) == 24
    # quick is a subset of the full grid: a full run reuses a quick run's partial file
    assert {c for _, _, c in bench_sweep.points(quick)} <= \
        {c for _, _, c in bench_sweep.points(full)}
    assert bench_sweep.estimate_seconds(full, 2) > bench_sweep.estimate_seconds(quick, 2)
    with pytest.raises(ValueError, match="unknown sweep"):
        bench_sweep.points(bench_sweep.SweepConfig(sweeps=["nope"]))


def test_command_line(tmp_path: Path) -> None:
    out = tmp_path / "s.json"
    buf, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(err):
        rc = cli_main(["bench", "sweep", "--trials", "2", "--sweeps", "mag_noise", "--solvers",
                       "ours", "--workers", "0", "--no-progress", "--json", str(out)])
    assert rc == 0, err.getvalue()
    assert "estimated" in err.getvalue() and "--quick" in err.getvalue()
    d = json.loads(out.read_text())
    assert [p["value"] for p in d["sweeps"][0]["points"]] == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert not Path(f"{out}.partial.jsonl").exists()
    assert np.isfinite(d["sweeps"][0]["points"][2]["results"]["ours"]["time_ms"]["median"])
    with contextlib.redirect_stderr(io.StringIO()) as e2:
        assert cli_main(["bench", "sweep", "--sweeps", "nope", "--workers", "0"]) == 2
    assert "unknown sweep" in e2.getvalue()
