"""Benchmark the attitude filters against peers on the same gyro + magnetometer data.

One simulated LEO run (Crassidis & Junkins Ex. 7.1 gyro: ARW √10·10⁻⁷ rad/√s, RRW
√10·10⁻¹⁰ rad/s^{3/2}, bias 0.1 °/h per axis; orbital-rate pitch 0.0011 rad/s; a tilted-dipole
field direction sampled along a 51.6° orbit with 0.5° noise; 1 Hz, one orbit by default;
initial attitude error 5°). Each filter does, per sample, one gyro propagation and one
magnetometer direction update:

* ``mekf`` — :class:`adfusion.MEKF` (``propagate`` + ``update_vector``);
* ``ukf`` — :class:`adfusion.UKF` (USQUE on filterpy's ``UnscentedKalmanFilter``);
* ``ahrs_ekf`` — ``ahrs.filters.EKF`` (4-state quaternion EKF, no bias state), its ``update``
  with the field direction in the accelerometer slot and its reference set to the current
  ICRS field direction each step (it has no other way to take a moving reference);
* ``filterpy_ekf`` — a plain ``filterpy.kalman.ExtendedKalmanFilter`` with the same 6-state
  error model (Φ and Q from :mod:`adfusion.estimation.mekf`, the same quaternion arithmetic
  and reset),
  so the difference to ``mekf`` is the Kalman machinery alone.

Timing rounds are interleaved (each round runs every filter over the whole data, in rotating
order) so that a busy machine slows them alike, and are tight loops (the attitude is read and
scored in a separate pass: other code run between the steps evicts caches and slows every
filter by tens of per cent here). The median over all steps of all rounds is reported with the ratio
ours / peer, and the accuracy (RMS attitude error after a 10-minute burn-in, and at the end)
of each filter on the data.

Replay throughput (:func:`replay_throughput`, ``--replay-duration S``; 0 skips it): an
OEDIPUS-C-like flight (``sensors.scenarios.oedipus``, 30 fps, 200 Hz gyro, magnetometer)
simulated into an MCAP log — rendered intensified frames, and centroid-only — then replayed
through ``adfusion.app.pipeline.replay`` (detection, identification, MEKF, MCAP writing):
frames per second end to end and the attitude error against the log's truth.

Usage (from the repository root)::

    /tmp/venv/bin/python benchmarks/bench_filters.py [--rounds 3] [--steps 5712]
                                                     [--replay-duration 20]

Example:
    >>> r = run(rounds=1, steps=50)
    >>> "mekf" in r["median_us"], r["steps"], r["final_err_deg"]["mekf"] < 5.0
    (True, 50, True)
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.bench.machine import machine_info
from adfusion.estimation.common import tangent_basis
from adfusion.estimation.mekf import MEKF, process_noise, transition_matrix
from adfusion.estimation.ukf import UKF
from adfusion.maths import rotations as rot

try:
    from ahrs.filters import EKF as AhrsEKF
except ImportError:  # optional peer: pip install ahrs
    AhrsEKF = None

SIGMA_V = math.sqrt(10.0) * 1e-7
SIGMA_U = math.sqrt(10.0) * 1e-10
DEG_PER_H = math.radians(1.0) / 3600.0
MAG_SIGMA = math.radians(0.5)
SIGMA_ATT0 = math.radians(5.0)
SIGMA_BIAS0 = 0.2 * DEG_PER_H
ORBIT_STEPS = int(2 * math.pi / 0.0011)

Step = Callable[[int], None]


def simulate(steps: int, dt: float = 1.0, seed: int = 1) -> dict[str, np.ndarray]:
    """Truth, gyro (sample k covers (k−1, k]) and field directions (body and ICRS)."""
    rng = np.random.default_rng(seed)
    omega = np.array([0.0, 0.0011, 0.0])
    t = np.arange(steps + 1) * dt
    q0 = rot.normalize([0.9, 0.1, -0.3, 0.3])
    q = rot.multiply(rot.exp_map(-t[:, None] * omega), q0)
    bias = np.full(3, 0.1 * DEG_PER_H) + np.concatenate(
        [np.zeros((1, 3)), np.cumsum(SIGMA_U * math.sqrt(dt) * rng.standard_normal((steps, 3)), 0)])
    gyro = np.zeros((steps + 1, 3))
    gyro[1:] = omega + 0.5 * (bias[1:] + bias[:-1]) + math.sqrt(
        SIGMA_V**2 / dt + SIGMA_U**2 * dt / 12) * rng.standard_normal((steps, 3))  # fmt: skip
    n, inc, tilt, w_e = 0.0011, math.radians(51.6), math.radians(11.0), 7.292e-5
    r = np.stack([np.cos(n * t), np.sin(n * t) * math.cos(inc), np.sin(n * t) * math.sin(inc)], -1)
    m = np.stack([math.sin(tilt) * np.cos(w_e * t), math.sin(tilt) * np.sin(w_e * t),
                  np.full_like(t, math.cos(tilt))], -1)  # fmt: skip
    ref = 3 * np.sum(m * r, -1, keepdims=True) * r - m
    ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
    noise = rot.exp_map(MAG_SIGMA * rng.standard_normal((steps + 1, 3)))
    meas = rot.rotate(rot.multiply(noise, q), ref)
    q_init = rot.multiply(rot.exp_map(SIGMA_ATT0 * np.array([1.0, -2.0, 2.0]) / 3.0), q[0])
    return {"dt": np.array(dt), "q": q, "bias": bias, "gyro": gyro, "ref": ref, "meas": meas,
            "q_init": q_init}  # fmt: skip


# --- the filters, each as (step function, attitude read-out) ------------------------------


def _ours(cls: type, d: dict[str, np.ndarray]) -> tuple[Step, Callable[[], np.ndarray]]:
    f = cls(d["q_init"], SIGMA_ATT0, SIGMA_BIAS0, SIGMA_V, SIGMA_U)
    dt, gyro, meas, ref = float(d["dt"]), d["gyro"], d["meas"], d["ref"]

    def step(k: int) -> None:
        f.propagate(dt, gyro[k])
        f.update_vector(meas[k], ref[k], MAG_SIGMA)

    return step, lambda: f.q_body_icrs


def _ahrs(d: dict[str, np.ndarray]) -> tuple[Step, Callable[[], np.ndarray]]:
    dt = float(d["dt"])
    # ahrs: q is body → reference (q_icrs_body); Q = var_gyr·W Wᵀ per step, so var_gyr is the
    # per-sample rate variance; R = var_acc·I on the unit "acceleration" (our field direction)
    ekf = AhrsEKF(frequency=1.0 / dt, noises=[SIGMA_V**2 / dt, MAG_SIGMA**2, MAG_SIGMA**2],
                  P=np.eye(4) * (SIGMA_ATT0 / 2) ** 2)  # fmt: skip
    state = {"q": rot.inverse(d["q_init"])}
    gyro, meas, ref = d["gyro"], d["meas"], d["ref"]

    def step(k: int) -> None:
        ekf.a_ref = ref[k]
        state["q"] = ekf.update(state["q"], gyro[k], meas[k], dt=dt)

    return step, lambda: rot.inverse(state["q"])


def _filterpy(d: dict[str, np.ndarray]) -> tuple[Step, Callable[[], np.ndarray]]:
    from filterpy.kalman import ExtendedKalmanFilter

    ekf = ExtendedKalmanFilter(dim_x=6, dim_z=2)
    ekf.x = np.zeros(6)  # 1-D state (filterpy's default is a column)
    ekf.P = np.diag([SIGMA_ATT0**2] * 3 + [SIGMA_BIAS0**2] * 3)
    dt = float(d["dt"])
    ekf.Q = process_noise(dt, SIGMA_V, SIGMA_U)
    r2 = np.eye(2) * MAG_SIGMA**2
    st: dict[str, Any] = {"q": tuple(d["q_init"].tolist()), "b": np.zeros(3)}
    gyro, meas, ref = d["gyro"], d["meas"], d["ref"]

    def step(k: int) -> None:
        w = gyro[k] - st["b"]
        tx, ty, tz = (w * dt).tolist()
        st["q"] = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(-tx, -ty, -tz), st["q"]))
        ekf.F = transition_matrix(w, dt)
        ekf.predict()
        e1, e2 = tangent_basis(*rot.rotate_floats(st["q"], tuple(ref[k].tolist())))
        h = np.zeros((2, 6))
        h[0, :3], h[1, :3] = e2, (-e1[0], -e1[1], -e1[2])
        z = np.array([np.dot(e1, meas[k]), np.dot(e2, meas[k])])
        ekf.update(z, HJacobian=lambda _x: h, Hx=lambda x: h @ x, R=r2)
        dx = ekf.x.tolist()
        step = rot.exp_map_floats(dx[0], dx[1], dx[2])
        st["q"] = rot.normalize_floats(rot.hamilton(step, st["q"]))
        st["b"] = st["b"] + ekf.x[3:]
        ekf.x[:] = 0.0  # the reset: error state back to zero

    return step, lambda: np.array(st["q"])


def _filters(d: dict[str, np.ndarray]) -> dict[str, Callable[[], tuple[Step, Any]]]:
    out: dict[str, Callable[[], tuple[Step, Any]]] = {
        "mekf": lambda: _ours(MEKF, d),
        "ukf": lambda: _ours(UKF, d),
        "filterpy_ekf": lambda: _filterpy(d),
    }
    if AhrsEKF is not None:
        out["ahrs_ekf"] = lambda: _ahrs(d)
    return out


def run(rounds: int = 3, steps: int = ORBIT_STEPS, seed: int = 1) -> dict[str, Any]:
    """Time and score every filter; returns the JSON-able report."""
    d = simulate(steps, seed=seed)
    makers = _filters(d)
    names = list(makers)
    times: dict[str, list[int]] = {n: [] for n in names}
    err_deg: dict[str, np.ndarray] = {}
    for name in names:  # accuracy: one pass, reading the attitude after every step
        step, attitude = makers[name]()
        errs = np.empty(steps)
        for k in range(1, steps + 1):
            step(k)
            errs[k - 1] = rot.angle_between(d["q"][k], attitude())
        err_deg[name] = np.degrees(errs)
    clock = time.perf_counter_ns
    for r in range(rounds):  # timing: tight loops, nothing else between the steps
        for name in names[r % len(names):] + names[: r % len(names)]:
            step, _ = makers[name]()
            t_ns = times[name]
            for k in range(1, steps + 1):
                t0 = clock()
                step(k)
                t_ns.append(clock() - t0)
    med = {n: statistics.median(times[n]) / 1e3 for n in names}
    burn = min(600, steps // 2)
    ratios = {f"{ours}/{peer}": med[ours] / med[peer]
              for ours in ("mekf", "ukf") for peer in names if peer not in ("mekf", "ukf")}
    return {
        "scenario": "LEO gyro (C&J Ex. 7.1) + magnetometer direction (0.5 deg), 1 Hz, "
                    "initial error 5 deg; one propagate + one vector update per step",
        "steps": steps,
        "rounds": rounds,
        "median_us": {n: round(v, 2) for n, v in med.items()},
        "p90_us": {n: round(float(np.percentile(times[n], 90)) / 1e3, 2) for n in names},
        "ratio_ours_over_peer": {k: round(v, 3) for k, v in ratios.items()},
        "rms_err_deg_after_burn_in": {n: float(np.sqrt(np.mean(e[burn:] ** 2)))
                                      for n, e in err_deg.items()},
        "final_err_deg": {n: float(e[-1]) for n, e in err_deg.items()},
        "burn_in_steps": burn,
        "skipped": [] if AhrsEKF is not None else ["ahrs_ekf (ahrs not importable)"],
        "machine": machine_info(),
    }  # fmt: skip


def replay_throughput(duration_s: float = 20.0, seed: int = 0) -> dict[str, Any]:
    """Simulate an OEDIPUS-like flight (rendered and centroid-only) and replay both logs:
    frames/s end to end, identified frames, attitude error vs truth (deg)."""
    import tempfile

    from adfusion.sensors.scenarios import oedipus

    from adfusion.app.pipeline import replay, simulate

    out: dict[str, Any] = {"scenario": f"oedipus, {duration_s:g} s, seed {seed}"}
    with tempfile.TemporaryDirectory(prefix="adfusion-bench-") as tmp:
        for name, render in (("rendered", True), ("centroids", False)):
            sim, rep = Path(tmp) / f"{name}.mcap", Path(tmp) / f"{name}-replay.mcap"
            simulate(oedipus(duration_s=duration_s, seed=seed, render=render), sim)
            d = replay(sim, rep, progress=False).as_dict()
            out[name] = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in d.items()
                         if k in ("frames", "identified", "modes", "rejected_fixes",
                                  "error_rms_deg", "error_max_deg", "frames_per_s", "wall_s")}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=ORBIT_STEPS)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--replay-duration", type=float, default=20.0,
                    help="seconds of simulated flight for the replay throughput (0: skip)")
    args = ap.parse_args()
    doc = run(args.rounds, args.steps, args.seed)
    doc["steps_per_s"] = {n: round(1e6 / v) for n, v in doc["median_us"].items()}
    if args.replay_duration > 0:
        doc["replay"] = replay_throughput(args.replay_duration)
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
