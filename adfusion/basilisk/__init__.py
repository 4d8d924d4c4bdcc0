"""adfusion inside Basilisk: the estimator as a flight-software module, a rendered star camera
as a sensor, closed-loop attitude-control scenarios (optional extra ``bsk``).

* :class:`AdfusionNav` (:mod:`.nav`) — a Basilisk ``SysModel``: ``IMUSensorMsg`` +
  ``TAMSensorMsg``/``MagneticFieldMsg`` + camera frames or ``STSensorMsg`` →
  :class:`adfusion.Estimator` → ``NavAttMsg`` and ``InertialFilterMsg``.
* :class:`StarCameraModule` (:mod:`.camera`) — frames rendered by
  :func:`adfusion.sensors.render.render_frame` from ``SCStatesMsg``.
* :func:`run_loop` / :func:`scenario` (:mod:`.scenarios`) — the loop on Basilisk's truth,
  its ``inertialUKF`` or adfusion; :func:`run_acs` (:mod:`.acs`) — all three, the report and
  the MCAP log (``adfusion acs SCENARIO -o run.mcap``).

Nothing else in adfusion imports this package; it needs ``pip install adfusion[bsk]``.

Example:
    >>> from adfusion.basilisk import SCENARIOS
    >>> sorted(SCENARIOS)
    ['leo', 'misaligned', 'outage', 'slew']
"""

from adfusion.basilisk.camera import CameraFrame, StarCameraModule
from adfusion.basilisk.frames import q_body_icrs_from_sigma_bn, sigma_bn_from_q_body_icrs
from adfusion.basilisk.nav import AdfusionNav
from adfusion.basilisk.scenarios import LOOPS, SCENARIOS, AcsConfig, LoopRun, run_loop, scenario

__all__ = [
    "LOOPS",
    "SCENARIOS",
    "AcsConfig",
    "AdfusionNav",
    "CameraFrame",
    "LoopRun",
    "StarCameraModule",
    "q_body_icrs_from_sigma_bn",
    "run_loop",
    "scenario",
    "sigma_bn_from_q_body_icrs",
]
