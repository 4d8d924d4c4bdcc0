"""Flight-dynamics products of a replayed log: a CCSDS Attitude Ephemeris Message and a CSV.

* :func:`write_aem` — CCSDS AEM 1.0 (CCSDS 504.0-B-1) in KVN: ``REF_FRAME_A = ICRF``,
  ``REF_FRAME_B = SC_BODY_1``, ``ATTITUDE_DIR = A2B``, ``ATTITUDE_TYPE = QUATERNION``,
  ``QUATERNION_TYPE = LAST``, ``TIME_SYSTEM = UTC``; each data line is a UTC epoch and the
  quaternion ``Q1 Q2 Q3 QC`` (scalar last, as the header says) of the log's ``q_body_icrs``
  — the rotation taking ICRF vector coordinates into body coordinates (A → B), Hamilton
  convention, written with ``repr`` (17 significant digits) so that a reader gets the log's
  numbers back exactly. Version 1.0 because it names the direction and the scalar's place
  explicitly (and the independent reader ``ccsds-ndm`` reads it).
* :func:`write_csv` — one row per estimate: UTC, run seconds, the quaternion (scalar first),
  RA/Dec/roll of body +z (deg), 1σ about body x, y, z (deg), star-ID mode, stars matched.

Epochs are UTC when the log knows its start time (``clock`` metadata, or the ``config``'s
``start_utc``); otherwise :func:`read_attitude_history` raises, naming ``--start-utc``.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import replay, simulate
    >>> from adfusion.app.export import read_attitude_history, write_aem
    >>> d = tempfile.mkdtemp()
    >>> _ = simulate(oedipus(duration_s=0.3, render=False), os.path.join(d, "s.mcap"))
    >>> _ = replay(os.path.join(d, "s.mcap"), os.path.join(d, "o.mcap"), progress=False)
    >>> h = read_attitude_history(os.path.join(d, "o.mcap"))
    >>> write_aem(h, os.path.join(d, "o.aem"))
    >>> open(os.path.join(d, "o.aem")).readline().strip()
    'CCSDS_AEM_VERS = 1.0'
"""

from __future__ import annotations

import csv
import datetime as dt
import os
from dataclasses import dataclass, field

import numpy as np

from adfusion.app.errors import UsageError
from adfusion.logs import McapLogReader, topics
from adfusion.logs.writer import utc_ns
from adfusion.maths import rotations as rot

__all__ = ["AttitudeHistory", "read_attitude_history", "write_aem", "write_csv"]


@dataclass
class AttitudeHistory:
    """The estimates of a log: run times ``t`` (s), ``q_body_icrs`` (N, 4), 1σ ``sigma_rad``
    (N, 3) about body x, y, z, star-ID ``mode`` and stars matched per estimate, and the UTC
    of run time 0 (``start_utc_ns``, nanoseconds since 1970); ``problems``: what the log
    says went wrong (:func:`adfusion.app.report.log_problems`: damage, an incomplete run,
    input problems)."""

    t: np.ndarray
    q_body_icrs: np.ndarray
    sigma_rad: np.ndarray
    mode: list[str]
    n_stars: list[int]
    start_utc_ns: int
    object_name: str = "UNKNOWN"
    problems: list[str] = field(default_factory=list)

    def utc(self, k: int) -> str:
        """ISO 8601 UTC epoch of estimate ``k`` (microseconds)."""
        ns = self.start_utc_ns + round(float(self.t[k]) * 1e9)
        t = dt.datetime(1970, 1, 1) + dt.timedelta(microseconds=ns // 1000)
        return t.strftime("%Y-%m-%dT%H:%M:%S.%f")


def read_attitude_history(path: str | os.PathLike[str], *, smoothed: bool = False,
                          start_utc: str | None = None) -> AttitudeHistory:
    """The filter's (or with ``smoothed=True`` the smoother's) attitude history of a log.
    ``start_utc`` (ISO 8601 UTC) is the UTC of the log's t = 0, for a log that does not
    know it (an ``adfusion acs`` run, a replay without ``--start-utc``); a log that does
    keeps its own, and a different one is an error."""
    from adfusion.app.report import log_problems

    reader = McapLogReader(path)
    state = topics.SMOOTHED_STATE if smoothed else topics.ESTIMATE_STATE
    start = reader.start_utc or reader.metadata.get("config", {}).get("start_utc")
    if start_utc is not None:
        try:
            given = utc_ns(start_utc)
        except (TypeError, ValueError) as exc:
            raise UsageError(f"--start-utc {start_utc!r}: {exc}") from None
        if start is not None and utc_ns(start) != given:
            raise UsageError(f"{path}: the log starts at {start} UTC; --start-utc "
                             f"{start_utc} is only for a log that does not know its start")
        start = start_utc
    if start is None:
        raise ValueError(f"{path}: the log does not know its UTC start time: give it with "
                         "--start-utc TIME (the UTC of the log's t = 0)")
    t, q, var, modes, stars = [], [], [], {}, {}
    for m in reader:
        if m.topic == state:
            t.append(m.payload["t"])
            q.append(m.payload["q_body_icrs"])
            var.append(m.payload["cov_diag"][:3])
        elif m.topic == topics.ESTIMATE_ATTITUDE:
            modes[m.payload["t"]] = m.payload.get("mode") or ""
            stars[m.payload["t"]] = int(m.payload.get("n_stars", 0))
    if not t:
        raise UsageError(f"{path}: no {state} messages: is it a replayed log? (adfusion "
                         "replay INPUT -o OUT.mcap)")
    order = np.argsort(t, kind="stable")
    t_a = np.asarray(t, dtype=float)[order]
    name = str(reader.metadata.get("config", {}).get("scenario", "UNKNOWN")).upper()
    return AttitudeHistory(
        t_a, np.asarray(q, dtype=float)[order],
        np.sqrt(np.asarray(var, dtype=float)[order]),
        [modes.get(x, "") for x in t_a.tolist()], [stars.get(x, 0) for x in t_a.tolist()],
        utc_ns(start), name, log_problems(reader))


def write_aem(h: AttitudeHistory, path: str | os.PathLike[str]) -> None:
    """The history as a CCSDS AEM 2.0 KVN file (see the module docstring)."""
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%S")
    lines = ["CCSDS_AEM_VERS = 1.0", f"CREATION_DATE = {now}", "ORIGINATOR = ADFUSION", "",
             "META_START", f"OBJECT_NAME = {h.object_name}", "OBJECT_ID = UNKNOWN",
             "REF_FRAME_A = ICRF", "REF_FRAME_B = SC_BODY_1", "ATTITUDE_DIR = A2B",
             "TIME_SYSTEM = UTC", f"START_TIME = {h.utc(0)}",
             f"STOP_TIME = {h.utc(len(h.t) - 1)}", "ATTITUDE_TYPE = QUATERNION",
             "QUATERNION_TYPE = LAST", "META_STOP", "", "DATA_START"]
    for k in range(len(h.t)):
        w, x, y, z = (repr(float(v)) for v in h.q_body_icrs[k])
        lines.append(f"{h.utc(k)} {x} {y} {z} {w}")
    lines += ["DATA_STOP", ""]
    with open(path, "w", encoding="ascii") as f:
        f.write("\n".join(lines))


def write_csv(h: AttitudeHistory, path: str | os.PathLike[str]) -> None:
    """The history as CSV (see the module docstring)."""
    ra, dec, roll = rot.radec_roll_from_q_cam_icrs(h.q_body_icrs)
    sig = np.degrees(h.sigma_rad)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["utc", "t_s", "qw", "qx", "qy", "qz", "ra_deg", "dec_deg", "roll_deg",
                    "sigma_x_deg", "sigma_y_deg", "sigma_roll_deg", "mode", "n_stars"])
        for k in range(len(h.t)):
            w.writerow([h.utc(k) + "Z", repr(float(h.t[k])),
                        *(repr(float(v)) for v in h.q_body_icrs[k]),
                        *(f"{float(np.degrees(a[k])):.9f}" for a in (ra, dec, roll)),
                        *(f"{v:.3e}" for v in sig[k]), h.mode[k], h.n_stars[k]])
