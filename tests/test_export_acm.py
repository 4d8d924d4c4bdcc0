"""The filter's full covariance in /estimate/state (``cov``) and ``adfusion export --acm``:
a CCSDS ACM 2.0 read back with ``ccsds-ndm`` (and, for the attitude lines, the standard
library's XML parser) to the log's numbers."""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from adfusion.logs import McapLogReader, topics
from adfusion.sensors.scenarios import oedipus

from adfusion.app.cli import main
from adfusion.app.export import read_attitude_history, write_acm
from adfusion.app.replay import replay, simulate

DEG = math.degrees(1.0)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 2 s OEDIPUS flight (no rendering: star fixes from the catalogue), replayed."""
    d = tmp_path_factory.mktemp("acm")
    simulate(oedipus(duration_s=2.0, render=False, seed=1), d / "sim.mcap")
    replay(d / "sim.mcap", d / "out.mcap", progress=False)
    states = [m.payload for m in McapLogReader(d / "out.mcap")
              if m.topic == topics.ESTIMATE_STATE]
    assert len(states) > 10
    return d, states


def _acm(path):
    pytest.importorskip("ccsds_ndm")
    from ccsds_ndm.ndm_io import NdmIo

    return NdmIo().from_path(path)


def _rows(lines) -> np.ndarray:
    return np.array([[float(v) for v in line.split()] for line in lines])


def test_estimate_state_cov_is_the_full_symmetric_psd_covariance(flight):
    jsonschema = pytest.importorskip("jsonschema")
    from adfusion.logs.schemas import JSON_SCHEMAS

    _, states = flight
    schema = JSON_SCHEMAS[topics.ESTIMATE_STATE][1]
    for s in states:
        jsonschema.validate(s, schema)
        assert len(s["cov"]) == 36
        p = np.array(s["cov"], dtype=float).reshape(6, 6)
        assert np.all(np.isfinite(p))
        assert np.max(np.abs(p - p.T)) <= 1e-12 * np.max(np.abs(p))
        assert np.linalg.eigvalsh(0.5 * (p + p.T))[0] >= -1e-12 * np.max(np.abs(p))
        assert np.allclose(np.diag(p), s["cov_diag"], rtol=1e-14, atol=0.0)
    # the full matrix, not the diagonal again: attitude and bias correlate once fixes come in
    last = np.array(states[-1]["cov"]).reshape(6, 6)
    off = last - np.diag(np.diag(last))
    assert np.max(np.abs(off)) > 1e-3 * np.max(np.diag(last))


def test_acm_reads_back_to_the_logs_quaternions_bias_and_covariance(flight, tmp_path, capsys):
    d, states = flight
    acm = tmp_path / "out.acm"
    assert main(["export", str(d / "out.mcap"), "--acm", str(acm)]) == 0
    assert "ACM: " in capsys.readouterr().out
    msg = _acm(acm)
    meta, data = msg.body.segment.metadata, msg.body.segment.data
    assert (msg.id, msg.version) == ("CCSDS_ACM_VERS", "2.0")
    assert meta.time_system == "UTC"
    t0 = dt.datetime.fromisoformat(meta.epoch_tzero[:26])
    n = len(states)
    t = np.array([s["t"] for s in states])

    att = data.att[0]
    assert (att.ref_frame_a, att.ref_frame_b) == ("ICRF", "SC_BODY_1")
    assert att.att_type.value == "QUATERNION" and att.rate_type.value == "GYRO_BIAS"
    rows = _rows(att.att_line)
    assert rows.shape == (n, 8) and att.number_states == 7
    assert np.array_equal(rows[:, 0], t)  # time tags: run seconds from EPOCH_TZERO
    q = rows[:, [4, 1, 2, 3]]  # Q1 Q2 Q3 QC -> [w, x, y, z]
    want = np.array([s["q_body_icrs"] for s in states])
    err = np.minimum(np.abs(q - want).max(axis=1), np.abs(q + want).max(axis=1))
    assert err.max() <= 1e-9
    bias = np.array([s["bias"] for s in states])
    assert np.allclose(rows[:, 5:] / DEG, bias, rtol=1e-12, atol=1e-18)
    # the epoch of each line is the AEM export's
    h = read_attitude_history(d / "out.mcap")
    for k in (0, n // 2, n - 1):
        utc = t0 + dt.timedelta(seconds=float(rows[k, 0]))
        assert abs((utc - dt.datetime.fromisoformat(h.utc(k))).total_seconds()) < 2e-6

    # the standard library's reading of the same lines (not ccsds-ndm's)
    lines = [e.text for e in ET.parse(acm).getroot().iter("attLine")]
    assert len(lines) == n and np.array_equal(_rows(lines), rows)

    cov = np.array([s["cov"] for s in states], dtype=float).reshape(n, 6, 6)
    (block,) = data.cov
    assert block.cov_type.value == "ANGLE_GYROBIAS" and block.cov_ref_frame == "SC_BODY_1"
    diag = _rows(block.cov_line)
    assert np.array_equal(diag[:, 0], t)
    assert np.allclose(diag[:, 1:] / DEG**2, np.diagonal(cov, axis1=1, axis2=2),
                       rtol=1e-12, atol=0.0)
    # the full matrix, in the user-defined block (the ACM's covariance lines are diagonal)
    full = {u.parameter: _rows([u.value])[0] for u in data.user.user_defined}
    assert len(full) == n
    low = np.tril_indices(6)
    for k in range(n):
        v = full[f"COV_{k}"]
        assert v[0] == t[k]
        m = np.zeros((6, 6))
        m[low] = v[1:]
        m = m + np.tril(m, -1).T
        scale = np.array([DEG] * 6)
        back = m / np.outer(scale, scale)
        assert np.allclose(back, cov[k], rtol=1e-12, atol=1e-12 * np.max(np.abs(cov[k])))
    assert data.ad.ad_method.value == "EKF"


def test_acm_of_a_log_without_cov_has_the_diagonal_and_says_so(flight, tmp_path):
    d, states = flight
    h = read_attitude_history(d / "out.mcap")
    h = dataclasses.replace(h, cov=None)  # a log written before /estimate/state had cov
    write_acm(h, tmp_path / "old.acm")
    data = _acm(tmp_path / "old.acm").body.segment.data
    assert data.user is None
    (block,) = data.cov
    assert any("diagonal only" in c for c in block.comment)
    diag = _rows(block.cov_line)[:, 1:] / DEG**2
    assert np.allclose(diag, [s["cov_diag"] for s in states], rtol=1e-12, atol=0.0)


def test_acm_onto_the_log_is_refused(flight, capsys):
    d, _ = flight
    log = d / "out.mcap"
    before = log.read_bytes()
    assert main(["export", str(log), "--acm", str(log)]) == 2
    assert "--acm" in capsys.readouterr().err
    assert log.read_bytes() == before


def test_acm_of_a_video_only_replay_carries_the_rate_and_its_covariance(flight, tmp_path,
                                                                         capsys):
    d, _ = flight
    out = tmp_path / "video.mcap"
    replay(d / "sim.mcap", out, progress=False, use_gyro=False)
    states = [m.payload for m in McapLogReader(out) if m.topic == topics.ESTIMATE_STATE]
    assert states and all(s["bias"] is None and len(s["omega"]) == 3 for s in states)
    assert main(["export", str(out), "--acm", str(tmp_path / "v.acm")]) == 0
    capsys.readouterr()
    data = _acm(tmp_path / "v.acm").body.segment.data
    (att,) = data.att
    assert att.rate_type.value == "ANGVEL"
    rows = _rows(att.att_line)
    omega = np.array([s["omega"] for s in states])
    assert np.allclose(rows[:, 5:] / DEG, omega, rtol=1e-12, atol=1e-18)
    (block,) = data.cov
    assert block.cov_type.value == "ANGLE_ANGVEL"
    cov = np.array([s["cov"] for s in states], dtype=float).reshape(-1, 6, 6)
    assert np.allclose(_rows(block.cov_line)[:, 1:] / DEG**2,
                       np.diagonal(cov, axis1=1, axis2=2), rtol=1e-12, atol=0.0)
