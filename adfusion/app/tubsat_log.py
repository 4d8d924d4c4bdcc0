"""``adfusion simulate tubsat``: Bleif's night pass (:mod:`adfusion.pointing.night_pass`)
replayed into an MCAP log.

Topics (JSON; times are seconds from the pass start, its UTC in the ``config`` metadata):
``/tubsat/plan`` (best time, maximum elevation), ``/tubsat/blocks`` (the reduced star
image), ``/tubsat/marked``, ``/tubsat/candidate`` (each candidate shown, with the
operator's decision), ``/tubsat/lock``, ``/tubsat/command`` (send / re-send / query),
``/imu/gyro``, ``/truth/state`` and ``/truth/pose``, ``/tubsat/pointing`` (the boresight
error at the target and the predicted budget).

Example:
    >>> import tempfile, pathlib
    >>> from adfusion.logs import McapLogReader
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "pass.mcap"
    >>> res = simulate_tubsat(path)
    >>> topics = {c.topic for c in McapLogReader(path).channels.values()}
    >>> res.ok, {"/tubsat/pointing", "/tubsat/candidate", "/truth/pose"} <= topics
    (True, True)
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from adfusion.logs import LogWriter, topics
from adfusion.pointing.night_pass import NightPassConfig, NightPassResult, run_night_pass
from adfusion.starid.bleif.matcher import tubsat_camera

__all__ = ["simulate_tubsat"]


def simulate_tubsat(path: str | Path, seed: int = 0, n_marked: int = 4) -> NightPassResult:
    """Run one night pass and write its events to ``path``; returns the pass result."""
    config = NightPassConfig(seed=seed, n_marked=n_marked)
    res = run_night_pass(config)
    meta = {k: v for k, v in asdict(config).items() if k not in ("orbit",)}
    meta["t0"] = config.t0.isoformat()
    meta.update(ok=res.ok, reason=res.reason,
                ref_time=res.ref_time.isoformat() if res.ref_time else None)
    with LogWriter(path) as log:
        log.add_metadata("config", meta)
        log.add_camera_model(tubsat_camera().to_dict())
        for t, topic, payload in sorted(res.events, key=lambda e: e[0]):
            log.write_json(topic, t, payload)
            if topic == topics.TRUTH_STATE:
                log.write_attitude(topics.TRUTH_POSE, t, payload["q_body_icrs"])
    return res
