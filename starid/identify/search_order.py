"""The order in which 3-star combinations are tried after Renken's Not-Modus has failed.

A frame reaches the combination stage when the main pattern, all its (n−1)- and
(n−2)-star sub-patterns and the swaps have failed: several of the brightest detections
are false objects (or dropped stars left too few true ones among them). Trying the
3-star combinations by their faintest member — (0, 1, 2), (0, 1, 3), (0, 2, 3), … —
spends most trials on combinations that share the detections every failed pattern
already made suspect: with 8 false stars among ~20 detections the first clean triple
came after a median of 15 combinations (p90 35).

Every failed pattern says "at least one of these detections is false". With each
detection false independently with probability ``p_false_object``, the chance that a
triple is clean given all those failures is a sum over the 2^M false/true labellings of
the ``M`` brightest detections that are consistent with them. Trying next the triple with
the highest such chance — a failure of it is one more observation — gives a fixed
sequence, since the solver only goes on after failures. On the benchmark's frames
(``adfusion bench starid``, 1000 per condition, true/false labels from the truth) this finds
the first clean triple after a median of 2 combinations (p90 10) with 8 false stars and
after 1 (p90 2) with 30 % dropped + 3 false; the prior's value (0.2–0.4) hardly matters.

The order is a pure function of the detection count and the patterns already tried, so it
is computed once per count (a few ms) and kept. Triples beyond the ``M`` brightest follow
in the old faintest-member order. Correctness does not depend on the order: every
combination is still tried until the budget, and ``p_false`` counts every trial.

Example:
    >>> order = combination_order(8, [(0, 1, 2, 3, 4, 5)])
    >>> len(order) == 56 and len(set(order)) == 56
    True
    >>> 0 in order[0] and 5 in order[0]  # neither alone is suspect after one failure
    False
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["combination_order"]

#: Detections whose false/true labellings are enumerated (2^12 = 4096 labellings).
M_BRIGHTEST = 12
#: Prior chance that a detection is a false object (the order barely depends on it).
P_FALSE_OBJECT = 0.3


def combination_order(n_det: int, failed: Sequence[Sequence[int]],
                      m_brightest: int = M_BRIGHTEST,
                      p_false_object: float = P_FALSE_OBJECT) -> list[tuple[int, ...]]:
    """Every 3-star combination of ``n_det`` detections (sorted index tuples), most
    probably clean first given that every pattern in ``failed`` held a false object.

    Ties go to the brighter triple (lower faintest member, then lower index sum).
    """
    key = tuple(sorted({tuple(sorted(p)) for p in failed}))
    return list(_order(int(n_det), key, int(m_brightest), float(p_false_object)))


@lru_cache(maxsize=64)
def _order(n_det: int, failed: tuple[tuple[int, ...], ...], m_brightest: int,
           p_false_object: float) -> tuple[tuple[int, ...], ...]:
    by_faintest = [(*h, last) for last in range(2, n_det)
                   for h in itertools.combinations(range(last), 2)]
    m = min(m_brightest, n_det)
    if m < 3:
        return tuple(by_faintest)
    # only failures among the m brightest say anything about them: every detection
    # count from m up shares one computation (the solver's Not-Modus patterns reach
    # index 11, so counts ≥ 12 differ only in the tail)
    inside = tuple(p for p in failed if max(p) < m)
    order = _most_probably_clean(m, inside, p_false_object)
    seen = set(order)
    return order + tuple(t for t in by_faintest if t not in seen)


@lru_cache(maxsize=64)
def _most_probably_clean(m: int, failed: tuple[tuple[int, ...], ...],
                         p_false_object: float) -> tuple[tuple[int, ...], ...]:
    """The greedy sequence over the triples of ``m`` detections (module docstring)."""
    triples = list(itertools.combinations(range(m), 3))
    labels = np.arange(1 << m)  # bit i set: detection i is false
    false_count = ((labels[:, None] >> np.arange(m)) & 1).sum(axis=1)
    weight = p_false_object ** false_count * (1.0 - p_false_object) ** (m - false_count)
    for p in failed:
        weight[(labels & _mask(p)) == 0] = 0.0  # that pattern would have been clean
    masks = np.array([_mask(t) for t in triples])
    clean = (labels[:, None] & masks[None, :]) == 0  # (labellings, triples)
    score = weight @ clean
    brightness = np.array([(max(t), sum(t)) for t in triples])
    rank = np.lexsort((brightness[:, 1], brightness[:, 0]))  # brighter first on ties
    tried = np.zeros(len(triples), dtype=bool)
    order: list[tuple[int, ...]] = []
    while True:
        live = np.where(tried, -1.0, score)[rank]
        best = live.max() if len(live) else -1.0
        if best <= 0.0:
            break
        k = int(rank[np.argmax(live >= best * (1.0 - 1e-9))])
        order.append(triples[k])
        tried[k] = True
        gone = np.flatnonzero(clean[:, k] & (weight > 0))  # labellings this failure rules out
        score -= weight[gone] @ clean[gone]
        weight[gone] = 0.0
    return tuple(order)


def _mask(idx: Sequence[int]) -> int:
    return sum(1 << int(i) for i in idx)


def patterns(n_det: int, n_min: int, n_max: int) -> Iterator[tuple[tuple[int, ...], str]]:
    """Patterns (detection indices, brightest first) and their paths, in the fixed order
    tried: Renken's main pattern, his Not-Modus ((n−1)- and (n−2)-star sub-patterns, then
    fainter detections swapped in), then — our extension for frames with several false
    objects among the brightest — every 3-star combination, the most probably clean first
    given the failures so far (:func:`combination_order`), then every 4-star one by its
    faintest member. Verification against all other detections is what makes a 3-star
    pattern trustworthy.

    Example:
        >>> [path for _, path in itertools.islice(patterns(6, 3, 4), 3)]
        ['n=4', 'not-modus 3-of-4: 0, 1, 2', 'not-modus 3-of-4: 0, 1, 3']
    """
    seen: set[tuple[int, ...]] = set()
    yield from renken_patterns(n_det, n_min, n_max, seen)

    # 3-star patterns first: among false objects they are more often clean; most
    # probably clean first, given that every pattern so far held a false object
    if n_min <= 3:
        for pat in combination_order(n_det, list(seen)):
            if _fresh(pat, seen, n_min):
                yield pat, f"combination: {', '.join(map(str, pat))}"
    for last in range(3, n_det):
        for head in itertools.combinations(range(last), 3):
            pat = (*head, last)
            if _fresh(pat, seen, n_min):
                yield pat, f"combination: {', '.join(map(str, pat))}"


def renken_patterns(n_det: int, n_min: int, n_max: int, seen: set[tuple[int, ...]],
                    ) -> Iterator[tuple[tuple[int, ...], str]]:
    """The first part of :func:`patterns`: Renken's main pattern and Not-Modus (adding each
    to ``seen``).

    Example:
        >>> [p for p, _ in renken_patterns(4, 3, 4, set())][:2]
        [(0, 1, 2, 3), (0, 1, 2)]
    """
    n = min(n_max, n_det)
    base = tuple(range(n))

    if _fresh(base, seen, n_min):
        yield base, f"n={n}"
    for k in (n - 1, n - 2):
        # drop the faintest stars first: false objects are more often faint
        for keep in sorted(itertools.combinations(base, k), key=lambda c: sorted(
                set(base) - set(c), reverse=True), reverse=True):
            if _fresh(keep, seen, n_min):
                yield keep, f"not-modus {k}-of-{n}: {', '.join(map(str, keep))}"
    for extra in range(n, min(n_det, 2 * n)):  # the next n fainter detections
        for out in reversed(base):
            pat = tuple(sorted((set(base) - {out}) | {extra}))
            if _fresh(pat, seen, n_min):
                yield pat, f"not-modus swap {extra} for {out}"


def _fresh(p: tuple[int, ...], seen: set[tuple[int, ...]], n_min: int) -> bool:
    """Whether ``p`` is a pattern not yet tried, of at least ``n_min`` (and 3) stars; notes
    it in ``seen``."""
    if p in seen or len(p) < max(n_min, 3):
        return False
    seen.add(p)
    return True


@lru_cache(maxsize=256)
def pattern_arrays(n_det: int, full: bool, max_patterns: int, n_max: int, n_min: int,
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], list[str]]:
    """The patterns of :func:`patterns` for the compiled search — Renken's
    (:func:`renken_patterns`) or, with ``full``, all up to the budget (``max_patterns`` + 1)
    — as detections (P, 8), their counts (P,) and the paths.

    The order is a function of the detection count alone (the search reaches a pattern
    only after every earlier one failed), so each list is computed once per count and kept
    (the combinations' order costs a few ms, paid when a frame first gets there).
    The arrays are shared between solvers: the search only reads them.

    Example:
        >>> pats, counts, paths = pattern_arrays(5, False, 100, 4, 3)
        >>> pats.shape[1], int(counts[0]), paths[0]
        (8, 4, 'n=4')
    """
    it = (patterns(n_det, n_min, n_max) if full
          else renken_patterns(n_det, n_min, n_max, set()))
    pats = list(itertools.islice(it, max_patterns + 1))
    arr = np.zeros((len(pats), 8), dtype=np.int64)
    for r, (p, _) in enumerate(pats):
        arr[r, :len(p)] = p
    counts = np.array([len(p) for p, _ in pats], dtype=np.int64)
    return arr, counts, [path for _, path in pats]
