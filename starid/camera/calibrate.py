"""Fit a camera model and attitude to reference pixel ↔ sky-direction pairs.

Used to check a camera against an independent solution (astrometry.net's grid in
``shared/data/real-images/truth.json``) and to refine the focal length of a camera from
identified stars. Least squares on the angle between predicted and reference directions
(scipy ``least_squares``), starting from the Wahba solution.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> from adfusion.starid.camera.calibrate import fit_camera
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
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import wahba
from adfusion.plain import listed

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
    free_principal: bool = True,
) -> CameraModelFit:
    """Fit a pinhole camera (focal length, principal point, pixel aspect, OpenCV radial
    k1, k2 and tangential p1, p2) and one attitude per frame to identified stars.

    ``frames`` holds, per frame, the matched stars' pixel positions (N, 2) and their ICRS
    directions (N, 3); one frame is the solver's self-calibration, many a calibration run
    (``adfusion calibrate``). ``terms`` names what to fit (:data:`CAMERA_TERMS`), or
    ``"auto"``: the nested model (:data:`_AUTO_MODELS`) with the lowest Bayesian
    information criterion that the star count supports; ``free_principal=False`` keeps
    ``camera``'s principal point in every one of them. One frame cannot tell a shifted
    principal point from a turned camera (both move every star alike to first order), so
    the solver's per-frame fit keeps it: its attitude is then always that of the camera
    it was given, frame after frame. The rest of ``camera`` (k3,
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

        best, best_bic, start = None, math.inf, None
        models: list[tuple[tuple[str, ...], int]] = []
        for t, n in _AUTO_MODELS:
            t = t if free_principal else tuple(x for x in t if x != "principal")
            if all(t != seen for seen, _ in models):  # a model once, at its first count
                models.append((t, n))
        for t, n_min in models:
            if n_stars < n_min + need_extra // 2:
                break
            # each larger model starts where the smaller one ended (its new terms at 0):
            # fewer iterations, the same minimum
            f, x = _fit_model(data, camera, t, q0, start)
            b = bic(f)
            if b >= best_bic:
                break
            best, best_bic, start = f, b, x
        return best if best is not None else _fit_model(data, camera, (), q0)[0]
    terms = tuple(terms)
    bad = set(terms) - set(CAMERA_TERMS)
    if bad:
        raise ValueError(f"unknown camera terms {listed(sorted(bad), None)}; choose from "
                         f"{listed(CAMERA_TERMS, None)}")
    if n_stars * 2 < _n_params(terms) + 3 * len(data):
        raise ValueError(f"{n_stars} stars cannot fit the terms {listed(terms, None)} and "
                         f"{len(data)} attitude(s)")
    return _fit_model(data, camera, terms, q0)[0]


def _n_params(terms: tuple[str, ...]) -> int:
    return sum(2 if t in ("principal", "tangential") else 1 for t in terms)


def _fit_model(data: list[tuple[NDArray, NDArray]], cam0: Camera, terms: tuple[str, ...],
               q0: list[NDArray], start: dict[str, NDArray] | None = None,
               ) -> tuple[CameraModelFit, dict[str, NDArray]]:
    """The fit of ``terms`` and its parameters by name (``"rotation"`` and each term), from
    ``start`` (a previous fit's parameters; terms it lacks start at 0)."""
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
    ends = np.cumsum([len(xy) for xy, _ in data])
    frame_slices = [slice(int(e - len(xy)), int(e)) for e, (xy, _) in zip(ends, data,
                                                                          strict=True)]
    par = float(cam0.parity)
    skew = cam0.K[0, 1] / fx0
    higher_radial = "k2" in slots or bool(d0[1] or d0[4])
    tangential = "tangential" in slots or bool(d0[2] or d0[3])

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
        # each frame's stars (contiguous) through its own rotation: a matmul per frame, not
        # an (S, N, 3, 3) gather of the rotations per star
        v = np.empty((S, len(r_all), 3))
        for k, sl in enumerate(frame_slices):
            np.matmul(r_all[sl], R[:, k].transpose(0, 2, 1), out=v[:, sl])
        x, y = par * v[..., 0] / v[..., 2], v[..., 1] / v[..., 2]
        fx, fy, cx, cy, d = intrinsics(p)
        k1, k2, p1, p2, k3 = (d[:, i, None] for i in range(5))
        r2 = x * x + y * y
        # the terms neither fitted nor in the camera are left out (these fits are small:
        # their cost is the number of array operations, not their size)
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3)) if higher_radial else 1 + r2 * k1
        xd, yd = x * rad, y * rad
        if tangential:
            xy2 = 2 * x * y
            xd = xd + p1 * xy2 + p2 * (r2 + 2 * x * x)
            yd = yd + p1 * (r2 + 2 * y * y) + p2 * xy2
        u = fx[:, None] * (xd + skew * yd if skew else xd) + cx[:, None]
        return np.stack([u, fy[:, None] * yd + cy[:, None]], -1)

    prior_idx = [(sl, _PRIOR_SIGMA[t]) for t, sl in slots.items() if t in _PRIOR_SIGMA]

    def residuals_batch(p: NDArray) -> NDArray:
        res = (project(p) - xy_all).reshape(p.shape[0], -1)
        prior = [p[:, sl] / sig for sl, sig in prior_idx]
        return np.concatenate([res, *prior], axis=1) if prior else res

    p0 = np.zeros(pos)
    if start is not None:
        p0[: 3 * n_fr] = start["rotation"]
        for t, sl in slots.items():
            if t in start:
                p0[sl] = start[t]
    x = _levenberg_marquardt(residuals_batch, p0)
    fx, fy, cx, cy, d = (v[0] for v in intrinsics(x[None]))
    K = np.array([[fx, skew * fx, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = d if cam0.D.size <= 5 else np.concatenate([d, cam0.D[5:]])
    cam = Camera(K, D, cam0.width, cam0.height, "pinhole", cam0.parity)
    qs = [rot.normalize(rot.multiply(rot.exp_map(x[3 * k: 3 * k + 3]), q0[k]))
          for k in range(n_fr)]
    res_all = project(x[None])[0] - xy_all
    splits = np.cumsum([len(xy) for xy, _ in data])[:-1]
    n_obs = 2 * len(xy_all)
    dof = n_obs - _n_params(terms) - 3 * n_fr
    sigma = math.sqrt(float(np.sum(res_all**2)) / dof) if dof > 0 else float("nan")
    params = {"rotation": x[: 3 * n_fr], **{t: x[sl] for t, sl in slots.items()}}
    return CameraModelFit(cam, qs, np.split(res_all, splits), sigma, terms), params


# relative cost reduction below which Levenberg–Marquardt stops (≈ 1e-6 of a pixel-level
# residual: far below any centroid's noise)
_LM_RTOL = 1e-12


def _levenberg_marquardt(residuals_batch, p0: NDArray, max_iter: int = 100) -> NDArray:
    """Minimise ‖r(p)‖² by Levenberg–Marquardt (Marquardt's diagonal scaling), the
    Jacobian by forward differences of every parameter in one batched evaluation of
    ``residuals_batch`` (parameter sets (S, P) → residuals (S, M)).

    Written out rather than scipy's ``least_squares`` (MINPACK): these problems are small
    (a frame: 4–12 parameters, 10–60 stars), where the library's set-up and per-call
    overhead cost ~2 ms a fit against ~0.3 ms here, the same minimum to ~1e-9 px — a
    solve fits 3–6 such models (measured on the real frames, issue 14's 20 ms budget).

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 20)
    >>> y = 3.0 * np.exp(-2.0 * t)
    >>> f = lambda p: p[:, :1] * np.exp(-p[:, 1:2] * t) - y
    >>> np.round(_levenberg_marquardt(f, np.array([1.0, 0.0])), 9).tolist()
    [3.0, 2.0]
    """
    p = np.asarray(p0, dtype=np.float64).copy()
    n = p.size
    r = residuals_batch(p[None])[0]
    cost = float(r @ r)
    lam = None
    for _ in range(max_iter):
        h = 1e-7 * np.maximum(1.0, np.abs(p))
        f = residuals_batch(p + np.vstack([np.zeros(n), np.diag(h)]))
        r = f[0]
        J = ((f[1:] - r) / h[:, None]).T
        A = J.T @ J
        g = J.T @ r
        dA = np.maximum(np.diag(A), 1e-30)
        if lam is None:
            lam = 1e-3
        improved = False
        for _ in range(30):
            try:
                step = np.linalg.solve(A + lam * np.diag(dA), -g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            # converged: the linear model promises no relative gain worth a try (the rest
            # is round-off; chasing it cost more evaluations than the fit itself)
            predicted = -float(2.0 * g @ step + step @ A @ step)
            if predicted <= _LM_RTOL * cost:
                return p
            r_new = residuals_batch((p + step)[None])[0]
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new <= cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        p = p + step
        small_step = np.all(np.abs(step) <= 1e-12 * np.maximum(1e-3, np.abs(p)))
        small_gain = cost - c_new <= _LM_RTOL * max(cost, 1e-300)
        cost = c_new
        lam = max(lam / 10.0, 1e-12)
        if small_step or small_gain:
            break
    return p
