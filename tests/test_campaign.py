"""``adfusion.bench.campaign``: the same results on any number of dask workers, a lost worker
costs only its in-flight task, and a rerun computes only what its partial file lacks.

The dask tests need ``dask[distributed]`` (the ``dist`` extra; the ``test`` extra installs
it too, so CI runs them) and start real local clusters: a few seconds each.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from adfusion.bench import campaign
from adfusion.bench import sweep as bench_sweep


def test_serial_campaign_in_task_order(tmp_path: Path) -> None:
    tasks = [campaign.Task(f"k{i}", i, weight=2) for i in (3, 1, 2)]
    r = campaign.run_campaign(campaign.square, tasks, workers=0, progress=False,
                              partial=tmp_path / "p.jsonl")
    assert list(r.results.items()) == [("k3", 9), ("k1", 1), ("k2", 4)]
    assert r.backend == "serial" and r.resumed == 0
    assert not (tmp_path / "p.jsonl").exists()  # removed after a complete run


def test_duplicate_keys_rejected() -> None:
    with pytest.raises(ValueError, match="unique"):
        campaign.run_campaign(campaign.square, [campaign.Task("a", 1), campaign.Task("a", 2)],
                              workers=0, progress=False)


def flaky(payload: tuple[str, int]) -> int:
    """Fails for i while ``fail-i`` exists in the folder; logs every call."""
    folder, i = payload
    with open(os.path.join(folder, "calls"), "a") as f:
        f.write(f"{i}\n")
    if os.path.exists(os.path.join(folder, f"fail-{i}")):
        raise RuntimeError(f"task {i} told to fail")
    return 10 * i


def test_failed_task_reported_rest_kept_and_resumed(tmp_path: Path) -> None:
    folder, partial = str(tmp_path), tmp_path / "p.jsonl"
    tasks = [campaign.Task(f"t{i}", (folder, i)) for i in range(5)]
    (tmp_path / "fail-2").touch()
    with pytest.raises(campaign.CampaignError, match="t2") as e:
        campaign.run_campaign(flaky, tasks, workers=0, progress=False, partial=partial)
    assert set(e.value.failed) == {"t2"}
    kept = [json.loads(line)["key"] for line in partial.read_text().splitlines()]
    assert kept == ["t0", "t1", "t3", "t4"]
    (tmp_path / "fail-2").unlink()
    (tmp_path / "calls").unlink()
    r = campaign.run_campaign(flaky, tasks, workers=0, progress=False, partial=partial)
    assert (tmp_path / "calls").read_text().split() == ["2"]  # only the missing one ran
    assert r.resumed == 4 and list(r.results.values()) == [0, 10, 20, 30, 40]
    # a changed task is not taken from the file
    r2 = campaign.run_campaign(flaky, [campaign.Task("t0", (folder, 7))], workers=0,
                               progress=False)
    assert r2.results == {"t0": 70}


def test_without_dask_runs_serially_with_a_note() -> None:
    """dask is an optional extra: without it a campaign still runs, in-process, and says so
    (a fresh interpreter in which ``distributed`` cannot be imported)."""
    import subprocess

    code = ("import sys; sys.modules['distributed'] = None\n"
            "from adfusion.bench import campaign\n"
            "r = campaign.run_campaign(campaign.square, [campaign.Task('a', 3)], workers=2,"
            " progress=False)\n"
            "print(r.backend, r.results['a'])")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[1], timeout=60, check=False)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["serial", "9"]
    assert "dask is not installed" in p.stderr and "adfusion[dist]" in p.stderr


def test_strip_measured() -> None:
    doc = {"a": 1, "time_ms": {"median": 2.0}, "pts": [{"wall_s": 3.0, "n": 4}]}
    assert campaign.strip_measured(doc) == {"a": 1, "pts": [{"n": 4}]}


# --- on dask.distributed -----------------------------------------------------------------------


def die_once(payload: tuple[str, int]) -> int:
    """Kills its worker process the first time task 3 runs (a real worker loss)."""
    marker, i = payload
    if i == 3 and not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return i * i


def _tiny_sweep(workers: int) -> dict:
    solvers = ["ours", "ours_tracking"]
    try:
        import tetra3rs  # noqa: F401

        solvers.append("tetra3rs")
    except ImportError:
        pass
    cfg = bench_sweep.SweepConfig(
        trials=4, chunk=2, sweeps=["n_false", "rate_deg_s"],
        values={"n_false": (0.0, 4.0), "rate_deg_s": (2.0,)}, solvers=solvers,
        workers=workers, progress=False)
    return bench_sweep.run_sweep(cfg)


def test_same_json_on_1_and_2_workers() -> None:
    """The acceptance check: a sweep campaign (3 points × 4 trials, rendered frames among
    them) gives identical results on 1 and 2 dask workers and serially."""
    pytest.importorskip("distributed", reason="dask[distributed] (the 'dist' extra) missing")
    one, two = _tiny_sweep(1), _tiny_sweep(2)
    assert one["campaign"]["backend"] == two["campaign"]["backend"] == "dask-local"
    assert (one["campaign"]["workers"], two["campaign"]["workers"]) == (1, 2)
    a, b = campaign.strip_measured(one), campaign.strip_measured(two)
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert a["sweeps"][0]["points"][1]["results"]["ours"]["n_frames"] == 4
    serial = campaign.strip_measured(_tiny_sweep(0))
    assert json.dumps(serial, sort_keys=True) == json.dumps(a, sort_keys=True)


def test_worker_loss_loses_only_in_flight_work(tmp_path: Path) -> None:
    pytest.importorskip("distributed", reason="dask[distributed] (the 'dist' extra) missing")
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers need not import us
    marker = str(tmp_path / "killed")
    tasks = [campaign.Task(f"t{i}", (marker, i)) for i in range(6)]
    r = campaign.run_campaign(die_once, tasks, workers=2, progress=False,
                              partial=tmp_path / "p.jsonl")
    assert os.path.exists(marker)  # a worker really died
    assert list(r.results.values()) == [0, 1, 4, 9, 16, 25]
    assert r.backend == "dask-local"
