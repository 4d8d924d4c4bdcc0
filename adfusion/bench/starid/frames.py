"""The frames of ``adfusion bench starid``: conditions, synthetic and rendered frames.

:class:`Condition` (one benchmark condition; :data:`CONDITIONS` the default set) and
:class:`Frame` (the truth and the centroid list every solver sees); :func:`make_frame`
builds frame *i* of a condition from the seed — a uniformly random attitude
(:func:`random_attitude`, the same in every condition), the visible catalogue stars through
an ideal pinhole (:func:`camera_for`), centroid noise, drops, false stars and the magnitude
ordering — or renders it with motion blur and runs the detector (:func:`render_frame_for`).
:class:`FrameModel` holds the camera, sky and scoring defaults shared with
``adfusion bench sweep``; :func:`load_catalog` the per-process catalogue cache.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

# --- conditions and frames ---------------------------------------------------------------


@dataclass(frozen=True)
class Condition:
    """One benchmark condition (a sweep point of ``adfusion bench sweep`` is one, too).

    ``sigma_px``, ``mag_limit``, ``mag_noise`` and ``fov_deg`` of ``None`` mean "the run's
    base value" (``--sigma``, ``--mag-limit``, ``--mag-noise``, ``--fov``); :meth:`resolved`
    fills them in. ``rate_deg_s`` set means a *rendered* frame: the stars are drawn onto an
    image streaked by a body rate of that size (random axis) over ``exposure_s``, and the
    centroids come from :func:`starid.detection.detect` (:func:`make_frame`).

    >>> Condition("x", n_false=3).resolved(0.1, 6.0).sigma_px
    0.1
    >>> Condition("x", fov_deg=20.0).resolved(0.1, 6.0, mag_noise=0.1, fov_deg=15.0).fov_deg
    20.0
    """

    name: str
    description: str = ""
    n_false: int = 0
    drop_frac: float = 0.0
    sigma_px: float | None = None
    mag_limit: float | None = None
    coverage: bool = False  # report frames with ≥ 3 / ≥ 4 catalogue stars in the table
    mag_noise: float | None = None
    fov_deg: float | None = None
    rate_deg_s: float | None = None  # None: synthetic centroids; a value: rendered + detect
    exposure_s: float = 0.1

    def resolved(self, sigma_px: float, mag_limit: float, *, mag_noise: float | None = None,
                 fov_deg: float | None = None) -> Condition:
        """A copy with the run's base values where unset."""
        return replace(
            self,
            sigma_px=sigma_px if self.sigma_px is None else self.sigma_px,
            mag_limit=mag_limit if self.mag_limit is None else self.mag_limit,
            mag_noise=mag_noise if self.mag_noise is None else self.mag_noise,
            fov_deg=fov_deg if self.fov_deg is None else self.fov_deg,
        )

    def params(self) -> dict[str, Any]:
        """The frame model's parameters (recorded in the JSON)."""
        out = {"n_false": self.n_false, "drop_frac": self.drop_frac,
               "sigma_px": self.sigma_px, "mag_limit": self.mag_limit}
        for k in ("mag_noise", "fov_deg", "rate_deg_s"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.rate_deg_s is not None:
            out["exposure_s"] = self.exposure_s
        return out


#: The default conditions, by name (``--conditions`` picks a subset, in this order).
CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        Condition("clean", "base centroid noise only"),
        Condition("false3", "3 false stars", n_false=3),
        Condition("false8", "8 false stars", n_false=8),
        Condition("drop30_false3", "30 % of stars dropped + 3 false", n_false=3,
                  drop_frac=0.3),
        Condition("sparse45", "sparse field: catalogue and visible stars V < 4.5",
                  mag_limit=4.5, coverage=True),
        Condition("sigma1", "centroid σ = 1 px", sigma_px=1.0),
        Condition("sigma2", "centroid σ = 2 px", sigma_px=2.0),
    )
}


@dataclass(frozen=True)
class Frame:
    """One synthetic frame: the truth and the centroid list every solver sees.

    ``xy`` is (N, 2), brightest (observed) first, pixel centres (docs/conventions.md);
    ``cat_ids`` holds the HIP number of each row, −1 for a false star.
    """

    condition: str
    index: int
    q_cam_icrs: NDArray[np.float64]
    xy: NDArray[np.float64]
    cat_ids: NDArray[np.int64]
    n_in_view: int  # catalogue stars in view before drops
    seed: int = 0
    # rendered frames: the camera's rate (rad/s, camera axes) over the exposure, during which
    # the true attitude is exp(−ω s) ⊗ q_cam_icrs, s ∈ [−T/2, T/2]
    omega_cam_rad_s: NDArray[np.float64] | None = None
    exposure_s: float = 0.0

    @property
    def n_true(self) -> int:
        """Catalogue stars among the centroids (after drops and noise)."""
        return int(np.count_nonzero(self.cat_ids >= 0))


def _cond_key(name: str) -> int:
    return zlib.crc32(name.encode())


def random_attitude(seed: int, index: int) -> NDArray[np.float64]:
    """Uniformly random ``q_cam_icrs`` for frame ``index`` (the same in every condition).

    >>> from adfusion.starid import rotations as rot
    >>> bool(np.allclose(random_attitude(0, 5), random_attitude(0, 5)))
    True
    """
    from adfusion.maths import rotations as rot

    rng = np.random.default_rng([seed, index])
    return rot.normalize(rng.normal(size=4))


def make_frame(catalog, camera, cond: Condition, seed: int, index: int,
               mag_noise: float = 0.1) -> Frame:
    """Build frame ``index`` of condition ``cond`` (resolved: ``sigma_px``, ``mag_limit`` set).

    ``catalog`` must hold the stars visible under ``cond`` (``mag < cond.mag_limit``) and
    ``camera`` be the condition's (:func:`camera_for`). ``cond.mag_noise``, when set, replaces
    ``mag_noise``. A condition with ``rate_deg_s`` is rendered (:func:`render_frame_for`).

    >>> from adfusion import starid
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=6.0, epoch=2025.0)
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> f = make_frame(cat, cam, CONDITIONS["false3"].resolved(0.1, 6.0), seed=0, index=7)
    >>> int(np.count_nonzero(f.cat_ids < 0)), f.xy.shape[1]
    (3, 2)
    """
    from adfusion.maths import rotations as rot

    if cond.rate_deg_s is not None:
        return render_frame_for(catalog, camera, cond, seed, index)
    if cond.mag_noise is not None:
        mag_noise = cond.mag_noise
    q = random_attitude(seed, index)
    rng = np.random.default_rng([seed, index, _cond_key(cond.name)])
    v = rot.rotate(q, catalog.vectors)
    front = np.flatnonzero(v[:, 2] > 0)
    xy = camera.vectors_to_pixels(v[front])
    inside = camera.in_frame(xy)
    xy, idx = xy[inside], front[inside]
    n_in_view = len(idx)
    mags = np.asarray(catalog.mag, dtype=np.float64)[idx]
    ids = np.asarray(catalog.ids, dtype=np.int64)[idx]
    keep = rng.random(len(idx)) >= cond.drop_frac
    xy, mags, ids = xy[keep], mags[keep], ids[keep]
    sigma = float(cond.sigma_px or 0.0)
    xy = xy + rng.normal(0.0, 1.0, xy.shape) * sigma
    ok = camera.in_frame(xy)  # pushed out of the frame by the noise: not detected
    xy, mags, ids = xy[ok], mags[ok], ids[ok]
    if cond.n_false:
        fx = rng.uniform(-0.5, camera.width - 0.5, cond.n_false)
        fy = rng.uniform(-0.5, camera.height - 0.5, cond.n_false)
        fmag = rng.choice(np.asarray(catalog.mag, dtype=np.float64), cond.n_false)
        xy = np.vstack([xy, np.column_stack([fx, fy])])
        mags = np.concatenate([mags, fmag])
        ids = np.concatenate([ids, np.full(cond.n_false, -1, np.int64)])
    observed = mags + rng.normal(0.0, 1.0, len(mags)) * mag_noise
    order = np.argsort(observed, kind="stable")
    return Frame(cond.name, index, q, xy[order], ids[order], n_in_view, seed)


#: The detector model of rendered frames: the renderer's default small star tracker (a
#: V = 6 star gives ~4000 e⁻ per exposure over 100 e⁻ of sky per pixel, 10 e⁻ read noise).
RENDER_SENSOR: dict[str, Any] = {"psf_sigma_px": 1.0, "noise": "gaussian"}


def render_frame_for(catalog, camera, cond: Condition, seed: int, index: int) -> Frame:
    """A rendered frame: ``sensors.render.render_frame`` + :func:`starid.detection.detect`.

    The attitude is :func:`random_attitude` ``(seed, index)`` at mid-exposure; the body turns
    at ``cond.rate_deg_s`` about a random axis (camera frame) during ``cond.exposure_s``, so
    every star is a streak of rate × exposure. ``catalog``'s stars are rendered (the visible
    set, as for synthetic frames) and the detections — all of them, brightest first — are
    the centroid list; ``detect`` runs with ``max_elongation=None`` because streaks are the
    point of the condition (its default rejects blobs longer than 3:1 as satellite trails).
    A detection within 3 px of a star's mid-exposure position is that star (``cat_ids``).

    >>> from adfusion import starid
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=5.0, epoch=2025.0)
    >>> cam = starid.Camera.pinhole(256, 192, fov_x_deg=15.0)
    >>> f = render_frame_for(cat, cam, Condition("r", rate_deg_s=1.0), seed=0, index=3)
    >>> f.n_true >= 1, f.xy.shape[1]
    (True, 2)
    """
    from scipy.spatial import cKDTree

    from adfusion import starid
    from adfusion.sensors.render import SensorModel, render_frame

    if cond.n_false or cond.drop_frac:  # (sigma_px only tells the solvers what to expect)
        raise ValueError(f"{cond.name}: a rendered condition takes no synthetic perturbations")
    q = random_attitude(seed, index)
    rng = np.random.default_rng([seed, index, _cond_key(cond.name)])
    axis = rng.normal(size=3)
    omega = np.radians(float(cond.rate_deg_s or 0.0)) * axis / np.linalg.norm(axis)
    fr = render_frame(camera, q, catalog.vectors, catalog.mag, SensorModel(**RENDER_SENSOR),
                      seed=int(rng.integers(2**31)), omega_cam_rad_s=omega,
                      exposure_s=cond.exposure_s)
    det = starid.detect(fr.image, camera, max_elongation=None)
    xy = np.asarray(det.xy, dtype=np.float64).reshape(-1, 2)
    ids = np.full(len(xy), -1, np.int64)
    if len(xy) and len(fr.star_xy):
        d, j = cKDTree(fr.star_xy).query(xy, distance_upper_bound=3.0)
        hit = np.isfinite(d)
        ids[hit] = np.asarray(catalog.ids, dtype=np.int64)[fr.star_index[j[hit]]]
    return Frame(cond.name, index, q, xy, ids, len(fr.star_xy), seed, omega, cond.exposure_s)


def camera_for(cond: Condition, width: int, height: int, fov_deg: float = 15.0):
    """The pinhole camera of a condition (its ``fov_deg``, else ``fov_deg``).

    >>> round(camera_for(Condition("x", fov_deg=20.0), 1024, 768).fov_x_deg, 9)
    20.0
    """
    from adfusion import starid
    fov = fov_deg if cond.fov_deg is None else cond.fov_deg
    return starid.Camera.pinhole(width, height, fov_x_deg=float(fov))


# --- frame model and catalogue -----------------------------------------------------------


@dataclass
class FrameModel:
    """The synthetic camera, sky and scoring every benchmark frame comes from — one set
    of defaults for ``bench starid`` (:class:`BenchConfig`) and ``bench sweep``."""

    seed: int = 0
    width: int = 1024
    height: int = 768
    fov_deg: float = 15.0
    mag_limit: float = 6.0
    sigma_px: float = 0.1
    mag_noise: float = 0.1
    tol_px: float = 5.0
    tol_sigma: float = 4.0
    epoch: float = 2025.0


_CATALOGS: dict[tuple[float, float], Any] = {}


def load_catalog(mag_limit: float, epoch: float):
    from adfusion.starid.catalog.stars import Catalog

    key = (mag_limit, epoch)
    if key not in _CATALOGS:
        _CATALOGS[key] = Catalog.hipparcos(mag_limit=mag_limit, epoch=epoch)
    return _CATALOGS[key]
