"""Fuzzing the sensor streams of a replay (issue 33): gyros that stop, pause, repeat, jump
or run on another clock, and two writers of one output.

:func:`check_streams` replays one flight of :class:`StreamCorpus` with a random fault in
its gyro stream and holds the replay to the promises of ``adfusion.app.fuzz``: no
traceback; no estimate the truth contradicts beyond max(10σ, 0.2°) (``wrong-attitude``);
a gyro silent longer than its age limit said so in the run's problems (``silent-loss``).
:func:`check_writers` starts two writers of one output and holds them to one winner, a
one-line refusal for the other, and a whole log.

Example:
    >>> import tempfile
    >>> corpus = StreamCorpus(tempfile.mkdtemp(), duration_s=2.0)
    >>> check_streams(corpus, "stop", 1.0, 0.0)
    'reported'
"""

from __future__ import annotations

import math
import os
import random
import warnings
from pathlib import Path

import numpy as np

from adfusion.app.fuzz_violation import FuzzViolation

__all__ = ["FAULTS", "StreamCorpus", "check_streams", "check_writers", "random_case"]

#: the gyro faults: stop at ``a``; pause from ``a`` for ``b`` s; times × 1000 (ms) from
#: ``a`` on; every time shifted by ``b`` s; samples repeated (same time twice); NaN samples
#: for ``b`` s from ``a``; a jump forward of the gyro clock by ``b`` s at ``a``
FAULTS = ("stop", "pause", "ms", "offset", "repeat", "nan", "jump")


class StreamCorpus:
    """One simulated flight (star centroids, 200 Hz gyro, magnetometer, truth) to damage."""

    def __init__(self, folder: str | os.PathLike[str], duration_s: float = 4.0,
                 seed: int = 3) -> None:
        from adfusion.app.replay import simulate
        from adfusion.sensors.scenarios import oedipus

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.path = self.folder / "flight.mcap"
        self.duration_s = float(duration_s)
        if not self.path.exists():
            simulate(oedipus(duration_s=duration_s, render=False, seed=seed), self.path)
        from adfusion.logs import McapLogReader

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = McapLogReader(self.path)
            self.config = reader.metadata["config"]
            self.camera = reader.camera_model()
            self.messages = [m for m in reader if m.topic in (
                "/imu/gyro", "/mag", "/camera/centroids", "/truth/state")]


def _damaged(corpus: StreamCorpus, fault: str, a: float, b: float) -> tuple[list, float]:
    """The messages with ``fault`` in the gyro, and the longest time (s) the frames met
    without a gyro sample — what the run must report when past the age limit."""
    out = []
    for m in corpus.messages:
        t, payload = m.t_s, m.payload
        if m.topic == "/imu/gyro":
            if (fault == "stop" and t > a) or (fault == "pause" and a < t < a + b):
                continue
            if fault == "ms" and t > a:
                t = a + (t - a) * 1000.0
            elif fault == "offset":
                t = max(t + b, 0.0)
            elif fault == "jump" and t > a:
                t = t + b
            elif fault == "nan" and a < t < a + b:
                payload = {"omega": [float("nan")] * 3}
            elif fault == "repeat" and int(t * 200) % 7 == 0:
                out.append((m.topic, t, payload))
        out.append((m.topic, t, payload))
    out.sort(key=lambda x: x[1])
    frames = [t for topic, t, _ in out if topic == "/camera/centroids"]
    gyro = sorted(t for topic, t, p in out if topic == "/imu/gyro"
                  and all(math.isfinite(v) for v in p["omega"]))
    silent = 0.0
    for t in frames:  # the frames' longest wait since the last good sample
        k = np.searchsorted(gyro, t, side="right")
        silent = max(silent, t - gyro[k - 1] if k else 0.0)
    return out, silent


def check_streams(corpus: StreamCorpus, fault: str, a: float, b: float) -> str:
    """Replay the corpus's flight with ``fault`` (:data:`FAULTS`) at ``a`` s (size ``b``):
    "ok", "reported", or a :class:`FuzzViolation`."""
    from adfusion.app.replay import replay
    from adfusion.logs import LogWriter, McapLogReader, topics

    case = f"{fault} a={a:.3f} b={b:.3f}"
    msgs, silent = _damaged(corpus, fault, a, b)
    src = corpus.folder / "damaged.mcap"
    out = corpus.folder / "replayed.mcap"
    for p in (src, out):
        p.unlink(missing_ok=True)
    with LogWriter(src, compression="none") as log:
        log.add_metadata("config", corpus.config)
        log.add_camera_model(corpus.camera)
        for topic, t, payload in msgs:
            log.write_json(topic, t, payload)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = replay(src, out, progress=False)
            errors = [m.payload for m in McapLogReader(out) if m.topic == topics.ESTIMATE_ERROR]
    except ValueError:
        return "reported"
    except Exception as exc:
        raise FuzzViolation("traceback", f"streams {case}: {type(exc).__name__}: "
                            f"{exc}") from exc
    for p in errors:  # /estimate/error: the angle off the truth and its 3σ per axis
        sigma_deg = float(np.linalg.norm(p["sigma3_deg"])) / 3.0
        if p["angle_deg"] > max(10.0 * sigma_deg, 0.2):
            raise FuzzViolation("wrong-attitude", f"streams {case}: t = {p['t']:.3f} s "
                                f"{p['angle_deg']:.3g}° off, σ {sigma_deg:.3g}°")
    told = any("gyro silent" in p or ("gyro" in p and "dropped" in p) for p in s.problems)
    if silent > 1.0 and not told:  # 1 s: the age limit's cap, whatever the gyro's rate
        raise FuzzViolation("silent-loss", f"streams {case}: the frames went {silent:.3g} s "
                            "without a gyro sample and the run did not say so")
    return "reported" if s.problems else "ok"


def check_writers(folder: str | os.PathLike[str], seed: int) -> str:
    """Two writers of one output, the second started while the first writes: exactly one
    log, the first's, whole; the second refused at once."""
    from adfusion.logs import LogWriter, McapLogReader
    from adfusion.outfiles import OutputBusy

    out = Path(folder) / f"race-{seed % 4}.mcap"
    out.unlink(missing_ok=True)
    try:
        with LogWriter(out, atomic=True) as first:
            first.add_metadata("run", {"who": "first", "seed": seed})
            try:
                LogWriter(out, atomic=True)
            except OutputBusy:
                pass
            else:
                raise FuzzViolation("silent-loss", f"writers seed {seed}: a second writer "
                                    "of one output was accepted")
        got = McapLogReader(out).metadata.get("run")
    except FuzzViolation:
        raise
    except Exception as exc:
        raise FuzzViolation("traceback", f"writers seed {seed}: {type(exc).__name__}: "
                            f"{exc}") from exc
    if got != {"who": "first", "seed": seed}:
        raise FuzzViolation("silent-loss", f"writers seed {seed}: the output holds {got}")
    if any(p.name.startswith(".adf-") for p in Path(folder).iterdir()):
        raise FuzzViolation("silent-loss", f"writers seed {seed}: a temporary file was left")
    return "ok"


def random_case(r: random.Random, duration_s: float,
                fault: str | None = None) -> tuple[str, float, float]:
    """A fault of :data:`FAULTS` (or ``fault``) with its time ``a`` and size ``b``."""
    fault = fault or r.choice(FAULTS)
    a = r.uniform(0.2, duration_s - 0.2)
    # offsets within a logger's timestamp jitter (2 ms); a jump forward of 0.5 s is a gap
    # after which the gyro runs 0.5 s late (the replay reports it, and the fixes the filter
    # finds surprising widen its σ; docs/reliability.md); a backward jump merged into a
    # time-ordered log is a denser gyro, not a fault the log shows
    b = {"offset": r.uniform(-0.002, 0.002), "jump": r.choice([0.5, 5.0, 1000.0])}.get(
        fault, r.uniform(0.01, 2.0))
    return fault, a, b
