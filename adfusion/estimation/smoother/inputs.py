"""What the smoother is given: the frames' identified stars, the gyro and the magnetometer
(:class:`SmootherInput`, filled during a replay), and the error it raises."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

Array = NDArray[np.float64]


class SmootherError(RuntimeError):
    """The smoother could not produce an answer it can stand behind (the message says why)."""


@dataclass
class FrameData:
    """One camera frame as the smoother sees it.

    Attributes:
        t: frame time, s.
        b_body: (N, 3) measured unit directions of the identified stars, body frame.
        r_icrs: (N, 3) their catalogue directions, ICRS.
        ids: (N,) catalogue ids (diagnostics: which star a down-weighted residual was).
        q_init: the filter's ``q_body_icrs`` at this frame (starting point), or None.
        bias_init: the filter's gyro bias at this frame (rad/s), or None.
        q_fix, cov_fix: the solver's fix as ``q_body_icrs`` and its body-frame covariance
            (rad²) — used by ``star_model="fix"`` and for frames with a fix but no vectors.
        accepted: whether the filter accepted the fix (diagnostics only: the smoother uses
            every identified frame and lets its robust kernel judge).
    """

    t: float
    b_body: Array
    r_icrs: Array
    ids: NDArray[np.int64]
    q_init: Array | None = None
    bias_init: Array | None = None
    q_fix: Array | None = None
    cov_fix: Array | None = None
    accepted: bool = False

    @property
    def n_stars(self) -> int:
        return len(self.b_body)


class SmootherInput:
    """What a replay records for :func:`smooth`: frames (with their stars), gyro, magnetometer.

    Args:
        q_body_cam: camera mounting (camera → body), to turn camera vectors into body ones.
        arw_rad_sqrt_s, rrw_rad_s_sqrt_s: gyro angle and rate random walk.
        sigma_mag_rad: 1σ direction error of a magnetometer sample.
        video_only: no gyro — the smoother estimates the body rate (docs/concepts/smoother.md).

    Example:
        >>> inp = SmootherInput(video_only=True)
        >>> inp.add_frame(0.0, b_body=[[0.0, 0.0, 1.0]], r_icrs=[[1.0, 0.0, 0.0]], ids=[7])
        >>> inp.frames[0].n_stars, inp.video_only
        (1, True)
    """

    def __init__(
        self,
        q_body_cam: ArrayLike = rot.IDENTITY,
        *,
        arw_rad_sqrt_s: float = 1e-4,
        rrw_rad_s_sqrt_s: float = 1e-6,
        sigma_mag_rad: float = math.radians(1.0),
        video_only: bool = False,
    ) -> None:
        self.q_body_cam = rot.normalize(q_body_cam)
        self.R_body_cam = rot.to_matrix(self.q_body_cam)
        self.arw = float(arw_rad_sqrt_s)
        self.rrw = float(rrw_rad_s_sqrt_s)
        self.sigma_mag_rad = float(sigma_mag_rad)
        self.video_only = bool(video_only)
        self.frames: list[FrameData] = []
        self._gyro_t: list[float] = []
        self._gyro_w: list[Array] = []
        self._mag_t: list[float] = []
        self._mag_b: list[Array] = []
        self._mag_r: list[Array] = []
        self._id_rows: dict[int, tuple[Any, dict[int, int]]] = {}
        self.problems: list[str] = []  # what recording had to leave out, and why

    # --- recording ------------------------------------------------------------------------

    def add_gyro(self, t: float, omega_rad_s: ArrayLike) -> None:
        """A gyro sample (rad/s, body frame, bias included). Ignored in video-only mode."""
        w = np.asarray(omega_rad_s, dtype=np.float64).reshape(3)
        if not self.video_only and np.all(np.isfinite(w)) and math.isfinite(t):
            self._gyro_t.append(float(t))
            self._gyro_w.append(w)

    def add_mag(self, t: float, b_body: ArrayLike, b_icrs: ArrayLike) -> None:
        """A magnetometer sample: the field in the body frame and its ICRS reference."""
        b = np.asarray(b_body, dtype=np.float64).reshape(3)
        r = np.asarray(b_icrs, dtype=np.float64).reshape(3)
        nb, nr = np.linalg.norm(b), np.linalg.norm(r)
        if math.isfinite(t) and np.isfinite(nb * nr) and nb > 0 and nr > 0:
            self._mag_t.append(float(t))
            self._mag_b.append(b / nb)
            self._mag_r.append(r / nr)

    def add_frame(
        self,
        t: float,
        *,
        b_body: ArrayLike = (),
        r_icrs: ArrayLike = (),
        ids: ArrayLike | None = None,
        q_init: ArrayLike | None = None,
        bias_init: ArrayLike | None = None,
        q_fix: ArrayLike | None = None,
        cov_fix: ArrayLike | None = None,
        accepted: bool = False,
    ) -> None:
        """A camera frame with its identified stars (possibly none), in time order."""
        b = np.asarray(b_body, dtype=np.float64).reshape(-1, 3)
        r = np.asarray(r_icrs, dtype=np.float64).reshape(-1, 3)
        if len(b) != len(r):
            raise ValueError(f"b_body and r_icrs differ in length: {len(b)} vs {len(r)}")
        ids_a = (np.full(len(b), -1, np.int64) if ids is None
                 else np.asarray(ids, dtype=np.int64).reshape(-1))
        if len(ids_a) != len(b):
            raise ValueError(f"ids has {len(ids_a)} entries for {len(b)} stars")
        if self.frames and not t > self.frames[-1].t:
            raise ValueError(f"frame times must increase: {t} after {self.frames[-1].t}")
        ok = np.all(np.isfinite(b), axis=1) & np.all(np.isfinite(r), axis=1)
        b, r, ids_a = b[ok], r[ok], ids_a[ok]
        b = b / np.linalg.norm(b, axis=1, keepdims=True) if len(b) else b
        r = r / np.linalg.norm(r, axis=1, keepdims=True) if len(r) else r

        def opt(x, n):
            return None if x is None else np.asarray(x, dtype=np.float64).reshape(n)

        self.frames.append(FrameData(
            float(t), b, r, ids_a, None if q_init is None else rot.normalize(q_init),
            opt(bias_init, 3), None if q_fix is None else rot.normalize(q_fix),
            opt(cov_fix, (3, 3)), bool(accepted)))

    def add_step(self, t: float, rec: Any, solver: Any) -> None:
        """A camera frame from an :class:`adfusion.estimation.estimator.StepRecord` and its solver.

        The identified stars come from ``rec.solution.matches`` (detection index, catalogue
        id) with ``rec.detections_xy`` through the solution's camera, mounted into the body
        frame; the filter's estimate after the step is the starting point. A frame whose time
        does not follow the previous one is left out and noted in :attr:`problems`.
        """
        if self.frames and not t > self.frames[-1].t:
            self.problems.append(f"frame at t = {t} s left out: not after the previous frame "
                                 f"({self.frames[-1].t} s)")
            return
        sol = rec.solution
        b = r = ids = None
        q_fix = cov_fix = None
        if sol is not None and sol.ok:
            q_fix = rot.multiply(self.q_body_cam, sol.q_cam_icrs)
            if sol.covariance is not None:
                cov_fix = self.R_body_cam @ np.asarray(sol.covariance) @ self.R_body_cam.T
            xy = rec.detections_xy
            if xy is not None and len(sol.matches):
                det = np.array([m[0] for m in sol.matches], dtype=np.int64)
                ids = np.array([m[1] for m in sol.matches], dtype=np.int64)
                keep = det < len(xy)
                det, ids = det[keep], ids[keep]
                rows = self._rows(solver.catalog)
                cam = sol.camera if sol.camera is not None else solver.camera
                b = cam.pixels_to_vectors(np.asarray(xy)[det]) @ self.R_body_cam.T
                r = np.asarray(solver.catalog.vectors)[[rows[int(i)] for i in ids]]
        self.add_frame(t, b_body=() if b is None else b, r_icrs=() if r is None else r,
                       ids=ids, q_init=rec.q_body_icrs, bias_init=rec.bias_rad_s,
                       q_fix=q_fix, cov_fix=cov_fix, accepted=bool(rec.fix_accepted))

    def _rows(self, catalog: Any) -> dict[int, int]:
        hit = self._id_rows.get(id(catalog))
        if hit is None or hit[0] is not catalog:
            hit = (catalog, {int(i): k for k, i in enumerate(np.asarray(catalog.ids))})
            self._id_rows[id(catalog)] = hit
        return hit[1]

    # --- views ----------------------------------------------------------------------------

    @property
    def gyro(self) -> tuple[Array, Array]:
        """(times (G,), rates (G, 3)) of the gyro samples, time-sorted."""
        t = np.asarray(self._gyro_t, dtype=np.float64)
        w = np.asarray(self._gyro_w, dtype=np.float64).reshape(-1, 3)
        o = np.argsort(t, kind="stable")
        return t[o], w[o]

    @property
    def mag(self) -> tuple[Array, Array, Array]:
        """(times (M,), body unit vectors (M, 3), ICRS unit vectors (M, 3))."""
        return (np.asarray(self._mag_t, dtype=np.float64),
                np.asarray(self._mag_b, dtype=np.float64).reshape(-1, 3),
                np.asarray(self._mag_r, dtype=np.float64).reshape(-1, 3))
