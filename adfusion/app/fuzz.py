"""Fuzzing the promises of issue 16: no traceback, no silent loss, no wrong attitude.

Each ``check_*`` takes one generated case (its parameters drawn by ``hypothesis`` in
``tests/test_fuzz.py``, or by a seeded generator in ``benchmarks/fuzz.py --minutes N``),
runs the real code on it, and returns how it ended — ``"ok"`` or ``"reported"`` (an input
problem said so) — or raises :class:`FuzzViolation` naming the broken promise:

* ``traceback`` — an exception other than the documented ones escaped;
* ``silent-loss`` — messages went missing with no problem reported, or more was lost than
  the damaged chunk when the file has an index;
* ``wrong-attitude`` — an accepted solution the truth contradicts;
* ``cli`` — a command exited with a code other than 0/1/2, or a failure was not one line.

Example:
    >>> import tempfile
    >>> corpus = ReaderCorpus(tempfile.mkdtemp())
    >>> check_reader(corpus, "flip", offset=corpus.chunks[2][0] + 100, length=4)
    'reported'
"""

from __future__ import annotations

import contextlib
import io
import os
import random
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.fuzz_violation import FuzzViolation
from adfusion.plain import listed

__all__ = ["FuzzViolation", "ReaderCorpus", "SolverBank", "check_cli", "check_reader",
           "check_solver", "check_sources", "cli_argv", "run"]




# --------------------------------------------------------------------------- MCAP reader
class ReaderCorpus:
    """An intact log of many small chunks, with mcap's own reading of it as the truth:
    chunk byte ranges, each chunk's message count, and every message's identity."""

    def __init__(self, folder: str | os.PathLike[str], n_frames: int = 24,
                 compression: str = "zstd") -> None:
        from mcap.reader import make_reader

        from adfusion.logs import LogWriter

        self.folder = Path(folder)
        self.path = self.folder / f"intact-{compression}.mcap"
        rng = np.random.default_rng(5)
        with LogWriter(self.path, chunk_size=6 * 1024, compression=compression) as log:
            log.add_metadata("config", {"q_body_cam": [1.0, 0.0, 0.0, 0.0], "seed": 5})
            log.add_camera_model({"width": 32, "height": 24, "K": [[40.0, 0, 15.5],
                                  [0, 40.0, 11.5], [0, 0, 1]], "D": [0, 0, 0, 0, 0]})
            for i in range(n_frames):
                t = i / 10
                for j in range(5):
                    log.write_json("/imu/gyro", t + j / 50, {"omega": [0.01 * i, 0.0, j]})
                log.write_json("/mag", t, {"b_body": [2e4 + i, 0.0, -4e4]})
                log.write_image(t, rng.integers(0, 255, (24, 32), dtype=np.uint8))
                log.write_json("/estimate/state", t, {"t": t, "q_body_icrs": [1, 0, 0, 0],
                                                      "bias": [0, 0, 0], "cov_diag": [0] * 6,
                                                      "nis": {"star fix": 1.0}})
        self.data = self.path.read_bytes()
        with open(self.path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            self.messages = {(m.channel.topic, m.log_time, bytes(m.data))
                             for m in _mcap_messages(reader)}
        counts: dict[int, int] = {}
        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk
        from mcap.records import Message as McapMessage
        from mcap.stream_reader import breakup_chunk

        self.chunks: list[tuple[int, int, int]] = []
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            start = ci.chunk_start_offset
            body = self.data[start + 9:start + ci.chunk_length]
            chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
            n = sum(isinstance(r, McapMessage) for r in breakup_chunk(chunk))
            counts[start] = n
            self.chunks.append((start, start + ci.chunk_length, n))
        self.total = len(self.messages)
        self.summary_start = max(e for _, e, _ in self.chunks)

    def damaged(self, kind: str, offset: int, length: int, name: str = "case.mcap") -> Path:
        """A copy with ``length`` bytes at ``offset`` flipped (``"flip"``), zeroed
        (``"zero"``), cut out (``"cutout"``), or the file cut there (``"truncate"``)."""
        data = bytearray(self.data)
        offset = max(0, min(offset, len(data)))
        end = min(len(data), offset + max(length, 0))
        if kind == "flip":
            for i in range(offset, end):
                data[i] ^= 0xFF
        elif kind == "zero":
            data[offset:end] = bytes(end - offset)
        elif kind == "cutout":
            del data[offset:end]
        elif kind == "truncate":
            del data[offset:]
        else:
            raise ValueError(f"unknown damage {kind!r}")
        path = self.folder / name
        path.write_bytes(bytes(data))
        return path

    def chunk_of(self, offset: int, end: int) -> tuple[int, int, int] | None:
        """The chunk holding the whole byte range [offset, end), if one does."""
        for c in self.chunks:
            if c[0] <= offset and end <= c[1]:
                return c
        return None


def _mcap_messages(reader: Any):
    for _schema, channel, message in reader.iter_messages(log_time_order=True):
        yield type("M", (), {"channel": channel, "log_time": message.log_time,
                             "data": message.data})


def check_reader(corpus: ReaderCorpus, kind: str, offset: int, length: int) -> str:
    """Read a damaged copy: only :class:`~adfusion.logs.reader.NotMcapError` may escape;
    messages come in time order and are all genuine; fewer than the intact file's means
    a problem was reported; damage inside one chunk of a file whose summary survived costs
    at most that chunk."""
    from adfusion.logs import McapLogReader
    from adfusion.logs.reader import NotMcapError

    path = corpus.damaged(kind, offset, length)
    end = offset + length
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = McapLogReader(path)
            raw = [(c.topic, m.log_time, bytes(m.data)) for c, m in reader.raw_records()]
            decoded = sum(1 for _ in reader.messages())
    except NotMcapError:
        if offset < 8 and kind != "truncate":
            return "reported"
        raise FuzzViolation("traceback", f"{kind} at {offset}+{length}: NotMcapError on a "
                            "file whose magic is intact") from None
    except Exception as exc:
        raise FuzzViolation("traceback", f"{kind} at {offset}+{length}: "
                            f"{type(exc).__name__}: {exc}") from exc
    times = [t for _, t, _ in raw]
    if times != sorted(times):
        raise FuzzViolation("silent-loss", f"{kind} at {offset}+{length}: out of time order")
    fake = [r for r in raw if r not in corpus.messages]
    if fake:
        raise FuzzViolation("silent-loss", f"{kind} at {offset}+{length}: {len(fake)} "
                            "message(s) that the intact file does not hold were delivered")
    lost = corpus.total - len(set(raw))
    problems = reader.problems
    if (lost or decoded < len(raw)) and not problems:
        raise FuzzViolation("silent-loss", f"{kind} at {offset}+{length}: {lost} message(s) "
                            "lost, none reported")
    inside = corpus.chunk_of(offset, end)
    footer_intact = kind in ("flip", "zero") and end <= corpus.summary_start
    if inside is not None and footer_intact and lost > inside[2]:
        raise FuzzViolation("silent-loss", f"{kind} at {offset}+{length} inside one chunk "
                            f"({inside[2]} messages) lost {lost}")
    return "reported" if problems else "ok"


# --------------------------------------------------------------------------- solver
@dataclass
class SolverBank:
    """Solvers for a few cameras, built once (a pattern index takes seconds)."""

    fovs_deg: tuple[float, ...] = (12.0, 20.0, 30.0)
    mag_limit: float = 6.0
    solvers: dict[float, Any] = field(default_factory=dict)

    def get(self, fov_deg: float):
        from adfusion import starid

        if not self.solvers:
            cat = starid.Catalog.hipparcos(mag_limit=self.mag_limit, epoch=2025.0)
            for f in self.fovs_deg:
                self.solvers[f] = starid.Solver(cat, starid.Camera.pinhole(640, 480, f))
        return self.solvers[min(self.fovs_deg, key=lambda f: abs(f - fov_deg))]


def check_solver(bank: SolverBank, seed: int, fov_deg: float, n_false: int,
                 drop_frac: float, sigma_px: float, prior: str, prior_error_deg: float,
                 prior_sigma_deg: float, shuffle: bool = True) -> str:
    """Solve a frame of a random attitude (catalogue stars with centroid noise, some
    dropped, false stars added), lost in space or with a prior that may be wrong. Only
    ``ValueError`` (documented) may escape; an accepted attitude must agree with the truth
    within max(10σ, 0.2°)."""
    from adfusion.maths import rotations as rot
    from adfusion.starid.solver import Prior

    solver = bank.get(fov_deg)
    cam = solver.camera
    rng = np.random.default_rng(seed)
    q = rot.normalize(rng.normal(size=4))
    _, xy = solver.stars_in_view(q)
    xy = xy + rng.normal(0.0, sigma_px, xy.shape)
    keep = rng.random(len(xy)) >= drop_frac
    xy = xy[keep]
    false_xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n_false, 2))
    dets = np.vstack([xy, false_xy]) if len(false_xy) else xy
    if shuffle and len(dets):
        dets = dets[rng.permutation(len(dets))]
    p = None
    if prior != "none":
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        err = np.radians(prior_error_deg) * axis
        q_prior = rot.multiply(rot.exp_map(err), q)
        p = Prior(q_prior, prior_sigma_deg)
    try:
        sol = solver.solve(dets, prior=p)
    except ValueError:
        return "reported"
    except Exception as exc:
        raise FuzzViolation("traceback", f"solve seed {seed}: {type(exc).__name__}: "
                            f"{exc}") from exc
    if not sol.ok:
        return "reported"
    error = float(rot.angle_between(sol.q_cam_icrs, q))
    sigma = float(np.sqrt(np.max(np.linalg.eigvalsh(sol.covariance))))
    if error > max(10 * sigma, np.radians(0.2)):
        case = (f"check_solver(bank, {seed}, {fov_deg}, {n_false}, {drop_frac}, {sigma_px}, "
                f"{prior!r}, {prior_error_deg}, {prior_sigma_deg})")
        raise FuzzViolation("wrong-attitude", f"{case} {sol.mode} with {len(sol.matches)} "
                            f"stars: accepted {np.degrees(error):.3f}° off "
                            f"(σ {np.degrees(sigma):.4f}°, p_false {sol.p_false:.1e})")
    return "ok"


# --------------------------------------------------------------------------- sources
def check_sources(folder: str | os.PathLike[str], seed: int) -> str:
    """Random CSV text and bytes, random image files: the sources raise only
    ``ValueError``/``FileNotFoundError`` (documented) or yield finite samples, reporting
    what they skipped."""
    from adfusion.logs import ImageFolderSource, read_sensor_csv

    r = random.Random(seed)
    folder = Path(folder)
    cells = ["0", "0.5", "-1e3", "nan", "inf", "", " ", "a", "1e400", "0x10", "1,5", "é",
             "\x00", "1e-3"]
    cols = ["t_s", "gyro_x", "gyro_y", "gyro_z", "mag_x", "mag_y", "mag_z", "extra"]
    header = r.sample(cols, r.randint(1, len(cols)))
    lines = [",".join(header)]
    for _ in range(r.randint(0, 8)):
        lines.append(",".join(r.choice(cells) for _ in range(r.randint(0, len(header) + 1))))
    text = "\n".join(lines).encode("utf-8", "surrogatepass")
    if r.random() < 0.2:
        text = bytes(r.randrange(256) for _ in range(r.randint(0, 60)))
    csv_path = folder / "s.csv"
    csv_path.write_bytes(text)
    outcome = "ok"
    try:
        problems: list[str] = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            msgs = read_sensor_csv(csv_path, problems)
        for m in msgs:
            values = m.payload.get("omega") or m.payload.get("b_body")
            if not (np.isfinite(m.t_s) and np.all(np.isfinite(values))):
                raise FuzzViolation("silent-loss", f"csv seed {seed}: non-finite sample {m}")
        outcome = "reported" if problems else outcome
    except (ValueError, FileNotFoundError):
        outcome = "reported"
    except FuzzViolation:
        raise
    except Exception as exc:
        raise FuzzViolation("traceback", f"csv seed {seed}: {type(exc).__name__}: "
                            f"{exc}") from exc
    images = folder / "frames"
    images.mkdir(exist_ok=True)
    for p in images.iterdir():
        p.unlink()
    for i in range(r.randint(0, 3)):
        blob = bytes(r.randrange(256) for _ in range(r.randint(0, 200)))
        if r.random() < 0.5:
            import cv2

            _, enc = cv2.imencode(".png", np.full((4, 5), i, np.uint8))
            blob = enc.tobytes()[: r.randint(8, len(enc))] if r.random() < 0.5 else enc.tobytes()
        (images / f"f{i}.png").write_bytes(blob)
    fps = r.choice([10.0, float("nan"), -1.0, 0.0, 1e308, None])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            src = ImageFolderSource(images, fps=fps)
            frames = list(src)
        if not all(np.isfinite(m.t_s) for m in frames):
            raise FuzzViolation("silent-loss", f"images seed {seed}: non-finite frame time")
        if src.problems:
            outcome = "reported"
    except (ValueError, FileNotFoundError):
        outcome = "reported"
    except FuzzViolation:
        raise
    except Exception as exc:
        raise FuzzViolation("traceback", f"images seed {seed}: {type(exc).__name__}: "
                            f"{exc}") from exc
    return outcome


# --------------------------------------------------------------------------- CLI
def cli_argv(r: random.Random, corpus: dict[str, str], out_dir: str) -> list[str]:
    """One command line: a command, its positional inputs from ``corpus`` (damaged and
    foreign files, folders, missing paths), flags with ordinary and absurd values."""
    def number():
        return r.choice(["1", "0", "-1", "nan", "inf", "1e9", "abc", "5.5", "12", "99",
                         "-1e308", "3"])

    paths = list(corpus.values())
    out = os.path.join(out_dir, r.choice(["o.mcap", "sub/o.mcap", "o"]))
    cmd = r.choice(["detect", "solve", "replay", "report", "simulate", "catalog", "demo",
                    "bench", "nonsense"])
    argv = [cmd]
    if cmd in ("detect", "solve"):
        if r.random() < 0.5:
            argv.append("--example")
        if r.random() < 0.6:
            argv.append(r.choice(paths))
        if cmd == "solve":
            for flag in ("--fov", "--fov-error", "--mag-limit", "--epoch", "--sigma"):
                if r.random() < 0.3:
                    argv += [flag, number()]
            if r.random() < 0.2:
                argv += ["--overlay", os.path.join(out_dir, r.choice(["o.png", "o.txt",
                                                                      "x/o.png"]))]
        elif r.random() < 0.3:
            argv += ["--sigma", number()]
    elif cmd == "replay":
        argv += [r.choice(paths), "-o", r.choice([out, out_dir, r.choice(paths)])]
        for flag in ("--no-gyro", "--no-mag", "--json", "--assume-defaults"):
            if r.random() < 0.2:
                argv.append(flag)
        if r.random() < 0.3:
            argv += ["--mag-limit", r.choice(["5", "6.5", "nan", "99", "-3", "12"])]
        if r.random() < 0.2:
            argv += ["--config", r.choice(paths)]
    elif cmd == "report":
        argv += [r.choice(paths), "-o", r.choice([out_dir, os.path.join(out_dir, "rep"),
                                                  r.choice(paths)])]
    elif cmd == "simulate":
        argv += [r.choice(["oedipus", "leo", "mars"]), "-o", r.choice([out, out_dir])]
        argv += ["--duration", r.choice(["0.3", "0", "-1", "nan", "1e9", "inf", "x"])]
        argv.append("--no-render")
    elif cmd == "demo":
        argv += ["--duration", r.choice(["0", "-1", "nan", "x"])]  # never a long real run
    elif cmd == "bench":
        argv += [r.choice(["", "nonsense"])]
    if r.random() < 0.1:
        argv.append("--bogus-flag")
    return [a for a in argv if a != ""]


def check_cli(argv: list[str]) -> str:
    """Run ``adfusion ARGV`` in-process: exit code 0, 1 or 2; a failure is one line on
    stderr (argparse's usage lines aside) and never a traceback."""
    from adfusion.app.cli import main

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            code = main(argv)
        except SystemExit as e:  # argparse inside a sub-command's own parser
            code = e.code if isinstance(e.code, int) else 2
        except BaseException as exc:
            raise FuzzViolation("traceback", f"{argv}: {type(exc).__name__}: {exc}") from exc
    text = err.getvalue()
    if code not in (0, 1, 2):
        raise FuzzViolation("cli", f"{argv}: exit code {code}")
    if "Traceback" in text:
        raise FuzzViolation("traceback", f"{argv}: {text[-500:]}")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith(
        ("usage:", " ", "example:", "\t")) and "Warning" not in ln]
    if code != 0 and len(lines) != 1 and not (code == 1 and not lines):
        raise FuzzViolation("cli", f"{argv}: exit {code} with {len(lines)} error lines: "
                            f"{listed(lines, 3, sep=' | ')}")
    return "ok" if code == 0 else "reported"


def cli_corpus(folder: str | os.PathLike[str], reader: ReaderCorpus | None = None
               ) -> dict[str, str]:
    """Inputs for the CLI cases: a real simulated log, damaged and foreign copies, a
    folder, an empty file, text, a PNG, a missing path."""
    from adfusion.app.replay import simulate
    from adfusion.sensors.scenarios import oedipus

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sim = folder / "sim.mcap"
    if not sim.exists():
        simulate(oedipus(duration_s=1.0, render=False, seed=3), sim)
    data = sim.read_bytes()
    out = {"sim": str(sim), "folder": str(folder / "dir"), "missing": str(folder / "no.mcap"),
           "empty": str(folder / "empty.mcap"), "text": str(folder / "notes.txt")}
    (folder / "dir").mkdir(exist_ok=True)
    (folder / "empty.mcap").write_bytes(b"")
    (folder / "notes.txt").write_text("not a log\n")
    r = random.Random(11)
    for k in range(4):
        bad = bytearray(data)
        for _ in range(3):
            i = r.randrange(len(bad))
            bad[i] ^= 0xFF
        path = folder / f"flipped{k}.mcap"
        path.write_bytes(bytes(bad))
        out[f"flipped{k}"] = str(path)
    cut = folder / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    out["cut"] = str(cut)
    if reader is not None:
        out["reader-intact"] = str(reader.path)
    import cv2

    png = folder / "frame.png"
    cv2.imwrite(str(png), np.zeros((48, 64), np.uint8))
    out["png"] = str(png)
    cfg = folder / "config.json"
    cfg.write_text('{"q_body_cam": [1, 0, 0, 0]}')
    out["config"] = str(cfg)
    return out


# --------------------------------------------------------------------------- the long run
def run(minutes: float, seed: int = 1, folder: str | os.PathLike[str] | None = None,
        cli_share: float = 0.1) -> dict[str, Any]:
    """Cases from every family, round robin, for ``minutes``; counts of outcomes and of
    violations (the first few kept with their case)."""
    import tempfile
    import time

    work = Path(folder or tempfile.mkdtemp(prefix="adfusion-fuzz-"))
    work.mkdir(parents=True, exist_ok=True)
    (work / "out").mkdir(exist_ok=True)
    from adfusion.app import fuzz_streams

    reader_corpus = {c: ReaderCorpus(work, compression=c) for c in ("zstd", "none")}
    streams = fuzz_streams.StreamCorpus(work / "streams")
    bank = SolverBank()
    corpus = cli_corpus(work / "cli", reader_corpus["zstd"])
    r = random.Random(seed)
    counts: dict[str, dict[str, int]] = {}
    violations: list[str] = []
    deadline = time.monotonic() + 60.0 * minutes
    t0 = time.monotonic()
    k = 0
    while time.monotonic() < deadline:
        k += 1
        family = ("reader", "solver", "sources", "cli", "streams", "writers")[k % 6]
        if family == "cli" and r.random() > cli_share * 6:
            family = "reader"
        try:
            if family == "reader":
                rc = reader_corpus[r.choice(["zstd", "none"])]
                kind = r.choice(["flip", "zero", "truncate", "cutout", "flip"])
                if r.random() < 0.5:
                    s, e, _ = r.choice(rc.chunks)  # inside one chunk
                    off = r.randrange(s, e)
                    length = r.randint(1, max(1, e - off))
                else:
                    off = r.randrange(len(rc.data))
                    length = r.randint(1, 64)
                outcome = check_reader(rc, kind, off, length)
            elif family == "solver":
                outcome = check_solver(
                    bank, r.randrange(2**32), r.choice(bank.fovs_deg), r.randint(0, 12),
                    r.choice([0.0, 0.0, 0.3, 0.7]), r.choice([0.1, 0.5, 1.5]),
                    r.choice(["none", "none", "prior"]), r.choice([0.0, 0.05, 1.0, 10.0]),
                    r.choice([0.05, 0.5, 3.0]))
            elif family == "sources":
                outcome = check_sources(work, r.randrange(2**32))
            elif family == "streams":
                outcome = fuzz_streams.check_streams(
                    streams, *fuzz_streams.random_case(r, streams.duration_s))
            elif family == "writers":
                outcome = fuzz_streams.check_writers(work / "out", r.randrange(2**32))
            else:
                outcome = check_cli(cli_argv(r, corpus, str(work / "out")))
        except FuzzViolation as v:
            outcome = f"violation:{v.kind}"
            if len(violations) < 20:
                violations.append(str(v))
        c = counts.setdefault(family, {})
        c[outcome] = c.get(outcome, 0) + 1
    totals = {"cases": sum(sum(c.values()) for c in counts.values()),
              "tracebacks": _count(counts, "violation:traceback"),
              "silent_losses": _count(counts, "violation:silent-loss"),
              "wrong_attitudes": _count(counts, "violation:wrong-attitude"),
              "cli_violations": _count(counts, "violation:cli")}
    return {"minutes": minutes, "seed": seed, "wall_s": round(time.monotonic() - t0, 1),
            **totals, "by_family": counts, "violations": violations}


def _count(counts: dict[str, dict[str, int]], key: str) -> int:
    return sum(c.get(key, 0) for c in counts.values())
