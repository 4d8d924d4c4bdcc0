"""The compiled (numba) kernels of lost-in-space identification, as one name space.

The code lives in four modules by concern: :mod:`.match_kernels` (a pattern's catalogue
assignments), :mod:`.check_kernels` (quick checks, the sky map, the chance of a match),
:mod:`.search_kernels` (the walk of a frame's pattern list) and :mod:`.fit_kernels`
(Wahba fits, a candidate's verification, the final refit); this module re-exports them so
that callers and tests name one module.

Why compiled code: a lost-in-space frame with false stars among the brightest tries
~90–200 patterns (Renken's Not-Modus, then every 3-star combination). In numpy a trial
cost ~170–230 µs, almost all of it per-call overhead spread over many small operations
(pattern windows, window look-ups, a few 3×3 SVDs, a KD-tree query of ~20 points, the
false-match bookkeeping), not arithmetic. Compiled, a trial costs ~15–25 µs (the match,
bound by the ~10³ catalogue pairs in each window) plus ~2.5 µs per candidate checked, and
:func:`search` walks a frame's whole pattern list in one call. With the catalogue's
triangles looked up instead of scanned (:mod:`starid.catalog.triangle_index`) and the sky map
sparing the association its empty sky (:func:`sky_map`), a trial of a noise frame costs
~6 µs of matching and ~10 µs of checking. Measured (thread time,
this 2-core machine, 300 benchmark frames, Hipparcos V ≤ 6, 15° field): p95 per solve
with 8 false stars 16–20 ms → 2.4–3.1 ms, clean median 0.9 → 0.5 ms.

The functions compute what the numpy reference computes (:func:`starid.identify.nstar.
match_indexed`, the solver's quick check with :mod:`starid.identify.verify`'s chance estimate) —
the same rows in the same order, the same decisions; tests compare them on random
patterns. A candidate's full verification (:func:`verify_candidate`) and the final refit
(:func:`refine_pinhole`) are compiled too, equal to :mod:`starid.identify.verify` and
:mod:`starid.identify.refine` to rounding (docs/decisions.md). Compiled on first use and cached on
disk (:func:`starid.jit_cache.njit_cached`, keyed by this file's content and that of the
modules it compiles in): the first process after an install or
an edit spends 15–60 s compiling (once) unless :func:`adfusion.starid.prepare.prepare`
(``python -m adfusion.starid.prepare``) did it, later ones ~1 s loading.

``ix`` below is :func:`index_arrays` of a :class:`starid.catalog.pair_index.PatternIndex`.

Example:
    >>> from adfusion.starid.identify.kernels import binomial_tail
    >>> round(binomial_tail(3, 10, 0.01), 6)  # P(X ≥ 3), X ~ Binomial(10, 0.01): as scipy
    0.000114
"""

from adfusion.starid.identify.check_kernels import (
    _COARSE_SHIFT,
    _FACE_Z_MIN,
    SKY_CELLS,
    _bit,
    _chance,
    _crossing_sin,
    _face_bin,
    _nearest,
    _nearest_in,
    _rotation,
    _set_bit,
    _sky_bits,
    _sky_cell,
    _sky_marked,
    _spot_geometry,
    binomial_tail,
    quick_checks,
    sky_map,
)
from adfusion.starid.identify.fit_kernels import (
    _covariance,
    _final_fit,
    _inverse_information,
    _matrix_of,
    _median_of_squares,
    _no_fit,
    _noise,
    _not_verified,
    _pair_directions,
    _pixel_direction,
    _quaternion_of,
    _to_pixels,
    _to_vectors,
    _to_vectors_of,
    _wahba,
    _wahba_at,
    refine_pinhole,
    verify_candidate,
)
from adfusion.starid.identify.match_kernels import (
    _CELL_MARGIN,
    _COS_MARGIN,
    _ROWS,
    _SLACK,
    DONE,
    NOTE_NONE,
    NOTE_PATTERNS,
    NOTE_WORK,
    PAIR_BINS,
    SEARCH_START,
    STRONG,
    TRIANGLES_KEPT_MAX,
    _angle_window,
    _bracket,
    _cos_deviation,
    _cross_norm,
    _dot,
    _extended,
    _first_at_most,
    _first_below,
    _grown,
    _in_scan_order,
    _looked_up,
    _mirror_ok,
    _near_tie,
    _pair_window,
    _prefetch,
    _quanta_in,
    _row_before,
    _stored_cos,
    _triangles,
    _triangles_looked_up,
    chirality,
    index_arrays,
    match,
    pair_bins,
    scratch,
    with_triangles,
)
from adfusion.starid.identify.search_kernels import (
    _closest_pair_first,
    _window,
    pair_windows,
    pattern_windows,
    pattern_windows_kept,
    search,
    triangle_store,
)

# every name, the private ones too: the tests compare them with the numpy reference
__all__ = [
    "DONE",
    "NOTE_NONE",
    "NOTE_PATTERNS",
    "NOTE_WORK",
    "PAIR_BINS",
    "SEARCH_START",
    "SKY_CELLS",
    "STRONG",
    "TRIANGLES_KEPT_MAX",
    "_CELL_MARGIN",
    "_COARSE_SHIFT",
    "_COS_MARGIN",
    "_FACE_Z_MIN",
    "_ROWS",
    "_SLACK",
    "_angle_window",
    "_bit",
    "_bracket",
    "_chance",
    "_closest_pair_first",
    "_cos_deviation",
    "_covariance",
    "_cross_norm",
    "_crossing_sin",
    "_dot",
    "_extended",
    "_face_bin",
    "_final_fit",
    "_first_at_most",
    "_first_below",
    "_grown",
    "_in_scan_order",
    "_inverse_information",
    "_looked_up",
    "_matrix_of",
    "_median_of_squares",
    "_mirror_ok",
    "_near_tie",
    "_nearest",
    "_nearest_in",
    "_no_fit",
    "_noise",
    "_not_verified",
    "_pair_directions",
    "_pair_window",
    "_pixel_direction",
    "_prefetch",
    "_quanta_in",
    "_quaternion_of",
    "_rotation",
    "_row_before",
    "_set_bit",
    "_sky_bits",
    "_sky_cell",
    "_sky_marked",
    "_spot_geometry",
    "_stored_cos",
    "_to_pixels",
    "_to_vectors",
    "_to_vectors_of",
    "_triangles",
    "_triangles_looked_up",
    "_wahba",
    "_wahba_at",
    "_window",
    "binomial_tail",
    "chirality",
    "index_arrays",
    "match",
    "pair_bins",
    "pair_windows",
    "pattern_windows",
    "pattern_windows_kept",
    "quick_checks",
    "refine_pinhole",
    "scratch",
    "search",
    "sky_map",
    "triangle_store",
    "verify_candidate",
    "with_triangles",
]
