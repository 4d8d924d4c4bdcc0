"""Plots and a short markdown summary of a replayed log (``adfusion report``).

PNG plots, one question each: how far off was the attitude (with its 3σ bound, when the
log has truth)? where did the boresight point (RA/Dec track, as Yee's Fig. 4.11)? which
frames were identified and how (mode per frame)? what did the filter think of the gyro
bias? were the innovations consistent (NIS)? A log replayed with ``--smooth`` has the
smoother's history too: its error and 3σ bound, and its bias, are drawn next to the filter's.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import simulate, replay
    >>> from adfusion.app.report import report
    >>> d = tempfile.mkdtemp()
    >>> _ = simulate(oedipus(duration_s=0.5, render=False), os.path.join(d, "s.mcap"))
    >>> _ = replay(os.path.join(d, "s.mcap"), os.path.join(d, "o.mcap"), progress=False)
    >>> sorted(p.name for p in report(os.path.join(d, "o.mcap"), d))[:2]
    ['attitude_error.png', 'bias.png']
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from adfusion.logs import McapLogReader
from adfusion.starid import rotations as rot

__all__ = ["log_problems", "report"]


def report(log_path: str | Path, out_dir: str | Path) -> list[Path]:
    """Write the plots and ``summary.md`` for a replayed log; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    est_t, est_q, est_b, est_var, nis_t, nis_v = [], [], [], [], [], []
    tru_t, tru_q = [], []
    sol_t, sol_mode, sol_ok = [], [], []
    sm_t, sm_q, sm_b, sm_var = [], [], [], []  # /smoothed/state (replay --smooth)
    reader = McapLogReader(log_path)
    unreadable: dict[str, int] = {}  # topic → messages whose payload is not ours
    for m in reader:
        p = m.payload
        try:
            if m.topic == "/estimate/state":
                row = (p["q_body_icrs"], p["bias"], p["cov_diag"])
                nis = list((p.get("nis") or {}).values())
                est_t.append(m.t_s)
                est_q.append(row[0])
                est_b.append(row[1])
                est_var.append(row[2])
                for v in nis:
                    nis_t.append(m.t_s)
                    nis_v.append(v)
            elif m.topic == "/smoothed/state":
                row = (p["q_body_icrs"], p["bias"], p["cov_diag"])
                sm_t.append(m.t_s)
                sm_q.append(row[0])
                sm_b.append(row[1])
                sm_var.append(row[2])
            elif m.topic == "/truth/state":
                q = p["q_body_icrs"]
                tru_t.append(m.t_s)
                tru_q.append(q)
            elif m.topic == "/starid/solution":
                mode, ok = p["mode"], bool(p.get("fix_accepted", p["ok"]))
                sol_t.append(m.t_s)
                sol_mode.append(mode)
                sol_ok.append(ok)
        except (KeyError, TypeError, AttributeError):
            unreadable[m.topic] = unreadable.get(m.topic, 0) + 1
    files: list[Path] = []
    est_t, est_q = np.asarray(est_t), np.asarray(est_q, dtype=float).reshape(-1, 4)
    est_var = np.asarray(est_var, dtype=float).reshape(-1, 6)
    order = np.argsort(sm_t, kind="stable")  # written after the filter's, in one block
    sm_t = np.asarray(sm_t, dtype=float)[order]
    sm_q = np.asarray(sm_q, dtype=float).reshape(-1, 4)[order]
    sm_b = np.asarray(sm_b, dtype=float).reshape(-1, 3)[order]
    sm_var = np.asarray(sm_var, dtype=float).reshape(-1, 6)[order]
    lines = [f"# Replay report: {Path(log_path).name}", ""]

    # attitude error against truth, with the filter's 3σ bound
    fig, ax = plt.subplots(figsize=(9, 4))
    if len(tru_t) and len(est_t):
        tru_t_a, tru_q_a = np.asarray(tru_t), np.asarray(tru_q, dtype=float)
        k = np.clip(np.searchsorted(tru_t_a, est_t), 0, len(tru_t_a) - 1)
        err = np.degrees(rot.angle_between(est_q, tru_q_a[k]))
        bound = 3 * np.degrees(np.sqrt(est_var[:, :3].sum(axis=1)))
        ax.plot(est_t, err, lw=0.8, label="attitude error")
        ax.plot(est_t, bound, "r--", lw=0.8, label="3σ bound")
        ax.set_yscale("log")
        inside = float(np.mean(err <= bound)) if len(err) else float("nan")
        lines += [f"- attitude error: RMS {np.sqrt(np.mean(err**2)):.4f}°, max {err.max():.4f}°"
                  f", within 3σ for {100 * inside:.1f} % of estimates", ""]
        if len(sm_t):
            ks = np.clip(np.searchsorted(tru_t_a, sm_t), 0, len(tru_t_a) - 1)
            err_s = np.degrees(rot.angle_between(sm_q, tru_q_a[ks]))
            bound_s = 3 * np.degrees(np.sqrt(sm_var[:, :3].sum(axis=1)))
            ax.plot(sm_t, err_s, lw=0.8, color="tab:green", label="smoothed error")
            ax.plot(sm_t, bound_s, ":", color="tab:green", lw=0.8, label="smoothed 3σ")
            lines += [f"- smoothed attitude error: RMS {np.sqrt(np.mean(err_s**2)):.4f}°, max "
                      f"{err_s.max():.4f}°, within 3σ for "
                      f"{100 * float(np.mean(err_s <= bound_s)):.1f} % of states", ""]
    else:
        ax.text(0.5, 0.5, "no truth in this log", ha="center", transform=ax.transAxes)
    ax.set(xlabel="t [s]", ylabel="deg", title="Attitude error")
    ax.legend(loc="upper right") if len(tru_t) else None
    files.append(_save(fig, out / "attitude_error.png"))

    # boresight track (body +z) on the sky
    fig, ax = plt.subplots(figsize=(6, 5))
    if len(est_q):
        z = rot.rotate(rot.inverse(est_q), np.array([0.0, 0.0, 1.0]))
        ra, dec = rot.vector_to_radec(z)
        ax.plot(np.degrees(ra), np.degrees(dec), ".", ms=2)
        ax.invert_xaxis()  # RA increases to the left, as on a sky chart
    ax.set(xlabel="RA [deg]", ylabel="Dec [deg]", title="Body +z (boresight) track")
    files.append(_save(fig, out / "boresight_track.png"))

    # star-ID outcome per frame
    fig, ax = plt.subplots(figsize=(9, 2.8))
    codes = {"tracking": 2, "lost-in-space": 1}
    y = [codes.get(mo, 0) if ok else 0 for mo, ok in zip(sol_mode, sol_ok, strict=True)]
    ax.scatter(sol_t, y, s=4, c=y, cmap="viridis", vmin=0, vmax=2)
    ax.set_yticks([0, 1, 2], ["no fix", "lost-in-space", "tracking"])
    ax.set(xlabel="t [s]", title="Star identification per frame")
    files.append(_save(fig, out / "starid_outcome.png"))
    if sol_t:
        n_ok = int(np.sum(sol_ok))
        lines += [f"- frames: {len(sol_t)}, accepted fixes {n_ok} "
                  f"({100 * n_ok / len(sol_t):.1f} %), tracking "
                  f"{sum(m == 'tracking' for m in sol_mode)}, lost-in-space "
                  f"{sum(m == 'lost-in-space' for m in sol_mode)}", ""]

    # gyro bias estimate with 3σ
    fig, ax = plt.subplots(figsize=(9, 4))
    if len(est_b):
        b = np.degrees(np.asarray(est_b, dtype=float)) * 3600
        s3 = 3 * np.degrees(np.sqrt(est_var[:, 3:])) * 3600
        for i, c in enumerate("xyz"):
            ax.plot(est_t, b[:, i], lw=0.8, label=f"bias {c}")
            ax.fill_between(est_t, b[:, i] - s3[:, i], b[:, i] + s3[:, i], alpha=0.15)
        if len(sm_t):
            bs = np.degrees(sm_b) * 3600
            for i, c in enumerate("xyz"):
                ax.plot(sm_t, bs[:, i], "--", lw=0.8, color=f"C{i}", label=f"smoothed {c}")
        ax.legend(loc="upper right")
    ax.set(xlabel="t [s]", ylabel="deg/h", title="Gyro bias estimate (±3σ)")
    files.append(_save(fig, out / "bias.png"))

    # innovation NIS
    fig, ax = plt.subplots(figsize=(9, 3))
    if nis_v:
        ax.semilogy(nis_t, np.maximum(nis_v, 1e-6), ".", ms=2)
    ax.set(xlabel="t [s]", ylabel="NIS", title="Innovation NIS (star fixes: 3 dof)")
    files.append(_save(fig, out / "nis.png"))

    found = log_problems(reader)
    found += [f"{n} message(s) on {t} are not in adfusion's format: not plotted"
              for t, n in unreadable.items()]
    if found:
        lines += ["## Problems", ""] + [f"- {p}" for p in found] + [""]
    lines += ["Plots: " + ", ".join(f"[{f.name}]({f.name})" for f in files), ""]
    md = out / "summary.md"
    md.write_text("\n".join(lines))
    files.append(md)
    return files


def log_problems(reader: McapLogReader) -> list[str]:
    """What a replayed log says went wrong: damage found reading it, the run's input
    problems and dropped counts (``problems`` metadata), an ``incomplete`` run, and the
    defaults it assumed (``assumptions``)."""
    out = [f"reading this log: {p}" for p in reader.problems]
    inc = reader.metadata.get("incomplete")
    if isinstance(inc, dict):
        out.append(f"INCOMPLETE run: {inc.get('reason', '?')} "
                   f"({inc.get('messages_written', '?')} messages written)")
    probs = reader.metadata.get("problems")
    if isinstance(probs, dict):
        out += [f"input: {p}" for p in probs.get("input", []) if isinstance(p, str)]
    assumed = reader.metadata.get("assumptions")
    if isinstance(assumed, dict) and assumed:
        out.append("assumed (the input had no configuration): " + ", ".join(
            f"{k} = {v}" for k, v in assumed.items()))
    return out


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
