"""Prepare every compiled kernel now: ``python -m adfusion.starid.prepare``.

It compiles the lost-in-space, tracking and windowed-detection kernels into numba's
on-disk cache (or loads them), so that the first solve of every later process does not
wait for a compiler. A wheel's build (``pip install .``) runs it and ships the entries in
the package (:func:`adfusion.starid.jit_cache.export`); it is for editable installs and
for a wheel built on another CPU or with another numba or numpy.

Example (loads from the cache once prepared; compiles the first time)::

    >>> from adfusion.starid.prepare import prepare
    >>> prepare() > 0  # doctest: +SKIP
    True
"""

from __future__ import annotations


def prepare() -> float:
    """Compile every kernel a solve uses now — lost-in-space, tracking
    (:mod:`starid.tracking.kernels`) and the tracking windows' centroiding
    (:mod:`starid.detection.window_kernels`) — into numba's on-disk cache, and return the seconds
    it took: run once after an editable install (``python -m
    adfusion.starid.prepare``), and the first solve of every later process loads the
    compiled code (~1 s) instead of compiling it (60–120 s). The cache is keyed by the
    source's content (SHA-256), the numba version and the CPU, so it stays valid until
    one of them changes (docs/decisions.md, "First use")."""
    import time

    from adfusion.starid.camera.model import Camera
    from adfusion.starid.catalog.stars import Catalog
    from adfusion.starid.solver import Solver

    t0 = time.perf_counter()
    solver = Solver(Catalog.hipparcos(mag_limit=5.0), Camera.pinhole(1024, 768, 15.0),
                    cache=False)
    solver.warm_up()
    solver.warm_up_tracking()
    return time.perf_counter() - t0


if __name__ == "__main__":
    # the kernels of the imported modules (not this __main__ copy) are the ones cached
    from adfusion.starid import prepare as _prepare

    print(f"adfusion.starid.prepare: compiled code ready in {_prepare.prepare():.1f} s")
