"""Fit a camera model and attitude to reference pixel ↔ sky-direction pairs.

Used to check a camera against an independent solution (astrometry.net's grid in
``shared/data/real-images/truth.json``) and to refine the focal length of a camera from
identified stars. Least squares on the angle between predicted and reference directions
(scipy ``least_squares``), starting from the Wahba solution.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> from adfusion.starid.calibrate import fit_camera
    >>> true_cam = Camera.pinhole(1024, 768, 11.4)
    >>> q = rot.q_cam_icrs_from_radec_roll(3.0, 0.4, 1.0)
    >>> xy = np.array([[100.0, 80], [512, 80], [900, 700], [512, 384], [50, 700]])
    >>> r = rot.rotate(rot.inverse(q), true_cam.pixels_to_vectors(xy))
    >>> fit = fit_camera(xy, r, Camera.pinhole(1024, 768, 11.0))
    >>> round(fit.camera.fov_x_deg, 9), bool(fit.rms_rad < 1e-12)
    (11.4, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid import rotations as rot
from adfusion.starid.attitude import wahba
from adfusion.starid.camera import Camera
from numpy.typing import ArrayLike, NDArray

__all__ = ["CAMERA_TERMS", "CameraFit", "CameraModelFit", "fit_camera", "fit_camera_model"]


@dataclass(frozen=True)
class CameraFit:
    """Result of :func:`fit_camera`: the camera, ``q_cam_icrs`` and residuals (rad)."""

    camera: Camera
    q_cam_icrs: NDArray[np.float64]
    residuals_rad: NDArray[np.float64]

    @property
    def rms_rad(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_rad**2)))


def fit_camera(
    xy: ArrayLike,
    r_icrs: ArrayLike,
    camera: Camera,
    fit_focal: bool = True,
    fit_k1: bool = False,
    try_mirror: bool = True,
) -> CameraFit:
    """Fit attitude (and focal scale, and optionally radial k1) to pixel/direction pairs.

    With ``try_mirror`` both parities are fitted and the better one returned, so an
    image of unknown handedness is handled.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    r = np.asarray(r_icrs, dtype=np.float64).reshape(-1, 3)
    need = 2 + int(fit_focal) + int(fit_k1)
    if len(xy) < need or len(xy) != len(r):
        raise ValueError(f"need ≥ {need} matching pixel/direction pairs, got {len(xy)}/{len(r)}")
    if fit_k1 and camera.model != "pinhole":
        raise ValueError("k1 can only be fitted for the pinhole model")
    cams = [camera, camera.mirrored()] if try_mirror else [camera]
    fits = [_fit_one(xy, r, c, fit_focal, fit_k1) for c in cams]
    return min(fits, key=lambda f: f.rms_rad)


def _fit_one(xy: NDArray, r: NDArray, cam0: Camera, fit_focal: bool, fit_k1: bool) -> CameraFit:
    q0 = wahba(cam0.pixels_to_vectors(xy), r).q_cam_icrs

    def make_camera(p: NDArray) -> Camera:
        cam = cam0.scaled(float(np.exp(p[3]))) if fit_focal else cam0
        if fit_k1:
            d = np.zeros(5)
            d[: cam.D.size] = cam.D[:5]
            d[0] = p[4]
            cam = Camera(cam.K, d, cam.width, cam.height, cam.model, cam.parity)
        return cam

    def residuals(p: NDArray) -> NDArray:
        cam = make_camera(p)
        q = rot.multiply(rot.exp_map(p[:3]), q0)
        b = cam.pixels_to_vectors(xy)
        pred = rot.rotate(q, r)
        return np.cross(pred, b).ravel()  # ≈ angle × axis, smooth near the optimum

    p0 = np.zeros(3 + int(fit_focal) + int(fit_k1))
    from scipy.optimize import least_squares  # ~0.25 s: on first fit, not import

    sol = least_squares(residuals, p0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    cam = make_camera(sol.x)
    q = rot.normalize(rot.multiply(rot.exp_map(sol.x[:3]), q0))
    b = cam.pixels_to_vectors(xy)
    pred = rot.rotate(q, r)
    res = np.arctan2(np.linalg.norm(np.cross(pred, b), axis=1), np.sum(pred * b, axis=1))
    return CameraFit(cam, q, res)


# --- the camera model from identified stars: one frame or many ---------------------------

#: Terms :func:`fit_camera_model` can fit, and the nested models ``terms="auto"`` chooses
#: from (with the fewest matched stars each needs): the focal length first, then radial
#: distortion, the principal point, the pixel aspect, then k2 and the tangential terms.
CAMERA_TERMS = ("focal", "k1", "principal", "aspect", "k2", "tangential")
_AUTO_MODELS = (
    (("focal",), 3),
    (("focal", "k1"), 8),
    (("focal", "k1", "principal"), 12),
    (("focal", "k1", "principal", "aspect"), 16),
    (("focal", "k1", "principal", "k2"), 20),
    (("focal", "k1", "principal", "k2", "tangential"), 24),
    (("focal", "k1", "principal", "aspect", "k2", "tangential"), 28),
)
# Weak priors (1 σ) that keep a fit with few stars from wandering along its near-degenerate
# directions (principal point vs pointing, k1 vs focal length): the principal point within
# a tenth of the frame, |k1|, |k2| ≲ 1, tangential terms ≲ 0.02, pixel aspect ≲ 10 %.
_PRIOR_SIGMA = {"principal": 0.1, "k1": 1.0, "k2": 1.0, "tangential": 0.02, "aspect": 0.1}


@dataclass(frozen=True)
class CameraModelFit:
    """Result of :func:`fit_camera_model`: the camera, one attitude per frame, the pixel
    residuals (predicted − measured) per frame, the a-posteriori centroid noise (px) and
    the terms fitted."""

    camera: Camera
    q_cam_icrs: list[NDArray[np.float64]]
    residuals_px: list[NDArray[np.float64]]
    sigma_px: float
    terms: tuple[str, ...]

    @property
    def rms_px(self) -> float:
        """RMS pixel residual over all frames' stars (per star, both axes)."""
        r = np.concatenate(self.residuals_px)
        return float(np.sqrt(np.mean(np.sum(r * r, axis=1)))) if len(r) else float("nan")


def fit_camera_model(
    frames: list[tuple[ArrayLike, ArrayLike]],
    camera: Camera,
    terms: str | tuple[str, ...] = "auto",
    q_cam_icrs: list[ArrayLike] | None = None,
) -> CameraModelFit:
    """Fit a pinhole camera (focal length, principal point, pixel aspect, OpenCV radial
    k1, k2 and tangential p1, p2) and one attitude per frame to identified stars.

    ``frames`` holds, per frame, the matched stars' pixel positions (N, 2) and their ICRS
    directions (N, 3); one frame is the solver's self-calibration, many a calibration run
    (``adfusion calibrate``). ``terms`` names what to fit (:data:`CAMERA_TERMS`), or
    ``"auto"``: the nested model (:data:`_AUTO_MODELS`) with the lowest Bayesian
    information criterion that the star count supports. The rest of ``camera`` (k3,
    parity, size) is kept. Least squares on pixel residuals (``scipy.optimize``) with weak
    priors against the near-degenerate directions.

    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> true = Camera(np.array([[2650.0, 0, 520], [0, 2650.0, 380], [0, 0, 1]]),
    ...               [-0.3, 0.0, 0.0, 0.0, 0.0], 1024, 768)
    >>> q = rot.q_cam_icrs_from_radec_roll(1.0, 0.3, 0.2)
    >>> g = np.stack(np.meshgrid(np.linspace(20, 1000, 6), np.linspace(20, 740, 5)), -1)
    >>> xy = g.reshape(-1, 2)
    >>> r = rot.rotate(rot.inverse(q), true.pixels_to_vectors(xy))
    >>> fit = fit_camera_model([(xy, r)], Camera.pinhole(1024, 768, 11.0),
    ...                        terms=("focal", "principal", "k1"))
    >>> round(float(fit.camera.D[0]), 2), bool(fit.rms_px < 0.01)
    (-0.3, True)
    """
    if camera.model != "pinhole":
        raise ValueError(f"fit_camera_model fits the pinhole model, not {camera.model!r}")
    data = []
    for k, (xy, r) in enumerate(frames):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        r = np.asarray(r, dtype=np.float64).reshape(-1, 3)
        if len(xy) != len(r) or len(xy) < 2:
            raise ValueError(f"frame {k}: need ≥ 2 matching pixel/direction pairs, got "
                             f"{len(xy)}/{len(r)}")
        data.append((xy, r))
    if not data:
        raise ValueError("fit_camera_model needs at least one frame")
    n_stars = sum(len(xy) for xy, _ in data)
    if q_cam_icrs is None:
        q0 = [wahba(camera.pixels_to_vectors(xy), r).q_cam_icrs for xy, r in data]
    else:
        q0 = [rot.normalize(np.asarray(q, dtype=np.float64)) for q in q_cam_icrs]
    if terms == "auto":
        # the nested models in order, while the Bayesian information criterion improves
        need_extra = 3 * (len(data) - 1)  # every further frame's attitude
        n_obs = 2 * n_stars

        def bic(f: CameraModelFit) -> float:
            rss = sum(float(np.sum(r * r)) for r in f.residuals_px)
            k = _n_params(f.terms) + 3 * len(data)
            return n_obs * math.log(max(rss, 1e-12) / n_obs) + k * math.log(n_obs)

        best, best_bic = None, math.inf
        for t, n_min in _AUTO_MODELS:
            if n_stars < n_min + need_extra // 2:
                break
            f = _fit_model(data, camera, t, q0)
            b = bic(f)
            if b >= best_bic:
                break
            best, best_bic = f, b
        return best if best is not None else _fit_model(data, camera, (), q0)
    terms = tuple(terms)
    bad = set(terms) - set(CAMERA_TERMS)
    if bad:
        raise ValueError(f"unknown camera terms {sorted(bad)}; choose from {CAMERA_TERMS}")
    if n_stars * 2 < _n_params(terms) + 3 * len(data):
        raise ValueError(f"{n_stars} stars cannot fit {terms} and {len(data)} attitude(s)")
    return _fit_model(data, camera, terms, q0)


def _n_params(terms: tuple[str, ...]) -> int:
    return sum(2 if t in ("principal", "tangential") else 1 for t in terms)


def _fit_model(data: list[tuple[NDArray, NDArray]], cam0: Camera, terms: tuple[str, ...],
               q0: list[NDArray]) -> CameraModelFit:
    n_fr = len(data)
    fx0, fy0, cx0, cy0 = cam0.K[0, 0], cam0.K[1, 1], cam0.K[0, 2], cam0.K[1, 2]
    d0 = np.zeros(5)
    d0[: min(5, cam0.D.size)] = cam0.D[:5]
    size = float(max(cam0.width, cam0.height))
    slots: dict[str, slice] = {}
    pos = 3 * n_fr
    for t in CAMERA_TERMS:
        if t in terms:
            w = 2 if t in ("principal", "tangential") else 1
            slots[t] = slice(pos, pos + w)
            pos += w
    R0 = np.stack([rot.to_matrix(q) for q in q0])
    xy_all = np.concatenate([xy for xy, _ in data])
    r_all = np.concatenate([r for _, r in data])
    frame_of = np.concatenate([np.full(len(xy), k) for k, (xy, _) in enumerate(data)])
    par = float(cam0.parity)
    skew = cam0.K[0, 1] / fx0

    def intrinsics(p: NDArray) -> tuple[NDArray, ...]:
        """Per parameter set (rows of p): fx, fy, cx, cy (S,) and D (S, 5)."""
        S = p.shape[0]
        s = p[:, slots["focal"].start] if "focal" in slots else np.zeros(S)
        a = p[:, slots["aspect"].start] if "aspect" in slots else np.zeros(S)
        fx, fy = fx0 * np.exp(s), fy0 * np.exp(s + a)
        cx, cy = np.full(S, cx0), np.full(S, cy0)
        if "principal" in slots:
            dc = p[:, slots["principal"]] * size
            cx, cy = cx + dc[:, 0], cy + dc[:, 1]
        d = np.tile(d0, (S, 1))
        if "k1" in slots:
            d[:, 0] = p[:, slots["k1"].start]
        if "k2" in slots:
            d[:, 1] = p[:, slots["k2"].start]
        if "tangential" in slots:
            d[:, 2:4] = p[:, slots["tangential"]]
        return fx, fy, cx, cy, d

    def project(p: NDArray) -> NDArray:
        """Predicted pixels (S, N, 2) of every star for parameter sets p (S, P)."""
        S = p.shape[0]
        w = p[:, : 3 * n_fr].reshape(S, n_fr, 3)
        th = np.sqrt(np.einsum("sfi,sfi->sf", w, w))[..., None, None]
        Kx = np.zeros((S, n_fr, 3, 3))
        Kx[..., 0, 1], Kx[..., 0, 2], Kx[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
        Kx[..., 1, 0], Kx[..., 2, 0], Kx[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
        small = th < 1e-8
        a = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))
        b = np.where(small, 0.5, (1 - np.cos(th)) / np.where(small, 1.0, th * th))
        dR = np.eye(3) + a * Kx + b * (Kx @ Kx)  # Rodrigues: exp of the rotation vector
        R = dR @ R0  # (S, F, 3, 3)
        v = np.einsum("snj,snij->sni", np.broadcast_to(r_all, (S, *r_all.shape)),
                      R[:, frame_of])
        x, y = par * v[..., 0] / v[..., 2], v[..., 1] / v[..., 2]
        fx, fy, cx, cy, d = intrinsics(p)
        k1, k2, p1, p2, k3 = (d[:, i, None] for i in range(5))
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([fx[:, None] * (xd + skew * yd) + cx[:, None],
                         fy[:, None] * yd + cy[:, None]], -1)

    prior_idx = [(sl, _PRIOR_SIGMA[t]) for t, sl in slots.items() if t in _PRIOR_SIGMA]

    def residuals_batch(p: NDArray) -> NDArray:
        res = (project(p) - xy_all).reshape(p.shape[0], -1)
        prior = [p[:, sl] / sig for sl, sig in prior_idx]
        return np.concatenate([res, *prior], axis=1) if prior else res

    def residuals(p: NDArray) -> NDArray:
        return residuals_batch(p[None])[0]

    def jacobian(p: NDArray) -> NDArray:
        # forward differences, every parameter in one vectorised evaluation
        h = 1e-7 * np.maximum(1.0, np.abs(p))
        sets = np.vstack([p, p + np.diag(h)])
        f = residuals_batch(sets)
        return ((f[1:] - f[0]) / h[:, None]).T

    p0 = np.zeros(pos)
    from scipy.optimize import least_squares  # ~0.25 s: on first fit, not import

    sol = least_squares(residuals, p0, jac=jacobian, method="lm", xtol=1e-12, ftol=1e-12,
                        gtol=1e-12, max_nfev=100)
    fx, fy, cx, cy, d = (v[0] for v in intrinsics(sol.x[None]))
    K = np.array([[fx, skew * fx, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = d if cam0.D.size <= 5 else np.concatenate([d, cam0.D[5:]])
    cam = Camera(K, D, cam0.width, cam0.height, "pinhole", cam0.parity)
    qs = [rot.normalize(rot.multiply(rot.exp_map(sol.x[3 * k: 3 * k + 3]), q0[k]))
          for k in range(n_fr)]
    res_all = project(sol.x[None])[0] - xy_all
    splits = np.cumsum([len(xy) for xy, _ in data])[:-1]
    n_obs = 2 * len(xy_all)
    dof = n_obs - _n_params(terms) - 3 * n_fr
    sigma = math.sqrt(float(np.sum(res_all**2)) / dof) if dof > 0 else float("nan")
    return CameraModelFit(cam, qs, np.split(res_all, splits), sigma, terms)
