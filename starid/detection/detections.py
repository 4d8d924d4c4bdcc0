"""What detection returns: :class:`Detections` (centroids brightest first, with their
fluxes, shapes and the frame's noise) and the :class:`Rejection` of a blob.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

__all__ = ["Detections", "Rejection"]


_CENTROIDS = ("weighted", "unweighted")


class Rejection(NamedTuple):
    """One blob that was found above threshold and then rejected.

    Example:
        >>> r = Rejection(12.0, 40.0, 1, "hot_pixel")
        >>> r.reason, tuple(r)
        ('hot_pixel', (12.0, 40.0, 1, 'hot_pixel'))
    """

    x: float
    y: float
    area: int
    reason: str


@dataclass(frozen=True, eq=False, repr=False)
class Detections:
    """Stars found in one frame, brightest first.

    Attributes:
        xy: (N, 2) float64 centroids, pixel-centre convention (x right, y down).
        flux: (N,) background-subtracted summed intensity (raw sum with a fixed ``threshold``).
        area: (N,) number of pixels above threshold.
        peak: (N,) highest background-subtracted pixel value.
        ok: False when Renken's image-quality check failed (then N = 0).
        reason: why not ok; ``""`` when ok.
        rejected: one `Rejection` (x, y, area, reason) per rejected blob; the reason is the
            first that applies of "too_large", "hot_pixel", "too_small", "saturated",
            "elongated".
        background_level: median of the background map (0 with a fixed ``threshold``).
        noise_sigma: median of the noise map (NaN with a fixed ``threshold``).
        shape: image (height, width).
        bright_pixels: number of pixels above threshold (Renken's ``number_hlp``).
        noise_model: how the noise was estimated: ``"lower-half"`` (median − P15.87 of
            the background-subtracted pixels), ``"censored"`` (some blocks' dark tail is
            clipped at the black level: the noise from the quantiles above the clip),
            ``"fixed-threshold"``; ``"+matched-filter"`` when the frame was smoothed with
            the PSF before thresholding.

    Example:
        >>> d = Detections(np.array([[1.0, 2.0]]), np.array([50.0]), np.array([3]),
        ...                np.array([20.0]), True, "", [], 10.0, 1.0, (8, 8))
        >>> len(d), d.as_array().tolist()
        (1, [[1.0, 2.0, 50.0]])
        >>> d
        Detections(1 stars, ok, 0 rejected, background 10, noise 1, shape (8, 8))
    """

    xy: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    ok: bool
    reason: str
    rejected: list[Rejection]
    background_level: float
    noise_sigma: float
    shape: tuple[int, int]
    bright_pixels: int = field(default=0)
    noise_model: str = field(default="lower-half")

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def __repr__(self) -> str:
        state = "ok" if self.ok else f"not ok: {self.reason}"
        return (f"Detections({len(self)} stars, {state}, {len(self.rejected)} rejected, "
                f"background {self.background_level:.4g}, noise {self.noise_sigma:.4g}, "
                f"shape {self.shape})")

    def as_array(self) -> np.ndarray:
        """(N, 3) array of x, y, flux — the input format of ``Solver.solve``.

        Example:
            >>> Detections.empty((4, 4)).as_array().shape
            (0, 3)
        """
        return np.column_stack([self.xy, self.flux]) if len(self) else np.empty((0, 3))

    @classmethod
    def empty(
        cls,
        shape: tuple[int, int],
        *,
        ok: bool = True,
        reason: str = "",
        rejected: list[Rejection] | None = None,
        background_level: float = float("nan"),
        noise_sigma: float = float("nan"),
        bright_pixels: int = 0,
        noise_model: str = "lower-half",
    ) -> Detections:
        """No detections (a failed quality check, or an empty sky).

        Example:
            >>> len(Detections.empty((480, 512), ok=False, reason="too many bright pixels"))
            0
        """
        return cls(
            np.empty((0, 2)),
            np.empty(0),
            np.empty(0, dtype=np.int64),
            np.empty(0),
            ok,
            reason,
            [] if rejected is None else rejected,
            background_level,
            noise_sigma,
            shape,
            bright_pixels,
            noise_model,
        )
