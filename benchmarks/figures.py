"""Regenerate the generated benchmark figures: sweeps, Renken's §8 grid, filters and replay.

The replay-inputs table comes from ``benchmarks/results/replay_inputs.json``, which
``python -P benchmarks/bench_replay_inputs.py --rounds 3`` writes, and the closed-loop one
from ``benchmarks/results/bench_acs.json`` (``python -P benchmarks/bench_acs.py``), the
lost-in-space one from ``benchmarks/results/starid.json`` (``adfusion bench starid ...
--json benchmarks/results/starid.json``, the command in :func:`figures_block`; the same run of
the code before a change, on the same machine, as ``starid-before.json`` adds its ratios);
none is run from here.

One command runs the three benchmarks, keeps their JSON under ``benchmarks/results/`` and the
sweep plots under ``docs/img/``, and rewrites the block of ``docs/benchmarks.md`` between the
``<!-- figures:begin`` and ``<!-- figures:end -->`` markers (nothing else on the page is
touched)::

    python benchmarks/figures.py                 # quick sweep grid (24 points × 1000 trials)
    python benchmarks/figures.py --full          # the full grid (44 points × 1000 trials)
    python benchmarks/figures.py --from-json     # only rewrite the page from the JSON
    python benchmarks/figures.py --workers 8 --scheduler tcp://host:8786

The sweep and the Renken grid run as dask campaigns (``--workers``, ``--scheduler``); their
partial files are kept in the adfusion cache folder, so an interrupted run resumes and
``--full`` after a quick run reuses the quick grid's finished points (as long as the code
is unchanged: a digest of the sources is part of every task).

Example (the block from stored results):
    >>> block = figures_block({"sweep": None, "renken": None, "filters": None, "fuzz": None})
    >>> block.splitlines()[0].startswith("<!-- figures:begin")
    True
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "benchmarks.md"
RELIABILITY = ROOT / "docs" / "reliability.md"  # the long fuzz run's counts, too
PLOTS = ROOT / "docs" / "img"  # the sweep plots, linked from PAGE
BEGIN = "<!-- figures:begin"
END = "<!-- figures:end -->"


def _machine(doc: dict[str, Any]) -> str:
    m = doc["machine"]
    return f"{m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}"


def sweep_section(doc: dict[str, Any], command: str) -> str:
    from adfusion.bench import sweep as bench_sweep

    c, cfg, s = doc["campaign"], doc["config"], doc["summary"]
    n_points = sum(len(sw["points"]) for sw in doc["sweeps"])
    n_trials = sum(p["trials"] for sw in doc["sweeps"] for p in sw["points"])
    wrong = s["ours_wrong"]
    worst = s["ours_max_error_rate_upper95_pct"]
    lines = [
        "### Robustness sweeps against the peers",
        "",
        f"`{command}` — {n_points} points × {cfg['trials']} trials ({n_trials} frames, "
        f"seed {cfg['seed']}), {c['backend']} with {c['workers']} workers, "
        f"{doc['wall_s'] / 60:.0f} min on {_machine(doc)} (shared with other jobs: times are "
        "noisy, ratios more trustworthy). Base camera as `bench starid` (1024×768, 15°, "
        f"V < {cfg['mag_limit']:g}, σ {cfg['sigma_px']:g} px, magnitude noise "
        f"{cfg['mag_noise']:g}); one variable swept at a time; every solver sees the same "
        "centroid lists; correct = frame corners within max(5 px, 4σ) of truth. *Tracking* is "
        f"ours with a filter-like prior (truth tilted by N(0, {cfg['prior_sigma_deg']:g}°) "
        "per axis); the peers have no tracking mode. The rate sweep renders 0.1 s exposures "
        "streaked by the rate (random axis) and runs `starid.detection.detect` on them. "
        "The full grid "
        "(`adfusion bench sweep`, 44 points) takes about "
        f"{bench_sweep.estimate_seconds(bench_sweep.SweepConfig(), 2) / 60:.0f} min on this "
        "machine; `--quick` (24 points, ≥ 1000 trials each) about "
        f"{bench_sweep.estimate_seconds(bench_sweep.SweepConfig(quick=True), 2) / 60:.0f} min "
        "(estimates; the load of the shared machine changes them by up to 2×).",
        "",
    ]
    by = {n: sum(w["solver"] == n for w in wrong) for n in ("ours", "ours_tracking")}
    lines.append(
        f"**Wrong attitudes accepted by ours: lost-in-space {by['ours']} of {n_trials} frames, "
        f"tracking {by['ours_tracking']} of {n_trials}.** The largest 95 % upper bound of the "
        f"error rate at any point is {worst.get('ours', float('nan')):.2f} % (lost-in-space) / "
        f"{worst.get('ours_tracking', float('nan')):.2f} % (tracking); 0 of "
        f"{cfg['trials']} gives 1 − 0.05^(1/{cfg['trials']}) = "
        f"{100 * (1 - 0.05 ** (1 / cfg['trials'])):.2f} %.")
    if wrong:
        all_right = sum(w.get("stars_right") == 1.0 for w in wrong)
        beyond3 = sum((w.get("error_sigmas") or 0.0) > 3.0 for w in wrong)
        lines += ["", "In "
                  f"{all_right} of the {len(wrong)} every matched star is the right one (by "
                  "the frame's truth ids; on streaked frames, the detection lies within 2 px "
                  "of that star's path during the exposure): the identification is right, the "
                  f"attitude fitted to it is not. {beyond3} are more than 3σ off by the "
                  "solver's own covariance (overconfident); the others report an uncertainty "
                  "that covers their error. Every one, rebuildable with `make_frame(seed, "
                  "frame, point)`:", "",
                  "| solver | point | seed | frame | error ° | matched stars (right %) | "
                  "error in σ of its covariance | largest 1σ ° |",
                  "|---|---|---|---|---|---|---|---|"]
        for w in wrong:
            right = "—" if w.get("stars_right") is None else \
                f"{w['n_matches']} ({100 * w['stars_right']:.0f} %)"
            nsig = "—" if w.get("error_sigmas") is None else f"{w['error_sigmas']:.1f}"
            sig = "—" if w.get("sigma_max_deg") is None else f"{w['sigma_max_deg']:.3g}"
            lines.append(f"| {w['solver']} | `{w['point']}` | {w['seed']} | {w['index']} | "
                         f"{w['error_deg']:.3g} | {right} | {nsig} | {sig} |")
    off = s["ours_off_mid_exposure"]
    if off:
        pts = sorted({o["point"] for o in off})
        lines += ["", f"Streaked frames: {len(off)} accepted fixes of ours "
                  f"({', '.join(f'`{p}`' for p in pts)}) are the attitude of another instant of "
                  "the exposure, not mid-exposure: a long streak breaks into fragments, each "
                  "centroid belongs to some instant of the exposure, and the fit follows — "
                  "the stars are right, the attitude is up to rate × exposure / 2 off the "
                  "mid-exposure truth (largest "
                  f"{max(o['error_deg'] for o in off):.2f}°). They count as correct (within "
                  "5 px of the true attitude at some instant of the exposure, largest "
                  f"{max(o['error_path_px'] for o in off):.1f} px) and are listed in the JSON "
                  "(`summary.ours_off_mid_exposure`); the peers' are counted the same way."]
    pb = s["points_where_a_peer_is_better"]
    lines += ["", f"**Points where a peer's availability beats ours (lost-in-space): {len(pb)}**"
              + ("." if not pb else ":")]
    for b in pb:
        lines.append(f"- `{b['point']}`: {b['peer']} {b['peer_pct']:.1f} % vs ours "
                     f"{b['ours_pct']:.1f} % (ours tracking {b['ours_tracking_pct']:.1f} %)")
    lines += ["", "Per sweep, availability % with the number of wrong attitudes accepted in "
              "brackets (bold: a peer is better); our lost-in-space time per solve. Plots "
              "(availability, error rate with its bound, median time): "
              + ", ".join(f"[{sw['name']}](img/sweep-{sw['name']}.png)"
                          for sw in doc["sweeps"]) + ".", "",
              bench_sweep.markdown_tables(doc).rstrip()]
    sparse = next((sw for sw in doc["sweeps"] if sw["name"] == "mag_limit"), None)
    if sparse:
        names = [n for n in ("ours", "ours_tracking", "tetra3rs", "cedar")
                 if n in sparse["points"][0]["results"]]
        lines += ["", "Sparse fields: availability % on the frames with at least 3 / at least "
                  "4 catalogue stars in view (fewer than 3 cannot be identified lost-in-space; "
                  "tracking takes 2)", "",
                  "| V < | frames ≥ 3 / ≥ 4 stars | " + " | ".join(names) + " |",
                  "|---|---|" + "---|" * len(names)]
        for p in sparse["points"]:
            cs, r = p["catalog_stars_per_frame"], p["results"]
            cells = [f"{r[n]['availability_ge3_pct'] or 0:.1f} / "
                     f"{r[n]['availability_ge4_pct'] or 0:.1f}" for n in names]
            lines.append(f"| {p['value']:g} | {cs['ge3']} / {cs['ge4']} | "
                         + " | ".join(cells) + " |")
    return "\n".join(lines)


def renken_section(doc: dict[str, Any], command: str) -> str:
    from renken_simulation import markdown, worst_delta

    cells = doc["cells"]
    high = [c for c in cells if c["published"]["eta"] >= 85]
    within = sum(abs(c["eta"] - c["published"]["eta"]) <= 3 for c in high)
    wrong = sum(c["wrong_unique"] for c in cells)
    c = doc["campaign"]
    return "\n".join([
        "### Renken (1998) §8: the full simulation grid",
        "",
        f"`{command}` — 7 catalogues × 3 tolerances × {doc['frames']} frames, his 384×288 "
        "camera at 0.051°/px (equidistant), Eq. 8.1 attitudes, Hipparcos cut to his SAO "
        f"counts and merged at {doc['merge_px']:g} px; {c['backend']} with {c['workers']} "
        f"workers, {c['wall_s']:.0f} s. Published figures from Tab. 8.1–8.28 of the "
        "thesis; multiple matches are counted his way, `matching_counter ≥ 2` over all "
        "frames, 2-star frames included.",
        "",
        markdown(doc),
        "",
        f"Of the {len(high)} cells where the thesis has η ≥ 85 %, {within} agree within ±3 pp "
        f"(largest |Δ| {worst_delta(doc):.2f} pp); {wrong} unique matches were wrong. "
        "Differences come from the catalogue (Hipparcos positions and V magnitudes "
        "count-matched to his SAO catalogues; his merge radius and star rendering are not "
        "given) and from 2000-frame binomial noise (±1.3 pp at η = 50 %).",
    ])


def filters_section(doc: dict[str, Any], command: str) -> str:
    med, rms = doc["median_us"], doc["rms_err_deg_after_burn_in"]
    lines = [
        "### Filters and replay",
        "",
        f"`{command}` — {doc['scenario']}; {doc['steps']} steps × {doc['rounds']} interleaved "
        "rounds, median step time, RMS attitude error after the burn-in, on the same data:",
        "",
        "| filter | step µs (median) | steps/s | RMS error ° | final error ° |",
        "|---|---|---|---|---|",
    ]
    names = {"mekf": "MEKF (ours)", "ukf": "UKF (ours)", "ahrs_ekf": "ahrs EKF",
             "filterpy_ekf": "filterpy EKF (same model)"}
    for n in med:
        lines.append(f"| {names.get(n, n)} | {med[n]:.1f} | {1e6 / med[n]:,.0f} | "
                     f"{rms[n]:.4f} | {doc['final_err_deg'][n]:.4f} |")
    rp = doc.get("replay")
    if rp:
        lines += ["", f"Replay throughput ({rp['scenario']}, `adfusion.app.pipeline.replay`: "
                  "detection, identification, MEKF, MCAP writing):", ""]
        for k, label in (("rendered", "rendered intensified frames"),
                         ("centroids", "centroid-only log")):
            r = rp[k]
            lines.append(f"- {label}: {r['frames_per_s']:.0f} frames/s, {r['identified']} of "
                         f"{r['frames']} identified, attitude error RMS "
                         f"{r['error_rms_deg']:.3f}°, max {r['error_max_deg']:.3f}°")
    m = doc["machine"]
    cores = m.get("cores", m.get("cpus"))  # "cpus" in records before bench.machine
    lines += ["", f"(Python {m['python']}, numpy {m['numpy']}, {cores} CPUs, load "
              f"{m['loadavg'][0]:.1f} during the run.)"]
    return "\n".join(lines)


def replay_inputs_section(doc: dict[str, Any], command: str) -> str:
    """Replay throughput by input (``benchmarks/bench_replay_inputs.py``): frames per
    second (best round and median), the CPU a frame of the replay process and of the
    detection worker (medians), reading alone, and the estimates' agreement."""
    names = {"mcap": "our MCAP", "folder": "PNG folder + CSVs", "video": "FFV1 video + CSV",
             "video_mjpg": "Motion-JPEG video + CSV"}
    w, h = doc["frame_size"]
    lines = [
        "### Replay inputs",
        "",
        f"`{command}` — the same simulated flight ({doc['frames']} rendered {w}×{h} frames, "
        f"{doc['duration_s']:g} s) replayed end to end from each input, {doc['rounds']} "
        "rounds in rotating order:",
        "",
        "| input | frames/s, best round (after setup) | median (÷ MCAP's) | CPU a frame: replay "
        "process + detection worker | reading alone (CPU a frame) | identified | RMS error |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in doc["inputs"].items():
        cpu = r.get("cpu_ms_per_frame")
        cpu_text = (f"{cpu['replay_process']:.2f} + {cpu['detection_worker']:.2f} ms"
                    if cpu else "—")
        lines.append(
            f"| {names.get(name, name)} | {r['frames_per_s']:.0f} "
            f"({r['frames_per_s_after_setup']:.0f}) | {r['frames_per_s_median']:.0f} "
            f"({r['median_vs_mcap']:.2f}) | {cpu_text} | {r['read_ms_cpu_per_frame']:.2f} ms "
            f"| {r['identified']} of {doc['frames']} | {r['error_rms_deg']:.4f}° |")
    m = doc["machine"]
    lines += ["", f"(Python {m['python']}, {m['cores']} cores shared with other work, load "
              f"average {doc['load_average_1min_before']:.1f} before and "
              f"{m['load_average_1min']:.1f} after the run, {m['when']}.)"]
    return "\n".join(lines)


def acs_section(doc: dict[str, Any], command: str) -> str:
    """Basilisk's closed loop (``benchmarks/bench_acs.py``): pointing per loop, the
    estimators on the same messages, the camera's identifications and the cost per call
    against Basilisk's own modules."""
    n, ratio = doc["seeds"], doc["pointing_ratio_adfusion_truth"]
    ratio_st = doc["pointing_ratio_adfusion_st_truth"]
    pr, er, band = doc["pointing_rms_arcsec_mean"], doc["estimation_rms_arcsec_mean"], \
        doc["nees_band_95"]
    truth = pr["truth"]
    lines = [
        "### Closed loop in Basilisk",
        "",
        f"`{command}` — `{doc['scenario']}` over {n} seeds × {doc['duration_s']:g} s, "
        f"statistics from t = {doc['settle_s']:g} s:",
        "",
        "| loop closed on | pointing RMS (″, mean of seeds) | × truth-fed (mean / max) |",
        "|---|---|---|",
        f"| truth (`simpleNav`) | {truth:.1f} | 1 |",
        f"| `inertialUKF` (star tracker) | {pr['ukf']:.1f} | {pr['ukf'] / truth:.2f} |",
        f"| adfusion (the same star tracker) | {pr['adfusion_st']:.1f} | "
        f"{ratio_st['mean']:.2f} / {ratio_st['max']:.2f} |",
        f"| adfusion (camera in the loop) | {pr['adfusion']:.1f} | **{ratio['mean']:.2f}** / "
        f"{ratio['max']:.2f} ({ratio['seeds_above_1_2']} of {n} seeds above 1.2) |",
        "",
        f"| estimator, same messages | error RMS (″) | ensemble NEES (3 dof; 95 % band "
        f"{band[0]:.2f}–{band[1]:.2f}) | times inside the band |",
        "|---|---|---|---|",
    ]
    names = {"adfusion": "adfusion, camera + gyro + mag", "adfusion_st":
             "adfusion, star tracker + gyro", "ukf": "`inertialUKF`, star tracker + gyro"}
    for k, label in names.items():
        e = doc["ensemble_nees"][k]
        lines.append(f"| {label} | {er[k]:.2f} | {e['mean_ensemble_nees']:.2f} | "
                     f"{100 * e['fraction_of_times_inside_band']:.0f} % |")
    cam = doc["camera"]
    lines += ["", f"Camera in the loop: {cam['identified']} of {cam['frames_3_stars']} frames "
              f"with at least 3 stars identified, {cam['wrong']} wrong.", "",
              "Cost per call (CPU time of the calling thread; loops: the best of their "
              "rounds):", "", "| call | median (µs) | p95 (µs) |", "|---|---|---|"]
    for k, v in doc["cost"].items():
        lines.append(f"| {k} | {v['median_us']:.1f} | {v['p95_us']:.1f} |")
    m = doc["machine"]
    load = (f"load average {m['load_average_1min_before']:.1f} before and "
            f"{m['load_average_1min_after']:.1f} after the run, {m['when']}"
            if "load_average_1min_before" in m else "the load was not recorded")
    lines += ["", f"(Python {m['python']}, {m['cpus']} cores; {load}.)"]
    return "\n".join(lines)


def live_section(doc: dict[str, Any], command: str) -> str:
    """``adfusion live``'s latency (``benchmarks/bench_live.py``): a frame on disk → its
    estimate received by a Foxglove client, per file format."""
    w, h = doc["frame_size"]
    lines = [
        "### Live latency",
        "",
        f"`{command}` — `adfusion live DIR` in its own process, {w}×{h} frames "
        f"({w * h / 1e6:.1f} Mpx, {doc['fov_deg']:g}°, {doc['stars_per_frame_median']:.0f} "
        f"stars a frame, median) written into DIR at {doc['rate_hz']:g} Hz, received by a "
        "Foxglove-protocol client; latency = receipt of the estimate − rename of the file "
        "(issue 36 asks ≤ 50 ms median in tracking):",
        "",
        "| format | file | frames (identified) | latency median | p95 | max | the run's own "
        "median (arrival seen → published) |",
        "|---|---|---|---|---|---|---|",
    ]
    for fmt, r in doc["formats"].items():
        lat, own = r["latency_ms"], r["run_latency_ms"]
        modes = ", ".join(f"{m} {n}" for m, n in r["modes"].items())
        lines.append(f"| {fmt.upper()} | {r['file_kb']:.0f} kB | {r['frames']} ({r['identified']}"
                     f"; {modes}) | {lat['median']:.1f} ms | {lat['p95']:.1f} ms | "
                     f"{lat['max']:.1f} ms | {own['median']:.1f} ms |")
    m = doc["machine"]
    lines += ["", f"(Python {m['python']}, {m['cores']} cores shared with other work, load "
              f"average {m['load_average_1min']:.1f} after the run, {m['when']}.)"]
    return "\n".join(lines)


def fuzz_section(doc: dict[str, Any], command: str) -> str:
    names = {"reader": "MCAP reader", "solver": "solver", "sources": "sources",
             "cli": "command line", "streams": "sensor streams", "writers": "writers"}
    lines = [
        "### Long fuzz run",
        "",
        f"`{command}` — {doc['cases']:,} cases in {doc['wall_s'] / 60:.1f} min "
        f"(seed {doc['seed']}): **{doc['tracebacks']} tracebacks, {doc['silent_losses']} "
        f"silent losses, {doc['wrong_attitudes']} wrong attitudes accepted, "
        f"{doc['cli_violations']} command-line violations**"
        + (f" at commit `{doc['commit']}`" if doc.get("commit") else "") + ".",
        "",
        "| family | cases | ok | problem reported | violations |",
        "|---|---|---|---|---|",
    ]
    for fam, c in doc["by_family"].items():
        bad = sum(v for k, v in c.items() if k.startswith("violation"))
        lines.append(f"| {names.get(fam, fam)} | {sum(c.values()):,} | {c.get('ok', 0):,} | "
                     f"{c.get('reported', 0):,} | {bad} |")
    if doc.get("violations"):
        lines += ["", "Violations:", ""] + [f"- `{v}`" for v in doc["violations"]]
    return "\n".join(lines)


def _commit(doc: dict[str, Any]) -> str | None:
    code = doc.get("code") or {}
    commit = code.get("commit") or code.get("git_commit")
    return str(commit)[:7] if commit else None


def starid_section(doc: dict[str, Any], command: str,
                   before: dict[str, Any] | None = None) -> str:
    """Lost-in-space against the peers in one process (``adfusion bench starid --json``):
    availability, errors and CPU time per condition, and the ratios against each peer —
    and, given ``before`` (the same run of an earlier commit on the same machine:
    ``benchmarks/results/starid-before.json``), its ratios beside them."""
    peers = [n for n in doc["solvers"] if n != "ours"]
    commit = _commit(doc)
    if before is not None and _machine(before) != _machine(doc):
        before = None  # ratios from another machine do not compare
    label = f"`{_commit(before)}`" if before and _commit(before) else "an earlier run"
    load = doc["machine"].get("loadavg")
    repeats = doc["config"].get("hot_repeats", 0)
    hot = repeats > 0 and bool(peers)
    if repeats > 0 and "--hot" not in command:
        command += f" --hot {repeats}"
    lines = [
        "### Lost-in-space against the peers, interleaved",
        "",
        f"`{command}` ({doc['config']['frames']} frames a condition"
        + (f", code `{commit}`" if commit else "")
        + (f", load average {load[0]:.1f}" if load else "") + f"; {_machine(doc)}): the "
        "solvers interleaved frame by frame in one process on the same centroid lists; "
        "CPU time of each solve (`time.thread_time`), ms.",
        "",
        "| condition | avail % (err) ours | " + " | ".join(
            f"avail % (err) {p}" for p in peers) + " | ours median / p95 | " + " | ".join(
            f"{p} median / p95 | ours ÷ {p} median / p95" for p in peers)
        + (f" | before ({label}) ÷ {peers[0]} median / p95" if before and peers else "")
        + (f" | hot: ours / {peers[0]} median, ratio" if hot else "") + " |",
        "|---" * (3 + 3 * len(peers) + (1 if before and peers else 0) + (1 if hot else 0))
        + "|",
    ]
    earlier = {c["name"]: c for c in before["conditions"]} if before and peers else {}
    for c in doc["conditions"]:
        r = c["results"]
        row = [c["name"], f"{r['ours']['availability_pct']:.1f} ({r['ours']['n_wrong']})"]
        row += [f"{r[p]['availability_pct']:.1f} ({r[p]['n_wrong']})" for p in peers]
        t = r["ours"]["cpu_time_ms"]
        row.append(f"{t['median']:.3f} / {t['p95']:.3f}")
        for p in peers:
            tp = r[p]["cpu_time_ms"]
            rm = c["cpu_ratio_ours_over_peer"].get(p)
            r95 = c["cpu_p95_ratio_ours_over_peer"].get(p)
            row.append(f"{tp['median']:.3f} / {tp['p95']:.3f}")
            row.append(f"{rm:.2f} / {r95:.2f}" if rm and r95 else "—")
        if before and peers:
            e = earlier.get(c["name"])
            rm = e and e["cpu_ratio_ours_over_peer"].get(peers[0])
            r95 = e and e["cpu_p95_ratio_ours_over_peer"].get(peers[0])
            row.append(f"{rm:.2f} / {r95:.2f}" if rm and r95 else "—")
        if hot:
            h = c.get("hot_cpu_time_ms", {})
            rh = c.get("hot_cpu_ratio_ours_over_peer", {}).get(peers[0])
            row.append(f"{h['ours']['median']:.3f} / {h[peers[0]]['median']:.3f}, {rh:.2f}"
                       if rh and "ours" in h and peers[0] in h else "—")
        lines.append("| " + " | ".join(row) + " |")
    if hot:
        lines += ["", f"Hot: each frame solved {repeats} more times by "
                  "each solver right after the first solves, the last one's CPU time (the "
                  "solver's code and data in the caches); the other columns are each "
                  "frame's first solve."]
    return "\n".join(lines)


def never_wrong_section(doc: dict[str, Any], before: dict[str, Any] | None = None) -> str:
    """Frames of random detections (``benchmarks/never_wrong.py --json``): how many were
    accepted, time per frame — and, given ``before`` (the same run of an earlier commit
    on the same machine: ``benchmarks/results/never_wrong-before.json``), its times. The
    command shown is the one the document was run with (its frames and workers)."""
    if before is not None and _machine(before) != _machine(doc):
        before = None
    commit = _commit(doc)
    command = (f"python -P benchmarks/never_wrong.py --frames {doc['frames']} "
               f"--workers {doc['config']['workers']}")
    rows = [("this code" + (f" (`{commit}`)" if commit else ""), doc)]
    if before:
        rows.append((f"before (`{_commit(before)}`)" if _commit(before) else "before",
                     before))
    lines = [
        "### Never wrong: frames of noise",
        "",
        f"`{command}` ({doc['frames']} frames of 3–30 random detections, Hipparcos "
        f"V < {doc['config']['mag_limit']:g}, {doc['config']['fov_deg']:g}° field; "
        f"{_machine(doc)}): wall time per frame, ms.",
        "",
        "| code | frames | accepted | median | p95 | max |",
        "|---|---|---|---|---|---|",
    ]
    for name, d in rows:
        lines.append(f"| {name} | {d['frames']} | {d['accepted']} | {d['ms_median']:.2f} | "
                     f"{d['ms_p95']:.2f} | {d['ms_max']:.1f} |")
    return "\n".join(lines)


def _wrap(text: str, width: int = 90) -> str:
    """Prose lines wrapped like the rest of the page; tables, headings, comments kept."""
    import textwrap

    out = []
    for line in text.splitlines():
        if len(line) <= width or line.startswith(("|", "#", "<!--")):
            out.append(line)
            continue
        indent = "  " if line.startswith("- ") else ""
        out.append(textwrap.fill(line, width, subsequent_indent=indent,
                                 break_long_words=False, break_on_hyphens=False))
    return "\n".join(out)


def figures_block(docs: dict[str, Any], commands: dict[str, str] | None = None) -> str:
    """The generated block of ``docs/benchmarks.md`` (between the markers) from the
    benchmark documents."""
    cmd = {"sweep": "adfusion bench sweep --quick",
           "renken": "python benchmarks/renken_simulation.py",
           "filters": "python benchmarks/bench_filters.py",
           "fuzz": "python -P benchmarks/fuzz.py --minutes 30",
           "replay_inputs": "python -P benchmarks/bench_replay_inputs.py --rounds 3",
           "bench_acs": "python -P benchmarks/bench_acs.py",
           "live": "python -P benchmarks/bench_live.py",
           "starid": "adfusion bench starid --frames 300 --conditions clean,false3,false8,"
                     "drop30_false3,sigma1,sigma2 --solvers ours,tetra3rs",
           **(commands or {})}
    parts = [f"{BEGIN}: generated by `python benchmarks/figures.py`; edit that script, "
             "not this block -->"]
    if docs.get("sweep"):
        parts.append(sweep_section(docs["sweep"], cmd["sweep"]))
    if docs.get("renken"):
        parts.append(renken_section(docs["renken"], cmd["renken"]))
    if docs.get("filters"):
        parts.append(filters_section(docs["filters"], cmd["filters"]))
    if docs.get("replay_inputs"):
        parts.append(replay_inputs_section(docs["replay_inputs"], cmd["replay_inputs"]))
    if docs.get("bench_acs"):
        parts.append(acs_section(docs["bench_acs"], cmd["bench_acs"]))
    if docs.get("live"):
        parts.append(live_section(docs["live"], docs["live"].get("command", cmd["live"])))
    if docs.get("starid"):
        parts.append(starid_section(docs["starid"], cmd["starid"], docs.get("starid-before")))
    if docs.get("never_wrong"):
        parts.append(never_wrong_section(docs["never_wrong"], docs.get("never_wrong-before")))
    if docs.get("fuzz"):
        parts.append(fuzz_section(docs["fuzz"], cmd["fuzz"]))
    parts.append(END)
    return _wrap("\n\n".join(parts))


def reliability_block(fuzz: dict[str, Any] | None, command: str) -> str:
    """The generated block of ``docs/reliability.md``: the last long fuzz run's counts."""
    body = (fuzz_section(fuzz, command).replace("### Long fuzz run", "#### The last long run")
            if fuzz else "No long fuzz run recorded (`benchmarks/results/fuzz.json`).")
    return _wrap("\n\n".join([f"{BEGIN}: generated by `python benchmarks/figures.py` from "
                               "benchmarks/results/fuzz.json; edit that script, not this "
                               "block -->", body, END]))


def write_block(page: Path, block: str) -> None:
    """Replace the generated block of ``page``; the hand-written text around it stays."""
    text = page.read_text()
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        text = head + block + tail
    else:
        raise SystemExit(f"{page}: no '{BEGIN} … {END}' block to replace")
    page.write_text(text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="the full sweep grid (default: --quick)")
    p.add_argument("--trials", type=int, default=1000, help="trials per sweep point")
    p.add_argument("--renken-frames", type=int, default=2000)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--scheduler", default=None)
    p.add_argument("--from-json", action="store_true",
                   help="do not run anything: rewrite the page from benchmarks/results/")
    p.add_argument("--only", default="sweep,renken,filters",
                   help="which benchmarks to run (the others are read from their JSON)")
    p.add_argument("--page", default=str(PAGE),
                   help="the page whose generated block is rewritten (docs/benchmarks.md)")
    args = p.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    from adfusion.starid.catalog.cache import cache_dir

    store = cache_dir() or RESULTS  # partial files: outside the checkout when possible
    run = set() if args.from_json else {s.strip() for s in args.only.split(",")}
    sweep_cmd = "adfusion bench sweep" + ("" if args.full else " --quick") + \
        ("" if args.trials == 1000 else f" --trials {args.trials}")
    if "sweep" in run:
        from adfusion.bench import sweep as bench_sweep

        cfg = bench_sweep.SweepConfig(
            quick=not args.full, trials=args.trials, workers=args.workers,
            scheduler=args.scheduler, partial=str(store / "figures-sweep.partial.jsonl"),
            keep_partial=True)
        print(f"sweep: {len(bench_sweep.points(cfg))} points × {cfg.trials} trials, "
              f"estimated {bench_sweep.estimate_seconds(cfg, args.workers or 2) / 60:.0f} min",
              file=sys.stderr)
        doc = bench_sweep.run_sweep(cfg)
        doc["command"] = sweep_cmd
        (RESULTS / "sweep.json").write_text(json.dumps(doc, indent=1) + "\n")
        bench_sweep.write_plots(doc, PLOTS)
        print(bench_sweep.format_table(doc))
    if "renken" in run:
        import renken_simulation

        doc = renken_simulation.run(args.renken_frames, workers=args.workers,
                                    scheduler=args.scheduler,
                                    partial=str(store / "figures-renken.partial.jsonl"))
        (RESULTS / "renken.json").write_text(json.dumps(doc, indent=1) + "\n")
        print(renken_simulation.markdown(doc))
    if "filters" in run:
        import bench_filters

        doc = bench_filters.run()
        doc["replay"] = bench_filters.replay_throughput(20.0)
        (RESULTS / "filters.json").write_text(json.dumps(doc, indent=1) + "\n")
    docs: dict[str, Any] = {}
    for name in ("sweep", "renken", "filters", "replay_inputs", "bench_acs", "live", "fuzz",
                 "starid",
                 "starid-before", "never_wrong", "never_wrong-before"):
        f = RESULTS / f"{name}.json"
        docs[name] = json.loads(f.read_text()) if f.exists() else None
    cmds = {"sweep": (docs["sweep"] or {}).get("command", sweep_cmd)}
    if docs["fuzz"] and docs["fuzz"].get("command"):
        cmds["fuzz"] = docs["fuzz"]["command"]
    write_block(Path(args.page), figures_block(docs, cmds))
    print(f"{args.page}: generated block rewritten from {RESULTS}", file=sys.stderr)
    if Path(args.page) == PAGE:
        write_block(RELIABILITY, reliability_block(
            docs["fuzz"], cmds.get("fuzz", "python -P benchmarks/fuzz.py --minutes 30")))
        print(f"{RELIABILITY}: generated block rewritten", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
