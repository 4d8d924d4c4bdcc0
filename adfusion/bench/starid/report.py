"""The figures and the table of ``adfusion bench starid``: scoring and reporting.

:func:`score` judges one solve against the frame's truth (:func:`frame_error_px`, the shift
of the frame's corners and centre) into a :class:`Trial`; :func:`aggregate` (and
:func:`summarize`, from outcomes) gives one solver's figures over a condition —
availability, error rate with its Clopper–Pearson bound (:func:`clopper_pearson_upper`),
times — and :func:`time_ratios` our time over each peer's; :func:`format_table` is the
human-readable report of a run's result document.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.bench.starid.frames import CONDITIONS, Condition, Frame
from adfusion.bench.starid.peers import Outcome

# --- statistics --------------------------------------------------------------------------


def clopper_pearson_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper–Pearson upper bound of a binomial proportion (k of n).

    >>> round(clopper_pearson_upper(0, 100), 6) == round(1 - 0.05 ** (1 / 100), 6)
    True
    >>> clopper_pearson_upper(5, 5)
    1.0
    """
    from scipy.stats import beta

    if n <= 0:
        return 1.0
    if k >= n:
        return 1.0
    return float(beta.ppf(confidence, k + 1, n - k))


def _r(fn: Any, x: NDArray[np.float64], nd: int = 3) -> float | None:
    if len(x) == 0:
        return None
    v = float(fn(x))
    return round(v, nd) if np.isfinite(v) else None


def _pct(k: int, n: int) -> float | None:
    return None if n == 0 else round(100.0 * k / n, 3)


def _time_stats(t_s: Sequence[float]) -> dict[str, float | None]:
    if len(t_s) == 0:
        return {"median": None, "p95": None, "max": None}
    t = np.asarray(t_s) * 1e3
    return {"median": round(float(np.median(t)), 4), "p95": round(float(np.percentile(t, 95)), 4),
            "max": round(float(np.max(t)), 4)}


# --- scoring -----------------------------------------------------------------------------


def frame_error_px(q_est: NDArray[np.float64], q_true: NDArray[np.float64], camera) -> float:
    """Largest pixel shift of the frame's corners and centre between two attitudes.

    The directions the true attitude puts at the four corners and the centre are projected
    with the estimate; ``inf`` if one falls behind the camera.

    >>> from adfusion import starid
    >>> from adfusion.starid import rotations as rot
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> q = rot.q_cam_icrs_from_radec_roll(0.1, 0.2, 0.3)
    >>> dq = rot.exp_map([0.0, 0.0, np.radians(0.1)])      # 0.1° of roll
    >>> round(frame_error_px(rot.multiply(dq, q), q, cam), 2)
    1.12
    """
    from adfusion.maths import rotations as rot

    xy = np.vstack([camera.corners(), [[camera.K[0, 2], camera.K[1, 2]]]])
    v_icrs = rot.rotate(rot.inverse(q_true), camera.pixels_to_vectors(xy))
    moved = camera.vectors_to_pixels(rot.rotate(q_est, v_icrs))
    d = np.linalg.norm(moved - xy, axis=1)
    return float(np.max(d)) if np.all(np.isfinite(d)) else float("inf")


@dataclass(frozen=True)
class Trial:
    """One solver on one frame, scored: the unit a campaign task returns (JSON-able row).

    ``verdict`` is ``"correct"``, ``"wrong"`` (a wrong attitude accepted) or ``"failed"``
    (nothing accepted); errors are ``None`` unless something was accepted (``inf`` px when a
    frame corner falls behind the camera).
    """

    index: int
    verdict: str
    error_px: float | None
    error_deg: float | None
    time_s: float
    status: str
    own_time_s: float | None
    n_true: int
    n_centroids: int
    error_path_px: float | None = None  # rendered frames: closest instant of the exposure
    # wrong attitudes (ours): share of the matches that are right, how many, the largest 1σ
    # the solver reported and the error in units of that covariance (√ of δθᵀ C⁻¹ δθ) — a
    # misidentification, or the right stars badly fitted, and did the solver say so?
    stars_right: float | None = None
    n_matches: int | None = None
    sigma_max_deg: float | None = None
    error_sigmas: float | None = None

    def row(self) -> list[Any]:
        """As a list (JSON lines; ``Trial(*row)`` rebuilds it)."""
        return [self.index, self.verdict, self.error_px, self.error_deg, self.time_s,
                self.status, self.own_time_s, self.n_true, self.n_centroids,
                self.error_path_px, self.stars_right, self.n_matches, self.sigma_max_deg,
                self.error_sigmas]


def score(frame: Frame, outcome: Outcome, camera, tol_px: float, catalog=None) -> Trial:
    """Judge one outcome against the frame's truth: correct when the frame's corners and
    centre move by less than ``tol_px`` (:func:`frame_error_px`).

    A streaked (rendered, moving) frame has no single true attitude: the camera turned by
    rate × exposure while it was taken, and a streak broken into fragments yields centroids
    of *other instants* than mid-exposure — all stars of a frame alike, so the fit is tight
    and the identification right, yet the attitude is that of another instant (up to
    rate × exposure / 2 off mid-exposure). Such an outcome is correct when it is within
    ``tol_px`` of the true attitude at some instant of the exposure (41 instants tried);
    ``error_path_px`` records that distance, ``error_px`` stays the mid-exposure one, and
    :func:`aggregate` counts and lists these frames (``off_mid_exposure``).

    For a wrong attitude with its matches (ours), ``stars_right`` tells a misidentification
    from a bad fit of the right stars: the share of matched detections that are the claimed
    star — by the frame's truth ids, or, on a streaked frame (``catalog`` needed), lying
    within 2 px of that star's path during the exposure.

    >>> from adfusion import starid
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> from adfusion.bench.starid.frames import random_attitude
    >>> f = Frame("x", 0, random_attitude(0, 0), np.zeros((5, 2)), np.arange(5), 5)
    >>> score(f, Outcome(True, f.q_cam_icrs, 0.001), cam, 5.0).verdict
    'correct'
    """
    from adfusion.maths import rotations as rot

    err_px = err_deg = path_px = None
    verdict = "failed"
    if outcome.ok and outcome.q is not None:
        err_deg = float(np.degrees(rot.angle_between(outcome.q, frame.q_cam_icrs)))
        err_px = frame_error_px(outcome.q, frame.q_cam_icrs, camera)
        verdict = "correct" if err_px < tol_px else "wrong"
        if verdict == "wrong" and frame.omega_cam_rad_s is not None and frame.exposure_s > 0:
            s = np.linspace(-0.5, 0.5, 41) * frame.exposure_s
            q_path = rot.multiply(rot.exp_map(-np.outer(s, frame.omega_cam_rad_s)),
                                  frame.q_cam_icrs)
            path_px = min(frame_error_px(outcome.q, q, camera) for q in q_path)
            verdict = "correct" if path_px < tol_px else "wrong"
    right = n_match = sigma = n_sigma = None
    if verdict == "wrong" and outcome.matches:
        right = _stars_right(frame, outcome.matches, camera, catalog)
        n_match = len(outcome.matches)
    if verdict == "wrong" and outcome.covariance is not None and outcome.q is not None:
        c = np.asarray(outcome.covariance, dtype=np.float64)
        sigma = float(np.degrees(np.sqrt(np.max(np.diag(c)))))
        d = rot.log_map(rot.multiply(frame.q_cam_icrs, rot.inverse(outcome.q)))
        with contextlib.suppress(np.linalg.LinAlgError):
            n_sigma = float(np.sqrt(d @ np.linalg.solve(c, d)))
    return Trial(frame.index, verdict, err_px, err_deg, float(outcome.time_s),
                 outcome.status, outcome.own_time_s, frame.n_true, len(frame.xy), path_px,
                 right, n_match, sigma, n_sigma)


def _stars_right(frame: Frame, matches: Sequence[tuple[int, int]], camera,
                 catalog) -> float | None:
    """Share of (detection, catalogue id) matches that are right (see :func:`score`)."""
    from adfusion.maths import rotations as rot

    if frame.omega_cam_rad_s is None:
        return float(np.mean([frame.cat_ids[d] == c for d, c in matches]))
    if catalog is None:
        return None
    row = {int(i): k for k, i in enumerate(np.asarray(catalog.ids))}
    v = np.asarray(catalog.vectors)[[row[int(c)] for _, c in matches]]
    s = np.linspace(-0.5, 0.5, 41) * frame.exposure_s
    q_path = rot.multiply(rot.exp_map(-np.outer(s, frame.omega_cam_rad_s)), frame.q_cam_icrs)
    xy = frame.xy[[d for d, _ in matches]]
    best = np.full(len(matches), np.inf)
    for q in q_path:
        d = np.hypot(*(camera.vectors_to_pixels(rot.rotate(q, v)) - xy).T)
        best = np.minimum(best, d)
    return float(np.mean(best <= 2.0))


def summarize(frames: Sequence[Frame], outcomes: Sequence[Outcome], camera, tol_px: float,
              list_max: int = 50, per_frame: bool = False) -> dict[str, Any]:
    """Availability, error rate (+ 95 % bound), times (wall, and CPU where measured) and
    the frames worth a look."""
    out = aggregate([score(f, o, camera, tol_px)
                     for f, o in zip(frames, outcomes, strict=True)], list_max, per_frame)
    cpu = [o.cpu_s for o in outcomes]
    if cpu and all(c is not None for c in cpu):
        out["cpu_time_ms"] = _time_stats(cpu)
    return out


def aggregate(trials: Sequence[Trial], list_max: int = 50,
              per_frame: bool = False) -> dict[str, Any]:
    """The figures of one solver over scored trials (order matters only for the lists).

    >>> t = [Trial(i, "correct", 0.5, 0.001, 0.002, "", None, 8, 10) for i in range(3)]
    >>> a = aggregate(t + [Trial(3, "failed", None, None, 0.004, "ambiguous: 2", None, 3, 4)])
    >>> a["availability_pct"], a["n_failed"], a["failure_reasons"]
    (75.0, 1, {'ambiguous': 1})
    """
    n = len(trials)
    nan = float("nan")
    err_px = np.array([nan if t.error_px is None else t.error_px for t in trials], float)
    err_deg = np.array([nan if t.error_deg is None else t.error_deg for t in trials], float)
    verdict = np.array([t.verdict for t in trials], dtype=object)
    accepted = verdict != "failed"
    correct = verdict == "correct"
    wrong = verdict == "wrong"
    n_true = np.array([t.n_true for t in trials], dtype=np.int64)
    times = [t.time_s for t in trials]
    out: dict[str, Any] = {
        "n_frames": n,
        "n_correct": int(correct.sum()),
        "n_wrong": int(wrong.sum()),
        "n_failed": int((~accepted).sum()),
        "availability_pct": _pct(int(correct.sum()), n),
        "error_rate_pct": _pct(int(wrong.sum()), n),
        "error_rate_upper95_pct": round(100 * clopper_pearson_upper(int(wrong.sum()), n), 3),
        "time_ms": _time_stats(times),
        "time_ms_correct": _time_stats([t for t, c in zip(times, correct, strict=True) if c]),
        "median_error_correct_arcsec": _r(np.median, err_deg[correct] * 3600),
        "max_error_correct_deg": _r(np.max, err_deg[correct], 4),
        "max_error_correct_px": _r(np.max, err_px[correct]),
        "min_error_wrong_deg": _r(np.min, err_deg[wrong], 4),
        "min_error_wrong_px": _r(np.min, err_px[wrong]),
    }
    for k in (3, 4):
        sel = n_true >= k
        out[f"frames_ge{k}_stars"] = int(sel.sum())
        out[f"availability_ge{k}_pct"] = _pct(int((correct & sel).sum()), int(sel.sum()))
    own = [t.own_time_s for t in trials if t.own_time_s is not None]
    if own:
        out["own_reported_time_ms"] = _time_stats(own)
    statuses: dict[str, int] = {}
    for t in trials:
        if t.verdict == "failed":
            key = t.status.split(":")[0] or "not ok"
            statuses[key] = statuses.get(key, 0) + 1
    out["failure_reasons"] = dict(sorted(statuses.items(), key=lambda kv: -kv[1]))
    off_mid = [t for t in trials if t.verdict == "correct" and t.error_path_px is not None]
    if off_mid:  # streaked frames: right stars, the attitude of another instant (see score)
        out["n_off_mid_exposure"] = len(off_mid)
        out["off_mid_exposure_frames"] = [
            {"index": t.index, "error_px": round(float(t.error_px or 0.0), 2),
             "error_deg": round(float(t.error_deg or 0.0), 4),
             "error_path_px": round(float(t.error_path_px or 0.0), 2)} for t in off_mid]
    out["wrong_frames"] = [
        {"index": trials[i].index, "error_deg": round(float(err_deg[i]), 4),
         "error_px": round(float(err_px[i]), 2) if np.isfinite(err_px[i]) else "inf",
         "n_centroids": trials[i].n_centroids, "n_true": int(n_true[i]),
         **({} if trials[i].error_path_px is None else
            {"error_path_px": round(trials[i].error_path_px, 2)}),
         **({} if trials[i].stars_right is None else
            {"stars_right": round(trials[i].stars_right, 3), "n_matches": trials[i].n_matches}),
         **({} if trials[i].sigma_max_deg is None else
            {"sigma_max_deg": round(trials[i].sigma_max_deg, 4),
             "error_sigmas": None if trials[i].error_sigmas is None else
             round(trials[i].error_sigmas, 2)})}
        for i in np.flatnonzero(wrong)
    ]
    out["failed_frames"] = [
        {"index": trials[i].index, "status": trials[i].status[:120],
         "n_centroids": trials[i].n_centroids, "n_true": int(n_true[i])}
        for i in np.flatnonzero(~accepted)[:list_max]
    ]
    slow = np.argsort(times)[::-1][:5]
    out["slowest_frames"] = [{"index": trials[i].index, "time_ms": round(times[i] * 1e3, 3),
                              "ok": bool(correct[i])} for i in slow]
    if per_frame:
        out["per_frame"] = {
            "accepted": accepted.tolist(), "correct": correct.tolist(),
            "error_px": [round(float(e), 3) if np.isfinite(e) else None for e in err_px],
            "time_ms": [round(t * 1e3, 4) for t in times],
            "status": [t.status[:80] for t in trials],
        }  # fmt: skip
    return out


def time_ratios(per: dict[str, dict[str, Any]], key: str = "time_ms",
                stat: str = "median") -> dict[str, float | None]:
    """Our ``stat`` of ``key`` (``time_ms``, or ``cpu_time_ms`` where both have it) over
    each peer's."""
    if "ours" not in per or key not in per["ours"]:
        return {}
    ours = per["ours"][key][stat]
    out: dict[str, float | None] = {}
    for name, r in per.items():
        if name == "ours" or key not in r:
            continue
        peer = r[key][stat]
        out[name] = None if not ours or not peer else round(ours / peer, 3)
    return out


def _hot_figures(hot: dict[str, list[float | None]]) -> dict[str, Any]:
    """The hot CPU times of the solvers that measure one (:attr:`BenchConfig.hot_repeats`)
    and our ratios to them, as a condition's entry holds them.

    >>> f = _hot_figures({"ours": [1e-3, 3e-3], "tetra3rs": [2e-3, 2e-3], "cedar": [None]})
    >>> f["hot_cpu_time_ms"]["ours"]["median"], f["hot_cpu_ratio_ours_over_peer"]
    (2.0, {'tetra3rs': 1.0})
    """
    per = {name: {"cpu_time_ms": _time_stats(t)} for name, t in hot.items()
           if t and all(x is not None for x in t)}
    return {"hot_cpu_time_ms": {name: r["cpu_time_ms"] for name, r in per.items()},
            "hot_cpu_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms")}


# --- output ------------------------------------------------------------------------------


def _f(x: float | None, fmt: str) -> str:
    return "—" if x is None else format(x, fmt)


def format_table(doc: dict[str, Any]) -> str:
    """The human-readable report of :func:`run_benchmark`'s result."""
    cfg, m = doc["config"], doc["machine"]
    lines = [
        f"Star identification benchmark: {cfg['frames']} frames per condition, seed "
        f"{cfg['seed']}, {cfg['width']}x{cfg['height']} px, FOV {cfg['fov_deg']:g}°, "
        f"stars V < {cfg['mag_limit']:g}, base σ {cfg['sigma_px']:g} px, "
        f"correct = frame shift < max({cfg['tol_px']:g} px, {cfg['tol_sigma']:g}σ)",
        f"machine: {m['cpu']} ({m['cores']} cores), Python {m['python']}; starid "
        f"{doc['code']['git_commit']}{' + local changes' if doc['code']['git_dirty'] else ''}"
        f" (sources {doc['code']['sources_sha256']})",
    ]
    for name, s in doc["solvers"].items():
        if s.get("status") != "ok":
            lines.append(f"  {name}: SKIPPED — {s.get('reason')}")
        elif name == "ours":
            for key, b in s["indexes"].items():
                lines.append(f"  ours [{key}]: index {b['index_nbytes'] / 2**20:.1f} MiB "
                             f"({b['index_pairs']} pairs, {b['catalog_stars']} stars); "
                             f"build {b['index_build_fresh_s'] * 1e3:.0f} ms uncached, "
                             f"{b['index_build_s'] * 1e3:.0f} ms in this run (cache)")
        elif name == "tetra3rs":
            for key, b in s["databases"].items():
                lines.append(f"  tetra3rs {s['version']} [{key}]: database "
                             f"{b['file_bytes'] / 2**20:.1f} MiB ({b['num_stars']} stars, "
                             f"{b['num_patterns']} patterns), "
                             f"{'built' if b['built_now'] else 'loaded'} in "
                             f"{b['build_or_load_s']:.2f} s")
        elif name == "cedar":
            db = s.get("database") or {}
            lines.append(f"  cedar-solve {s['version']} (numpy {s['numpy']}): default "
                         f"database, FOV {db.get('min_fov')}–{db.get('max_fov')}°, "
                         f"{db.get('num_patterns')} patterns, mag ≤ "
                         f"{_f(db.get('star_max_magnitude'), '.2f')}")
    chk = ", ".join(f"{k} {_f(v['max_error_arcsec'], '.2f')}″"
                            f"{'' if v['passed'] else ' FAILED'}"
                    for k, v in doc["conversion_check"].items())
    lines.append(f"conversion check (noise-free frames, max attitude error): {chk}")
    head = (f"{'condition':<14} {'solver':<13} {'avail %':>8} {'err %':>6} {'err ≤95%':>8} "
            f"{'t med ms':>9} {'t p95':>8} {'t max':>8} {'ours/peer':>9}")
    lines += ["", head, "-" * len(head)]
    for c in doc["conditions"]:
        for k, (name, r) in enumerate(c["results"].items()):
            ratio = c["time_ratio_ours_over_peer"].get(name)
            lines.append(
                f"{c['name'] if k == 0 else '':<14} {name:<13} "
                f"{_f(r['availability_pct'], '.1f'):>8} {_f(r['error_rate_pct'], '.1f'):>6} "
                f"{_f(r['error_rate_upper95_pct'], '.2f'):>8} "
                f"{_f(r['time_ms']['median'], '.2f'):>9} {_f(r['time_ms']['p95'], '.2f'):>8} "
                f"{_f(r['time_ms']['max'], '.1f'):>8} {_f(ratio, '.2f'):>9}")
        cs = c["catalog_stars_per_frame"]
        if CONDITIONS.get(c["name"], Condition("")).coverage:
            avail = "; ".join(
                f"{name} {_f(r['availability_ge3_pct'], '.1f')} / "
                f"{_f(r['availability_ge4_pct'], '.1f')} %"
                for name, r in c["results"].items())
            lines.append(f"{'':<14} frames with ≥3 / ≥4 catalogue stars: {cs['ge3']} / "
                         f"{cs['ge4']} of {c['frames']} (median {cs['median']:g}); "
                         f"availability on those: {avail}")
    cpu_rows = [(c["name"], name, r["cpu_time_ms"], c.get("cpu_ratio_ours_over_peer", {}),
                 c.get("cpu_p95_ratio_ours_over_peer", {}))
                for c in doc["conditions"] for name, r in c["results"].items()
                if "cpu_time_ms" in r]
    if cpu_rows:
        head = (f"{'condition':<14} {'solver':<13} {'cpu med ms':>10} {'cpu p95':>8} "
                f"{'ours/peer med':>13} {'ours/peer p95':>13}")
        lines += ["", "CPU time of the solve (this thread; solvers in this process):", head,
                  "-" * len(head)]
        last = None
        for cond, name, t, rm, rp in cpu_rows:
            lines.append(f"{cond if cond != last else '':<14} {name:<13} "
                         f"{_f(t['median'], '.3f'):>10} {_f(t['p95'], '.3f'):>8} "
                         f"{_f(rm.get(name), '.2f'):>13} {_f(rp.get(name), '.2f'):>13}")
            last = cond
    hot_rows = [(c["name"], name, t, c["hot_cpu_ratio_ours_over_peer"].get(name))
                for c in doc["conditions"] for name, t in c.get("hot_cpu_time_ms", {}).items()]
    if hot_rows:
        lines += ["", f"CPU time of the same frame solved again ({cfg['hot_repeats']}×, the "
                  "last timed: code and data in the caches):"]
        for cond, name, t, r in hot_rows:
            lines.append(f"{cond:<14} {name:<13} {_f(t['median'], '.3f'):>10} "
                         f"{_f(t['p95'], '.3f'):>8} {_f(r, '.2f'):>13}")
    lines.append("")
    lines.append("avail = correct attitude accepted; err = wrong attitude accepted, with its "
                 "one-sided 95 % Clopper–Pearson bound; times over all frames, the solvers "
                 "interleaved frame by frame, measured in each solver's own process; "
                 "ours/peer = ratio of median times (< 1: ours faster).")
    return "\n".join(lines)
