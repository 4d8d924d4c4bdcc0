"""Flight-dynamics products of a replayed log: a CCSDS Attitude Ephemeris Message and a CSV.

* :func:`write_aem` — CCSDS AEM 1.0 (CCSDS 504.0-B-1) in KVN: ``REF_FRAME_A = ICRF``,
  ``REF_FRAME_B = SC_BODY_1``, ``ATTITUDE_DIR = A2B``, ``ATTITUDE_TYPE = QUATERNION``,
  ``QUATERNION_TYPE = LAST``, ``TIME_SYSTEM = UTC``; each data line is a UTC epoch and the
  quaternion ``Q1 Q2 Q3 QC`` (scalar last, as the header says) of the log's ``q_body_icrs``
  — the rotation taking ICRF vector coordinates into body coordinates (A → B), Hamilton
  convention, written with ``repr`` (17 significant digits) so that a reader gets the log's
  numbers back exactly. Version 1.0 because it names the direction and the scalar's place
  explicitly (and the independent reader ``ccsds-ndm`` reads it).
* :func:`write_acm` — CCSDS ACM 2.0 (CCSDS 504.0-B-2), an Attitude Comprehensive Message, in
  XML, written with the ``ccsds-ndm`` package (its ACM KVN writer and reader do not work in
  3.1: no block delimiters); see :func:`write_acm` for the content.
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
import math
import os
from dataclasses import dataclass, field

import numpy as np

from adfusion.app.errors import UsageError
from adfusion.logs import McapLogReader, topics
from adfusion.logs.writer import utc_ns
from adfusion.maths import rotations as rot

ACM_MISSING = "--acm needs the ccsds-ndm package: pip install ccsds-ndm"

__all__ = ["AttitudeHistory", "read_attitude_history", "write_acm", "write_aem", "write_csv"]


@dataclass
class AttitudeHistory:
    """The estimates of a log: run times ``t`` (s), ``q_body_icrs`` (N, 4), 1σ ``sigma_rad``
    (N, 3) about body x, y, z, star-ID ``mode`` and stars matched per estimate, and the UTC
    of run time 0 (``start_utc_ns``, nanoseconds since 1970); ``problems``: what the log
    says went wrong (:func:`adfusion.app.report.log_problems`: damage, an incomplete run,
    input problems). ``var`` (N, 6): the log's ``cov_diag``; ``cov`` (N, 6, 6): its full
    ``cov`` (NaN where the log has none: the smoother, an older log); ``bias`` and ``omega``
    (N, 3, rad/s, NaN where the log has none); ``smoothed``: the smoother's history. Left
    out, ``var`` is ``sigma_rad²`` then NaN, the others NaN: every writer reads them alike."""

    t: np.ndarray
    q_body_icrs: np.ndarray
    sigma_rad: np.ndarray
    mode: list[str]
    n_stars: list[int]
    start_utc_ns: int
    object_name: str = "UNKNOWN"
    problems: list[str] = field(default_factory=list)
    var: np.ndarray | None = None
    cov: np.ndarray | None = None
    bias: np.ndarray | None = None
    omega: np.ndarray | None = None
    smoothed: bool = False

    def __post_init__(self) -> None:
        n = len(self.t)
        if self.var is None:
            self.var = np.concatenate([self.sigma_rad**2, np.full((n, 3), np.nan)], axis=1)
        if self.cov is None:
            self.cov = np.full((n, 6, 6), np.nan)
        if self.bias is None:
            self.bias = np.full((n, 3), np.nan)
        if self.omega is None:
            self.omega = np.full((n, 3), np.nan)

    @property
    def full_cov(self) -> np.ndarray:
        """(N,) bool: the estimates whose full covariance (``cov``) the log holds."""
        return np.all(np.isfinite(self.cov.reshape(len(self.t), -1)), axis=1)

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
    cov, bias, omega = [], [], []
    nan3, nan36 = [math.nan] * 3, [math.nan] * 36
    for m in reader:
        if m.topic == state:
            t.append(m.payload["t"])
            q.append(m.payload["q_body_icrs"])
            d = list(m.payload["cov_diag"])
            var.append((d + [math.nan] * 6)[:6])
            c = m.payload.get("cov")
            cov.append(c if isinstance(c, list) and len(c) == 36 else nan36)
            bias.append(m.payload.get("bias") or nan3)
            omega.append(m.payload.get("omega") or nan3)
        elif m.topic == topics.ESTIMATE_ATTITUDE:
            modes[m.payload["t"]] = m.payload.get("mode") or ""
            stars[m.payload["t"]] = int(m.payload.get("n_stars", 0))
    if not t:
        raise UsageError(f"{path}: no {state} messages: is it a replayed log? (adfusion "
                         "replay INPUT -o OUT.mcap)")
    order = np.argsort(t, kind="stable")
    t_a = np.asarray(t, dtype=float)[order]
    name = str(reader.metadata.get("config", {}).get("scenario", "UNKNOWN")).upper()
    var_a = np.asarray(var, dtype=float)[order]
    return AttitudeHistory(
        t_a, np.asarray(q, dtype=float)[order], np.sqrt(var_a[:, :3]),
        [modes.get(x, "") for x in t_a.tolist()], [stars.get(x, 0) for x in t_a.tolist()],
        utc_ns(start), name, log_problems(reader), var=var_a,
        cov=np.asarray(cov, dtype=float)[order].reshape(-1, 6, 6),
        bias=np.asarray(bias, dtype=float)[order], omega=np.asarray(omega, dtype=float)[order],
        smoothed=smoothed)


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


def _utc_ns_iso(ns: int) -> str:
    """ISO 8601 UTC of ``ns`` nanoseconds since 1970, to the nanosecond."""
    t = dt.datetime(1970, 1, 1) + dt.timedelta(seconds=ns // 1_000_000_000)
    return t.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns % 1_000_000_000:09d}"


def _num(v: float) -> str:
    return repr(float(v))


def write_acm(h: AttitudeHistory, path: str | os.PathLike[str]) -> None:
    """The history as a CCSDS ACM 2.0 (XML), written with ``ccsds-ndm``.

    * ``EPOCH_TZERO`` is the UTC of the log's t = 0; every data line's time tag is the
      estimate's run time ``t`` (s) relative to it (the ACM's convention), so a line's UTC is
      ``EPOCH_TZERO + t`` — the epoch the AEM export writes, to the nanosecond.
    * ``ATT_1``: every estimate, ``REF_FRAME_A = ICRF``, ``REF_FRAME_B = SC_BODY_1``,
      ``ATT_TYPE = QUATERNION``. The ACM's quaternion is the coordinate transformation from
      frame A to frame B, written ``Q1 Q2 Q3 QC`` (scalar last): that is the log's
      ``q_body_icrs = [w, x, y, z]`` (Hamilton, rotates ICRS vector coordinates into the
      body frame) written ``x y z w``. ``RATE_TYPE = GYRO_BIAS`` (the filter's gyro bias)
      when every estimate has one; ``ANGVEL`` (the estimated body rate ``omega``, of the body
      relative to ICRF in body axes) when none has a bias but every one a rate (no gyro).
      Rates are deg/s, as the ACM wants.
    * ``ATT_2`` (when ``ATT_1`` carries the bias and some estimates have a rate: a gyro
      outage, a smoother with rates): ``QUATERNION`` + ``ANGVEL`` for those estimates.
    * ``COV_1`` (``COV_2`` when the last three states change between bias and rate): the
      covariance diagonal, ``COV_TYPE = ANGLE_GYROBIAS`` (or ``ANGLE_ANGVEL``),
      ``COV_REF_FRAME = SC_BODY_1`` (attitude error δθ in the body frame), deg² and
      (deg/s)². The ACM's covariance lines hold the diagonal only.
    * ``USER``: the full 6×6 covariance (the log's ``cov``) of every estimate that has one,
      ``USER_DEFINED`` parameter ``COV_k`` (k: the estimate's index), value: the time tag and
      the 21 elements of the lower triangle row by row, deg², deg²/s, (deg/s)². A log without
      ``cov`` (older, or the smoother's) gets the diagonal alone, and a ``COMMENT`` says so.
    * ``AD``: the method (``EKF``, or ``FILTER_SMOOTHER`` for ``--smoothed``).

    Numbers are ``repr`` (17 significant digits). Non-finite values are left out with their
    line. ``ccsds-ndm`` is needed (``pip install ccsds-ndm``: a ``test`` extra)."""
    try:
        from ccsds_ndm.mapping import NDMFileFormats
        from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_acm_2_0 as am
        from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as cm
        from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Acm
        from ccsds_ndm.ndm_io import NdmIo
    except ImportError:
        raise UsageError(ACM_MISSING) from None
    n = len(h.t)
    bias, omega, var, cov = h.bias, h.omega, h.var, h.cov
    has_bias = np.all(np.isfinite(bias), axis=1)
    has_omega = np.all(np.isfinite(omega), axis=1)
    deg = math.degrees(1.0)
    basis = cm.AttBasisType.DETERMINED_GND
    frames = {"ref_frame_a": "ICRF", "ref_frame_b": "SC_BODY_1"}

    def quat(k: int) -> str:
        w, x, y, z = h.q_body_icrs[k]
        return " ".join(_num(v) for v in (h.t[k], x, y, z, w))

    def rates(v: np.ndarray, k: int) -> str:
        return " ".join(_num(deg * float(x)) for x in v[k])

    att = []
    if has_bias.all():
        rate, lines = cm.AttRateType.GYRO_BIAS, [f"{quat(k)} {rates(bias, k)}" for k in range(n)]
    elif has_omega.all():
        rate, lines = cm.AttRateType.ANGVEL, [f"{quat(k)} {rates(omega, k)}" for k in range(n)]
    else:
        rate, lines = None, [quat(k) for k in range(n)]
    att.append(am.AcmAttitudeStateType(
        comment=["every estimate; quaternion ICRF -> SC_BODY_1 (A to B), Q1 Q2 Q3 QC"
                 + ("; gyro bias, deg/s, body axes" if rate is cm.AttRateType.GYRO_BIAS else
                    "; body rate relative to ICRF, deg/s, body axes" if rate else "")],
        att_id="ATT_1", att_basis=basis, **frames, number_states=4 if rate is None else 7,
        att_type=cm.AcmAttitudeType.QUATERNION, rate_type=rate, att_line=lines))
    if rate is not cm.AttRateType.ANGVEL and has_omega.any():
        att.append(am.AcmAttitudeStateType(
            comment=["the estimates with a body rate (no gyro): relative to ICRF, deg/s, "
                     "body axes"], att_id="ATT_2", att_prev_id="ATT_1", att_basis=basis,
            **frames, number_states=7, att_type=cm.AcmAttitudeType.QUATERNION,
            rate_type=cm.AttRateType.ANGVEL,
            att_line=[f"{quat(k)} {rates(omega, k)}" for k in np.flatnonzero(has_omega)]))

    full = h.full_cov
    scale = np.array([deg] * 6)
    covs: list[tuple[bool, list[str]]] = []  # (rate states, lines), in time order
    for k in range(n):
        v = var[k] if not full[k] else np.diag(cov[k])
        if not np.all(np.isfinite(v)):
            continue
        line = " ".join(_num(x) for x in (h.t[k], *(v * scale * scale)))
        if covs and covs[-1][0] == (not has_bias[k]):
            covs[-1][1].append(line)
        else:
            covs.append((not has_bias[k], [line]))
    note = [] if full.all() else [
        "diagonal only for the estimates without a full covariance in the log (the smoother, "
        "or a log older than /estimate/state cov): from cov_diag"]
    cov_blocks = [am.AcmCovarianceMatrixType(
        comment=["covariance diagonal: attitude error about body x, y, z (deg**2), then "
                 + ("body rate" if by_rate else "gyro bias") + " ((deg/s)**2)", *note],
        cov_id=f"COV_{i + 1}", cov_prev_id=f"COV_{i}" if i else None, cov_basis=basis,
        cov_ref_frame="SC_BODY_1",
        cov_type=(cm.AcmCovarianceLineType.ANGLE_ANGVEL if by_rate
                  else cm.AcmCovarianceLineType.ANGLE_GYROBIAS), cov_line=lines)
        for i, (by_rate, lines) in enumerate(covs)]
    user = None
    if full.any():
        low = np.tril_indices(6)
        user = cm.UserDefinedType(
            comment=["COV_k: the full 6x6 error covariance of estimate k (the ACM's COV lines "
                     "hold the diagonal only): time tag (s from EPOCH_TZERO), then the lower "
                     "triangle row by row (21 values): attitude error about body x, y, z "
                     "(deg**2), gyro bias or body rate ((deg/s)**2), cross terms (deg**2/s)"],
            user_defined=[cm.UserDefinedParameterType(
                parameter=f"COV_{k}", value=" ".join(_num(x) for x in (
                    h.t[k], *(cov[k] * np.outer(scale, scale))[low])))
                for k in np.flatnonzero(full)])
    rate_states = (cm.AttRateType.ANGVEL if covs and covs[0][0] else cm.AttRateType.GYRO_BIAS)
    ad = am.AcmAdParametersType(
        comment=["adfusion: star-camera fixes in a multiplicative EKF, with the gyro when "
                 "there is one" + ("; then smoothed (GTSAM)" if h.smoothed else "")],
        ad_method=cm.AdMethodType.FILTER_SMOOTHER if h.smoothed else cm.AdMethodType.EKF,
        attitude_source="star camera" + (", gyro" if has_bias.any() else ""), number_states=7,
        attitude_states=cm.AcmAttitudeType.QUATERNION,
        cov_type=(cm.AcmCovarianceLineType.ANGLE_ANGVEL if rate_states is cm.AttRateType.ANGVEL
                  else cm.AcmCovarianceLineType.ANGLE_GYROBIAS), **frames,
        rate_states=rate_states)
    elements = ["ATT"] * len(att) + ["COV"] * len(cov_blocks) + ["AD"] + (["USER"] if user
                                                                           else [])
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%S")
    msg = Acm(
        header=cm.AdmHeader(comment=[f"adfusion export of {h.object_name}"],
                            creation_date=now, originator="ADFUSION"),
        body=am.AcmBody(segment=am.AcmSegment(
            metadata=am.AcmMetadata(
                object_name=h.object_name, time_system="UTC",
                epoch_tzero=_utc_ns_iso(h.start_utc_ns), acm_data_elements=", ".join(elements),
                start_time=h.utc(0), stop_time=h.utc(n - 1)),
            data=am.AcmData(att=att, cov=cov_blocks, ad=ad, user=user))))
    text = NdmIo().to_string(msg, NDMFileFormats.XML)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


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
