"""The report of a replayed log (``adfusion report``): one HTML page with its plots
embedded, the PNGs beside it, and a short ``summary.md``.

Plots, one question each, labelled with units:

* ``attitude_error.png`` — the error per body axis (cross-boresight x, y and roll) against
  the truth with the filter's ±3σ band and markers at the accepted fixes; a log without
  truth gets the filter's own 3σ history per axis instead;
* ``nis.png`` — the star-fix NIS with its χ²(3) 95 % bounds and a running mean with the
  bounds of a mean of that many;
* ``stars.png`` — stars detected and matched per frame, and the star-ID mode timeline;
* ``residuals.png`` — the identified stars' residuals (arcsec): per-frame RMS and all;
* ``solve_time.png`` — identification time per frame (ms), by mode;
* ``bias.png`` — the gyro-bias estimate with ±3σ and the truth when the log has it; for a
  video-only log (no gyro) the filter's body-rate estimate (deg/s) instead;
* ``boresight_track.png`` — where body +z pointed (RA/Dec).

A log with no estimates is an error (replay it first), not a page of empty plots.

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

import base64
import html
from pathlib import Path

import numpy as np

from adfusion.app.errors import UsageError
from adfusion.logs import McapLogReader, topics
from adfusion.maths import rotations as rot
from adfusion.outfiles import refuse_overwrite

__all__ = ["log_assumed", "log_problems", "log_streams", "report"]

_CHI2_3 = (0.2157952826, 9.3484036045)  # χ²(3) 2.5 % and 97.5 % points
_WINDOW = 20  # frames in the NIS running mean


def _chi2_mean_bounds(dof: int, n: int) -> tuple[float, float]:
    """95 % bounds of the mean of ``n`` χ²(dof) values."""
    from scipy.stats import chi2

    return (float(chi2.ppf(0.025, dof * n) / n), float(chi2.ppf(0.975, dof * n) / n))


class _Log:
    """The topics of a replayed log the report draws, as arrays."""

    def __init__(self, path, progress: bool = False) -> None:
        self.reader = reader = McapLogReader(path)
        est, sm, truth, sol, err, live = [], [], [], [], [], []
        messages = iter(reader)
        if progress:
            from tqdm import tqdm

            messages = tqdm(messages, total=reader.message_count, unit="msg",
                            mininterval=0.5, desc="report")
        for m in messages:
            if m.topic == topics.ESTIMATE_STATE:
                est.append(m.payload)
            elif m.topic == topics.SMOOTHED_STATE:
                sm.append(m.payload)
            elif m.topic == topics.TRUTH_STATE:
                truth.append(m.payload)
            elif m.topic == topics.STARID_SOLUTION:
                sol.append((m.t_s, m.payload))
            elif m.topic == topics.ESTIMATE_ERROR:
                err.append(m.payload)
            elif m.topic == topics.LIVE_STATUS:
                live.append(m.payload)
        if not est:
            raise UsageError(f"{path}: no {topics.ESTIMATE_STATE} messages, nothing to report: "
                             "replay the log first (adfusion replay INPUT -o OUT.mcap)")
        self.t = np.array([p["t"] for p in est], dtype=float)
        self.q = np.array([p["q_body_icrs"] for p in est], dtype=float)
        self.var = np.array([p["cov_diag"] for p in est], dtype=float).reshape(len(est), -1)
        self.video_only = est[-1].get("bias") is None
        self.bias = None if self.video_only else np.array([p["bias"] for p in est], float)
        self.omega = (np.array([p["omega"] for p in est], float)
                      if all("omega" in p for p in est) else None)
        self.nis = np.array([np.nan if p.get("nis") is None else p["nis"] for p in est])
        # fixes that restarted the filter (no rate between frames, or a gate that kept
        # rejecting): their NIS is that of the prediction they replaced, not a test of it
        # (a replay's entries are {"input", "reason"} objects, an acs log's [input, reason])
        self.restarted = np.array([any("re-initialised" in str(r) for r in p.get("rejected")
                                       or []) for p in est], bool)
        self.sm = sm
        self.truth_t = np.array([p["t"] for p in truth], dtype=float)
        self.truth_q = np.array([p["q_body_icrs"] for p in truth], dtype=float).reshape(-1, 4)
        self.truth_bias = (np.array([p["bias"] for p in truth], float)
                           if truth and all("bias" in p for p in truth) else None)
        self.truth_omega = (np.array([p["omega"] for p in truth], float)
                            if truth and all("omega" in p for p in truth) else None)
        self.sol_t = np.array([t for t, _ in sol], dtype=float)
        self.sol = [p for _, p in sol]
        self.err = err
        self.live = live  # /live/status of an `adfusion live` run

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(self.truth_t, t - 1e-9), 0, len(self.truth_t) - 1)
        return k


#: the files :func:`report` writes into its folder (``LIVE_REPORT_FILES`` for a live run's
#: log only)
LIVE_REPORT_FILES = ("latency.png",)
REPORT_FILES = ("attitude_error.png", "nis.png", "stars.png", "residuals.png", "solve_time.png",
                "bias.png", "boresight_track.png", "latency.png", "summary.md", "report.html")


def report(log_path: str | Path, out_dir: str | Path, *, progress: bool = False) -> list[Path]:
    """Write the plots, ``report.html`` and ``summary.md`` for a replayed log; returns the
    files written (the HTML page last). ``progress`` shows a bar while reading the log."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    refuse_overwrite([("-o", out / f) for f in REPORT_FILES], [log_path])  # before any work
    log = _Log(log_path, progress)  # a log that cannot be reported leaves no folder behind
    out.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []
    files = [
        _attitude_error(log, out, lines), _nis(log, out, lines), _stars(log, out, lines),
        _residuals(log, out, lines), _solve_time(log, out, lines), _bias(log, out, lines),
        _track(log, out)]
    record = log.reader.metadata.get("live")
    if log.live:  # an `adfusion live` run: its pace
        files.append(_latency(log, out, lines))
    if isinstance(record, dict) and "frames_arrived" in record:
        from adfusion.app.replay.sinks import live_line

        lines.append(live_line(record))
    title = "Live report" if log.live or record else "Replay report"
    # how much of each input stream the run had and used (as the replay's summary said),
    # then damage found reading the log, the run's input problems and dropped counts, an
    # incomplete run, the defaults it assumed
    lines += log_streams(log.reader)
    lines += [f"problem: {p}" for p in log_problems(log.reader)]
    lines += [f"note: {n}" for n in log_assumed(log.reader)]
    name = Path(log_path).name
    md = out / "summary.md"
    md.write_text("\n".join([f"# {title}: {name}", ""] + [f"- {x}" for x in lines]
                            + ["", "Plots: " + ", ".join(f"[{f.name}]({f.name})"
                                                         for f in files), ""]))
    page = out / "report.html"
    figs = "\n".join(
        f'<figure><img alt="{f.stem}" src="data:image/png;base64,'
        f'{base64.b64encode(f.read_bytes()).decode()}"><figcaption>{f.name}</figcaption>'
        "</figure>" for f in files)
    page.write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>adfusion report: {html.escape(name)}</title><style>body{{font-family:"
        "sans-serif;max-width:1100px;margin:auto} img{max-width:100%} figure{margin:1em 0}"
        f"</style></head><body><h1>{title}: {html.escape(name)}</h1><ul>"
        + "".join(f"<li>{html.escape(x)}</li>" for x in lines) + f"</ul>{figs}</body></html>")
    return [*files, md, page]


def log_streams(reader: McapLogReader) -> list[str]:
    """How much of each input stream (frames, gyro, magnetometer) a replay had and used,
    and the frames it met without the gyro: the replay summary's ``streams:`` lines, from
    the log's ``streams`` metadata (none for a log written before it was recorded)."""
    from adfusion.app.replay.sinks import streams_lines

    rec = reader.metadata.get("streams")
    if not isinstance(rec, dict):
        return []
    streams = {k: v for k, v in rec.items() if isinstance(v, dict)
               and {"messages", "used", "first_s", "last_s"} <= set(v)}
    try:
        return streams_lines(streams, int(rec.get("frames_without_gyro", 0)),
                             int(rec.get("frames", 0)))
    except (TypeError, ValueError):  # a record this version does not know: not drawn
        return []


def log_problems(reader: McapLogReader) -> list[str]:
    """What a replayed log says went wrong: damage found reading it, the run's input
    problems and dropped counts (``problems`` metadata), an ``incomplete`` run. (The
    defaults a run was told to assume are no problem: :func:`log_assumed`.)"""
    out = [f"reading this log: {p}" for p in reader.problems]
    inc = reader.metadata.get("incomplete")
    if isinstance(inc, dict):
        out.append(f"INCOMPLETE run: {inc.get('reason', '?')} "
                   f"({inc.get('messages_written', '?')} messages written)")
    probs = reader.metadata.get("problems")
    if isinstance(probs, dict):
        out += [f"input: {p}" for p in probs.get("input", []) if isinstance(p, str)]
    return out


def log_assumed(reader: McapLogReader) -> list[str]:
    """The defaults a replay assumed for an input without configuration
    (``--assume-defaults``, the ``assumptions`` metadata): said, but no problem."""
    assumed = reader.metadata.get("assumptions")
    if not (isinstance(assumed, dict) and assumed):
        return []
    return ["assumed (the input had no configuration): " + ", ".join(
        f"{k} = {v}" for k, v in assumed.items())]


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _fix_times(log: _Log) -> tuple[np.ndarray, np.ndarray]:
    acc = np.array([bool(p.get("fix_accepted", p["ok"])) for p in log.sol], dtype=bool)
    lis = np.array([p["mode"] == "lost-in-space" for p in log.sol], dtype=bool)
    return log.sol_t[acc & ~lis], log.sol_t[acc & lis]


def _attitude_error(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    labels = ["x (cross-boresight)", "y (cross-boresight)", "z (roll)"]
    sigma3 = 3 * np.degrees(np.sqrt(np.maximum(log.var[:, :3], 0))) * 3600
    track, lis = _fix_times(log)
    if len(log.truth_t):
        k = log.truth_at(log.t)
        err = np.degrees(rot.log_map(rot.multiply(log.q, rot.inverse(log.truth_q[k])))) * 3600
        for i, ax in enumerate(axes):
            ax.fill_between(log.t, -sigma3[:, i], sigma3[:, i], color="tab:red", alpha=0.15,
                            lw=0, label="±3σ (filter)")
            ax.plot(log.t, err[:, i], lw=0.8, color="tab:blue", label="error vs truth")
            lim = max(float(np.percentile(np.abs(err[:, i]), 99.5)) * 1.5, 1.0)
            ax.set_ylim(-lim, lim)
            ax.set_ylabel(f"{labels[i]} [arcsec]")
        if log.sm:  # replay --smooth: the smoother's history beside the filter's
            sm = sorted(log.sm, key=lambda p: p["t"])
            t_s = np.array([p["t"] for p in sm], dtype=float)
            q_s = np.array([p["q_body_icrs"] for p in sm], dtype=float)
            var_s = np.array([p["cov_diag"][:3] for p in sm], dtype=float)
            ks = log.truth_at(t_s)
            err_s = np.degrees(rot.log_map(rot.multiply(q_s, rot.inverse(log.truth_q[ks]))))
            for i, ax in enumerate(axes):
                ax.plot(t_s, err_s[:, i] * 3600, lw=0.8, color="tab:green",
                        label="smoothed error")
            tot_s = np.linalg.norm(err_s, axis=1)
            bound_s = 3 * np.degrees(np.sqrt(var_s.sum(axis=1)))
            lines.append(f"smoothed attitude error: RMS {np.sqrt(np.mean(tot_s**2)):.4f}°, "
                         f"max {tot_s.max():.4f}°, within 3σ for "
                         f"{100 * float(np.mean(tot_s <= bound_s)):.1f} % of states")
        inside = np.mean(np.all(np.abs(err) <= sigma3, axis=1))
        tot = np.degrees(rot.angle_between(log.q, log.truth_q[k]))
        lines.append(f"attitude error vs truth: RMS {np.sqrt(np.mean(tot**2)):.4f}°, max "
                     f"{tot.max():.4f}°; per axis RMS x/y/roll "
                     + "/".join(f"{np.sqrt(np.mean(err[:, i] ** 2)):.1f}" for i in range(3))
                     + f" arcsec; all three inside ±3σ for {100 * inside:.1f} % of estimates")
        title = "Attitude error per body axis with the filter's ±3σ"
    else:
        for i, ax in enumerate(axes):
            ax.semilogy(log.t, np.maximum(sigma3[:, i], 1e-3), lw=0.8, color="tab:red",
                        label="3σ (filter)")
            ax.set_ylabel(f"{labels[i]} 3σ [arcsec]")
        lines.append("no truth in this log: the filter's own 3σ is drawn (median x/y/roll "
                     + "/".join(f"{np.median(sigma3[:, i]):.1f}" for i in range(3))
                     + " arcsec)")
        title = "Attitude uncertainty per body axis (3σ; no truth in this log)"
    for ax in axes:
        y0 = ax.get_ylim()[0]
        if len(track):
            ax.plot(track, np.full(len(track), y0), "|", color="tab:green", ms=6,
                    label="tracking fix")
        if len(lis):
            ax.plot(lis, np.full(len(lis), y0), "v", color="tab:purple", ms=5,
                    label="lost-in-space fix")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[0].set_title(title)
    axes[-1].set_xlabel("t [s]")
    return _save(fig, out / "attitude_error.png")


def _nis(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.5))
    ok = np.isfinite(log.nis) & ~log.restarted
    t, v = log.t[ok], log.nis[ok]
    n_restarts = int(np.sum(log.restarted))
    if n_restarts:
        lines.append(f"the filter restarted from a lost-in-space fix at {n_restarts} of "
                     f"{len(log.t)} estimates (no rate between frames, or fixes its gate kept "
                     "rejecting): rates and NIS across a restart mean nothing, and those "
                     "fixes are left out of the NIS")
    if len(v):
        ax.semilogy(t, np.maximum(v, 1e-4), ".", ms=3, color="tab:blue", label="NIS per fix")
        lo, hi = _CHI2_3
        ax.axhline(lo, color="k", ls=":", lw=0.8, label="χ²(3) 95 % bounds")
        ax.axhline(hi, color="k", ls=":", lw=0.8)
        n = min(_WINDOW, len(v))
        mean = np.convolve(v, np.ones(n) / n, mode="valid")
        ax.semilogy(t[n - 1:], mean, color="tab:orange", lw=1.2, label=f"running mean ({n})")
        mlo, mhi = _chi2_mean_bounds(3, n)
        ax.axhspan(mlo, mhi, color="tab:orange", alpha=0.12, label=f"95 % of a mean of {n}")
        inside = float(np.mean((v >= lo) & (v <= hi)))
        lines.append(f"star-fix NIS: mean {np.mean(v):.2f} (3 expected), inside the χ²(3) "
                     f"95 % bounds for {100 * inside:.1f} % of {len(v)} fixes")
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    else:
        ax.text(0.5, 0.5, "no star fix was tested against a prediction", ha="center",
                transform=ax.transAxes)
    ax.set(xlabel="t [s]", ylabel="NIS (dimensionless)",
           title="Normalised innovation squared of the star fixes (3 dof)")
    return _save(fig, out / "nis.png")


def _stars(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1.2]})
    det = np.array([p.get("n_detections", 0) for p in log.sol])
    matched = np.array([len(p["matches"]) for p in log.sol])
    ax.plot(log.sol_t, det, lw=0.8, color="tab:gray", label="detected")
    ax.plot(log.sol_t, matched, lw=0.8, color="tab:green", label="matched")
    ax.set(ylabel="stars per frame", title="Stars detected and matched per frame")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    codes = np.array([(2 if p["mode"] == "tracking" else 1)
                      if p.get("fix_accepted", p["ok"]) else 0 for p in log.sol])
    for code, color, name in ((0, "tab:red", "no fix"), (1, "tab:purple", "lost-in-space"),
                              (2, "tab:green", "tracking")):
        sel = codes == code
        ax2.plot(log.sol_t[sel], codes[sel], "|", color=color, ms=8, label=name)
    ax2.set_yticks([0, 1, 2], ["no fix", "lost-in-space", "tracking"])
    ax2.set_ylim(-0.5, 2.5)
    ax2.set(xlabel="t [s]", title="Star-ID mode per frame")
    if len(log.sol):
        lines.append(f"frames: {len(log.sol)}, accepted fixes {int(np.sum(codes > 0))} "
                     f"({100 * np.mean(codes > 0):.1f} %), tracking {int(np.sum(codes == 2))}, "
                     f"lost-in-space {int(np.sum(codes == 1))}; stars detected median "
                     f"{np.median(det):.0f}, matched median {np.median(matched):.0f}")
    return _save(fig, out / "stars.png")


def _residuals(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.5))
    ts, rs, rms_t, rms = [], [], [], []
    for t, p in zip(log.sol_t, log.sol, strict=True):
        r = p.get("residuals_arcsec") or []
        if r:
            ts += [t] * len(r)
            rs += r
            rms_t.append(t)
            rms.append(float(np.sqrt(np.mean(np.square(r)))))
    if rs:
        ax.plot(ts, rs, ".", ms=1.5, color="tab:gray", alpha=0.5, label="each matched star")
        ax.plot(rms_t, rms, lw=0.9, color="tab:blue", label="RMS per frame")
        ax.set_ylim(0, float(np.percentile(rs, 99.5)) * 1.3)
        ax.legend(loc="upper right", fontsize=8)
        lines.append(f"star residuals: median per-frame RMS {np.median(rms):.1f} arcsec")
    else:
        ax.text(0.5, 0.5, "no identified stars", ha="center", transform=ax.transAxes)
    ax.set(xlabel="t [s]", ylabel="residual [arcsec]",
           title="Residuals of the identified stars at the solution")
    ax.grid(alpha=0.3)
    return _save(fig, out / "residuals.png")


def _latency(log: _Log, out: Path, lines: list[str]) -> Path:
    """A live run's latency per frame (arrival → estimate published) and the frames
    dropped so far (``/live/status``)."""
    import matplotlib.pyplot as plt

    t = np.array([p["t"] for p in log.live], float)
    ms = np.array([p["latency_ms"] for p in log.live], float)
    dropped = np.array([p["dropped"] for p in log.live], float)
    fig, ax = plt.subplots(figsize=(10, 3.2))
    ax.plot(t, ms, ".", ms=3, color="tab:blue",
            label=f"latency (median {np.median(ms):.1f} ms, p95 {np.percentile(ms, 95):.1f})")
    ax.set(xlabel="t [s]", ylabel="latency [ms]",
           title="Live: frame arrival → estimate published")
    ax.grid(alpha=0.3)
    right = ax.twinx()
    right.step(t, dropped, where="post", color="tab:red", label="frames dropped so far")
    right.set_ylabel("dropped")
    handles = ax.get_legend_handles_labels()[0] + right.get_legend_handles_labels()[0]
    ax.legend(handles, [h.get_label() for h in handles], loc="upper left", fontsize=8)
    return _save(fig, out / "latency.png")


def _solve_time(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.2))
    ms = np.array([np.nan if p.get("time_ms") is None else p["time_ms"] for p in log.sol])
    mode = np.array([p["mode"] or "" for p in log.sol])
    for name, color in (("tracking", "tab:green"), ("lost-in-space", "tab:purple")):
        sel = mode == name
        if sel.any():
            ax.semilogy(log.sol_t[sel], np.maximum(ms[sel], 1e-3), ".", ms=3, color=color,
                        label=f"{name} (median {np.nanmedian(ms[sel]):.2f} ms)")
    if len(ms) and np.isfinite(ms).any():
        ax.legend(loc="upper right", fontsize=8)
        lines.append(f"identification time: median {np.nanmedian(ms):.2f} ms, max "
                     f"{np.nanmax(ms):.1f} ms per frame")
    ax.set(xlabel="t [s]", ylabel="solve time [ms]", title="Identification time per frame")
    ax.grid(alpha=0.3)
    return _save(fig, out / "solve_time.png")


def _bias(log: _Log, out: Path, lines: list[str]) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    if log.video_only:  # no gyro: the rate filter's body rate is the state to show
        if log.omega is not None:
            w = np.degrees(log.omega)
            s3 = 3 * np.degrees(np.sqrt(np.maximum(log.var[:, 3:6], 0)))
            for i, c in enumerate("xyz"):
                ax.plot(log.t, w[:, i], lw=0.8, color=f"C{i}", label=f"rate {c}")
                ax.fill_between(log.t, w[:, i] - s3[:, i], w[:, i] + s3[:, i],
                                color=f"C{i}", alpha=0.15, lw=0)
            if log.truth_omega is not None and len(log.truth_t):
                tw = np.degrees(log.truth_omega)
                for i, c in enumerate("xyz"):
                    ax.plot(log.truth_t, tw[:, i], "--", lw=0.8, color=f"C{i}",
                            label=f"truth {c}")
            settled = w[min(len(w) - 1, max(3, len(w) // 20)):]  # after the first fixes
            lo, hi = float(settled.min()), float(settled.max())
            pad = max(0.2 * (hi - lo), 1.0)
            ax.set_ylim(lo - pad, hi + pad)
            ax.legend(loc="upper right", fontsize=8, ncol=2)
        ax.set(xlabel="t [s]", ylabel="body rate [deg/s]",
               title="Body-rate estimate (±3σ; video only: no gyro, no bias)")
    else:
        b = np.degrees(log.bias) * 3600
        s3 = 3 * np.degrees(np.sqrt(np.maximum(log.var[:, 3:6], 0))) * 3600
        for i, c in enumerate("xyz"):
            ax.plot(log.t, b[:, i], lw=0.8, color=f"C{i}", label=f"estimate {c}")
            ax.fill_between(log.t, b[:, i] - s3[:, i], b[:, i] + s3[:, i], color=f"C{i}",
                            alpha=0.15, lw=0)
        if log.truth_bias is not None:
            tb = np.degrees(log.truth_bias) * 3600
            for i, c in enumerate("xyz"):
                ax.plot(log.truth_t, tb[:, i], "--", lw=1.0, color=f"C{i}", label=f"truth {c}")
            final = np.abs(b[-1] - tb[log.truth_at(log.t[-1:])][0])
            lines.append("gyro bias at the end: error x/y/z " + "/".join(
                f"{v:.1f}" for v in final) + " deg/h")
        lim = max(float(np.percentile(np.abs(b[len(b) // 10:]), 99)) * 2, 1.0)
        ax.set_ylim(-lim, lim)
        ax.legend(loc="upper right", fontsize=8, ncol=2)
        ax.set(xlabel="t [s]", ylabel="gyro bias [deg/h]",
               title="Gyro bias estimate (±3σ) and truth")
    ax.grid(alpha=0.3)
    return _save(fig, out / "bias.png")


def _track(log: _Log, out: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 5))
    z = rot.rotate(rot.inverse(log.q), np.array([0.0, 0.0, 1.0]))
    ra, dec = rot.vector_to_radec(z)
    ax.plot(np.degrees(ra), np.degrees(dec), ".", ms=2, label="estimate")
    if len(log.truth_t):
        zt = rot.rotate(rot.inverse(log.truth_q), np.array([0.0, 0.0, 1.0]))
        rt, dt_ = rot.vector_to_radec(zt)
        ax.plot(np.degrees(rt), np.degrees(dt_), lw=0.6, color="k", alpha=0.5, label="truth")
        ax.legend(fontsize=8)
    ax.invert_xaxis()  # RA increases to the left, as on a sky chart
    ax.set(xlabel="RA [deg]", ylabel="Dec [deg]", title="Body +z (boresight) on the sky")
    return _save(fig, out / "boresight_track.png")
