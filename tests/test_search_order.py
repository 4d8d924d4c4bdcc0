"""The 3-star combination order after a failed Not-Modus (starid.identify.search_order)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from adfusion.starid.identify.search_order import combination_order


def _notmodus(n_det: int, n: int = 6) -> list[tuple[int, ...]]:
    """The patterns the solver tries before the combinations (main, sub-patterns, swaps)."""
    base = tuple(range(min(n, n_det)))
    pats = [base]
    for k in (len(base) - 1, len(base) - 2):
        pats += list(itertools.combinations(base, k))
    for extra in range(len(base), min(n_det, 2 * len(base))):
        pats += [tuple(sorted((set(base) - {out}) | {extra})) for out in base]
    return [p for p in pats if len(p) >= 3]


@pytest.mark.parametrize("n_det", [3, 5, 8, 12, 20, 30])
def test_order_is_every_triple_once(n_det):
    order = combination_order(n_det, _notmodus(n_det))
    assert sorted(order) == list(itertools.combinations(range(n_det), 3))


def test_after_one_failure_a_disjoint_triple_comes_first():
    # P(clean | (0,1,2) held a false object) is (1 − f)³ for a triple sharing none of its
    # stars and less for one sharing any: the brightest disjoint triple must lead
    order = combination_order(10, [(0, 1, 2)])
    assert order[0] == (3, 4, 5)
    assert not set(order[0]) & {0, 1, 2}
    # with no failure at all, the brightest triple leads (ties go to brightness)
    assert combination_order(10, [])[0] == (0, 1, 2)


def test_first_clean_triple_found_sooner_than_by_faintest_member():
    # frames with false objects (each detection false with probability 0.35) that reach
    # the combination stage: every Not-Modus pattern held a false object
    rng = np.random.default_rng(7)
    n_det = 20
    nm = _notmodus(n_det)
    order = combination_order(n_det, nm)
    by_faintest = [(*h, last) for last in range(2, n_det)
                   for h in itertools.combinations(range(last), 2)]
    ranks_new, ranks_old = [], []
    while len(ranks_new) < 300:
        true = rng.random(n_det) >= 0.35
        if any(true[list(p)].all() for p in nm) or true.sum() < 3:
            continue  # Not-Modus would have succeeded, or no clean triple exists
        ranks_new.append(next(r for r, t in enumerate(order) if true[list(t)].all()))
        ranks_old.append(next(r for r, t in enumerate(by_faintest) if true[list(t)].all()))
    assert np.mean(ranks_new) < 0.5 * np.mean(ranks_old)
    assert np.percentile(ranks_new, 90) < np.percentile(ranks_old, 90)
