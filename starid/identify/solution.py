"""What the solver takes and gives: an attitude :class:`Prior` for tracking, verified
:class:`Candidate` matches and the frame's :class:`Solution`.

Example:
    >>> from adfusion.starid.identify.solution import Solution
    >>> Solution(False, "too few detections (2 < 3)").ok
    False
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import NDArray

from adfusion.maths import rotations as rot

__all__ = ["Candidate", "Prior", "Solution", "accepted_solution"]


def made(cls: type, values: dict):
    """An instance of the frozen dataclass ``cls`` whose fields are ``values`` (in a dict
    the instance keeps), its ``__init__`` skipped: the compiled lost-in-space path builds a
    :class:`Solution` per frame, and its ~18 ``object.__setattr__`` calls cost ~2 µs of a
    ~70 µs solve. A :class:`Solution`'s ``candidates`` may be given instead as
    ``_candidates_from`` (a function and its arguments), made when first read
    (:meth:`Solution.__getattr__`). Neither class checks its fields on creation;
    ``tests/test_frame_kernels.py`` holds the two ways equal.

    >>> c = made(Candidate, {"q_cam_icrs": None, "matches": [], "residuals_rad": None,
    ...                      "p_false": 0.5, "n_pattern": 3, "camera": None,
    ...                      "covariance": None, "_projector": None})
    >>> c == Candidate(None, [], None, 0.5, 3, None, None)
    True
    """
    obj = object.__new__(cls)
    object.__setattr__(obj, "__dict__", values)
    return obj


@dataclass(frozen=True)
class Prior:
    """An attitude prior for tracking: ``q_cam_icrs`` with a 1-σ uncertainty (deg).

    ``sigma_deg`` is the largest 1-σ attitude error about any axis (a filter's
    ``search_cone_deg(k=1)``). ``k`` sets the gate in σ. ``smear_cam_rad``, when known
    (a gyro's rate times the exposure), is the rotation vector (rad, camera axes) the
    camera turns through during the exposure: stars are then streaks, and a detection may
    be any piece of one, so tracking trusts it only across the streak
    (:func:`adfusion.maths.attitude.refine_streaked`) and its covariance says so.

    >>> p = Prior([1.0, 0.0, 0.0, 0.0], 0.05, smear_cam_rad=[0.0, 0.0, 0.01])
    >>> p.smear_cam_rad.tolist()
    [0.0, 0.0, 0.01]
    """

    q_cam_icrs: NDArray[np.float64]
    sigma_deg: float
    k: float = 3.0
    smear_cam_rad: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        q = np.asarray(self.q_cam_icrs, dtype=np.float64)
        if q.shape != (4,):
            raise ValueError("Prior.q_cam_icrs must be a quaternion [w,x,y,z]")
        try:
            q = rot.normalize(q)
        except ValueError:
            raise ValueError("Prior.q_cam_icrs must be a finite, non-zero quaternion "
                             "[w,x,y,z]") from None
        if not (math.isfinite(self.sigma_deg) and self.sigma_deg > 0):
            raise ValueError(f"Prior.sigma_deg must be positive, got {self.sigma_deg}")
        if not (isinstance(self.k, int | float | np.floating | np.integer)
                and math.isfinite(self.k) and self.k > 0):
            raise ValueError(f"Prior.k (the gate in σ) must be a finite number > 0, "
                             f"got {self.k!r}")
        object.__setattr__(self, "q_cam_icrs", q)
        if self.smear_cam_rad is not None:
            sm = np.asarray(self.smear_cam_rad, dtype=np.float64)
            if sm.shape != (3,) or not np.isfinite(sm).all():
                raise ValueError("Prior.smear_cam_rad must be a finite rotation vector (3,), "
                                 f"got {self.smear_cam_rad!r}")
            object.__setattr__(self, "smear_cam_rad", sm)


@dataclass(frozen=True)
class Candidate:
    """One verified geometric match (an entry of the operator-confirmation list).

    ``predicted_xy`` / ``predicted_ids`` — the catalogue projected into the frame at this
    attitude, for overlays — are computed on first use, not in the solve's hot path.
    """

    q_cam_icrs: NDArray[np.float64]
    matches: list[tuple[int, int]]  # (detection index, catalogue id)
    residuals_rad: NDArray[np.float64]
    p_false: float
    n_pattern: int
    camera: Camera
    covariance: NDArray[np.float64]  # 3×3, camera frame, rad²
    _projector: Callable[[NDArray, Camera], tuple[NDArray, NDArray]] = field(
        repr=False, compare=False, default=None)

    @cached_property
    def _predicted(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        return self._projector(self.q_cam_icrs, self.camera)

    @property
    def predicted_xy(self) -> NDArray[np.float64]:
        return self._predicted[0]

    @property
    def predicted_ids(self) -> NDArray[np.int64]:
        return self._predicted[1]

    @property
    def radec_roll_deg(self) -> tuple[float, float, float]:
        return tuple(float(np.degrees(a)) for a in rot.radec_roll_from_q_cam_icrs(
            self.q_cam_icrs))  # type: ignore[return-value]


@dataclass(frozen=True)
class Solution:
    """Result of :meth:`Solver.solve` (docs/api/starid.md)."""

    ok: bool
    reason: str = ""
    q_cam_icrs: NDArray[np.float64] | None = None
    matches: list[tuple[int, int]] = field(default_factory=list)
    matching_counter: int = 0
    covariance: NDArray[np.float64] | None = None
    mode: str = "lost-in-space"
    time_s: float = 0.0
    p_false: float | None = None
    path: str = ""
    candidates: list[Candidate] = field(default_factory=list)
    residuals_rad: NDArray[np.float64] | None = None
    camera: Camera | None = None
    n_detections: int = 0
    patterns_tried: int = 0
    #: a-posteriori 1-σ centroid noise (px) the covariance uses (None: not estimated)
    sigma_px: float | None = None
    #: what the solver decided on the way that the caller should know (not an error)
    note: str = ""
    #: tracking: catalogue stars the prior predicted in the frame (0 for lost-in-space)
    n_predicted: int = 0

    def __getattr__(self, name: str):
        # Only for an attribute the instance lacks: ``candidates`` of a solution the
        # compiled path made without it (starid.identify.lost_in_space._accepted) is made here from
        # ``_candidates_from`` (a function and its arguments) on first use. Two threads
        # may both make it; the first one stored is kept.
        if name == "candidates":
            d = self.__dict__
            made_from = d.get("_candidates_from")
            if made_from is not None:
                try:
                    found = made_from[0](*made_from[1:])
                except AttributeError as e:  # not to be taken for a missing attribute
                    raise RuntimeError(f"making the solution's candidates failed: {e}") from e
                d.setdefault("candidates", found)
                d.pop("_candidates_from", None)
            if "candidates" in d:
                return d["candidates"]
        raise AttributeError(f"'{type(self).__name__}' object has no attribute {name!r}")

    def __getstate__(self) -> dict:
        # pickled and copied with its candidates made (not the arrays they are made from)
        self.candidates  # noqa: B018
        return self.__dict__

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float] | None:
        """Boresight RA, Dec and roll (deg; roll as in :mod:`starid.rotations`)."""
        if self.q_cam_icrs is None:
            return None
        return tuple(float(np.degrees(a)) for a in rot.radec_roll_from_q_cam_icrs(
            self.q_cam_icrs))  # type: ignore[return-value]

    @property
    def rms_residual_arcsec(self) -> float | None:
        if self.residuals_rad is None or len(self.residuals_rad) == 0:
            return None
        return float(np.degrees(np.sqrt(np.mean(self.residuals_rad**2))) * 3600)


def accepted_solution(c: Candidate, counter: int, path: str,
                      cands: list[Candidate]) -> Solution:
    """The ``ok`` :class:`Solution` of an accepted candidate ``c``: its attitude, matches,
    covariance, p_false, residuals and camera, with the search's ``counter`` (Renken's
    matching counter), ``path`` and every candidate verified (``cands``)."""
    return Solution(
        True, "", q_cam_icrs=c.q_cam_icrs, matches=c.matches, matching_counter=counter,
        covariance=c.covariance, p_false=c.p_false, path=path, candidates=cands,
        residuals_rad=c.residuals_rad, camera=c.camera,
    )
