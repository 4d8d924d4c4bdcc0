"""First use of `adfusion solve FRAME --fov 11.4`: the cold call's wall time and what it
costs the hot path, for numba's optimisation levels (issue 37, "First use").

``cold``: each variant runs ``python -P -m adfusion solve FRAME --fov 11.4`` in a fresh
process against an empty numba cache (``NUMBA_CACHE_DIR``) and one catalogue cache filled
beforehand (``ADFUSION_CACHE_DIR``: the catalogue and its index are not what is measured);
the variants take turns, ``--runs`` rounds, so that a loaded machine slows all of them
alike. ``profile``: one cold solve in this process (an empty numba cache of its own), with
numba's compile events recorded: the seconds of each kernel's own compilation (its callees'
left out) and of each compiler pass. ``warm``: each variant's cache, once filled, serves a
process that times the
lost-in-space solve of the real frames' detections (the median of ``--reps`` passes over
all of them, µs a frame), again in turns. ``--variants`` lists environment settings, one
variant each (``-`` is the default, ``NUMBA_OPT=0`` …; ``+`` joins two; ``PYTHON=PATH``
runs that interpreter instead, e.g. a venv's that ``pip install .`` filled).

Usage (from the repository root)::

    python -P benchmarks/first_use.py cold --runs 2 --variants=-,NUMBA_OPT=0,NUMBA_OPT=1
    python -P benchmarks/first_use.py warm --runs 3 --variants=-,NUMBA_OPT=0,NUMBA_OPT=1
    python -P benchmarks/first_use.py profile

Example:
    >>> _env_of("NUMBA_OPT=0")
    {'NUMBA_OPT': '0'}
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FRAMES = Path(os.environ.get("ADFUSION_SHARED", ROOT.parent / "shared")) / "data" / "real-images"
DEFAULT_FRAME = FRAMES / "2019-07-29T204726_Alt40_Azi-135_Try1.tiff"

# the hot path in a process of its own: every real frame's detections, solved --reps times
_WARM = r"""
import statistics, sys, time, numpy as np
from pathlib import Path
from adfusion import starid
from adfusion.starid.detection.image import read_image
frames, reps = sorted(Path(sys.argv[1]).glob("*.tiff")), int(sys.argv[2])
solver = None
xys = []
for p in frames:
    img = read_image(p)
    xys.append(np.ascontiguousarray(starid.detect(img).xy))
cam = starid.Camera.pinhole(img.shape[1], img.shape[0], 11.4)
from adfusion.starid.catalog.coverage import DEFAULT_STARS_PER_FOV, catalog_for_camera
cat = catalog_for_camera(starid.Catalog.hipparcos(mag_limit=6.5), cam, DEFAULT_STARS_PER_FOV)
solver = starid.Solver(cat, cam)
solver.warm_up(triangles=False)
ok = [solver.solve(xy).ok for xy in xys]
per = []
for _ in range(reps):
    t0 = time.perf_counter()
    for xy in xys:
        solver.solve(xy)
    per.append((time.perf_counter() - t0) / len(xys) * 1e6)
print(sum(ok), statistics.median(per))
"""


def _env_of(variant: str) -> dict[str, str]:
    """The environment settings of a variant (``-``: none)."""
    if variant == "-":
        return {}
    return dict(kv.split("=", 1) for kv in variant.split("+"))


def _run(cmd: list[str], env: dict[str, str]) -> tuple[float, subprocess.CompletedProcess]:
    env = dict(env)
    cmd = [env.pop("PYTHON", cmd[0]), *cmd[1:]]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env={**os.environ, **env}, capture_output=True, text=True,
                       check=False, cwd=tempfile.gettempdir())
    return time.perf_counter() - t0, p


def cold(variants: list[str], runs: int, frame: Path) -> dict[str, list[float]]:
    """Wall seconds of a cold ``adfusion solve FRAME --fov 11.4`` per variant and run."""
    solve = [sys.executable, "-P", "-m", "adfusion", "solve", str(frame), "--fov", "11.4"]
    with tempfile.TemporaryDirectory() as tmp:
        catalogue = {"ADFUSION_CACHE_DIR": str(Path(tmp) / "adfusion")}
        # the catalogue's cache, filled once (its numba cache is thrown away)
        _run(solve, {**catalogue, "NUMBA_CACHE_DIR": str(Path(tmp) / "fill")})
        out: dict[str, list[float]] = {v: [] for v in variants}
        for r in range(runs):
            for v in variants:
                env = {**catalogue, "NUMBA_CACHE_DIR": str(Path(tmp) / f"n{r}-{v}"),
                       **_env_of(v)}
                dt, p = _run(solve, env)
                if p.returncode != 0 or "identification ok" not in p.stdout:
                    raise SystemExit(f"{v}: {p.stdout[-500:]}{p.stderr[-2000:]}")
                out[v].append(round(dt, 1))
                print(f"cold {v}: {dt:.1f} s", file=sys.stderr)
    return out


def warm(variants: list[str], runs: int, reps: int) -> dict[str, list[float]]:
    """µs a frame of the warm lost-in-space solve per variant and run."""
    cmd = [sys.executable, "-P", "-c", _WARM, str(FRAMES), str(reps)]
    with tempfile.TemporaryDirectory() as tmp:
        envs = {v: {"NUMBA_CACHE_DIR": str(Path(tmp) / f"n-{v}"), **_env_of(v)}
                for v in variants}
        for v in variants:  # fill each variant's cache
            _run([*cmd[:-1], "1"], envs[v])
        out: dict[str, list[float]] = {v: [] for v in variants}
        for _ in range(runs):
            for v in variants:
                _, p = _run(cmd, envs[v])
                if p.returncode != 0:
                    raise SystemExit(f"{v}: {p.stderr[-2000:]}")
                n_ok, us = p.stdout.split()
                out[v].append(round(float(us), 1))
                print(f"warm {v}: {float(us):.1f} µs a frame ({n_ok} ok)", file=sys.stderr)
    return out


def profile(frame: Path, top: int = 12) -> dict[str, object]:
    """One cold ``adfusion solve FRAME --fov 11.4`` in this process, numba's compile events
    recorded: seconds of each dispatcher's own compilation and of each compiler pass (both
    without what nests inside), the top-level compilations, and the wall seconds."""
    import collections
    import contextlib
    import io

    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp()  # before numba reads its config
    from numba.core import event

    own: dict[str, float] = collections.defaultdict(float)
    passes: dict[str, float] = collections.defaultdict(float)
    stack: list[list] = []  # [kind, name, start, seconds of what nests inside]
    roots: list[tuple[str, float]] = []

    class Listener(event.Listener):
        def on_start(self, ev):
            d = ev.data or {}
            if ev.kind == "numba:compile":
                f = getattr(d.get("dispatcher"), "py_func", None)
                name = f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', '?')}"
            else:
                name = str(d.get("name", "")).split(" [")[0]
            stack.append([ev.kind, name, time.perf_counter(), 0.0])

        def on_end(self, ev):
            if not stack:
                return
            kind, name, t0, inner = stack.pop()
            dt = time.perf_counter() - t0
            (own if kind == "numba:compile" else passes)[name] += dt - inner
            outer = next((fr for fr in reversed(stack) if fr[0] == kind), None)
            if outer is not None:
                outer[3] += dt
            elif kind == "numba:compile":
                roots.append((name, round(dt, 2)))

    listener = Listener()
    for kind in ("numba:compile", "numba:run_pass"):
        event.register(kind, listener)
    from adfusion.app.cli import main as cli

    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        cli(["solve", str(frame), "--fov", "11.4"])
    wall = time.perf_counter() - t0

    def ranked(d: dict[str, float]) -> dict[str, float]:
        return {k: round(v, 2) for k, v in sorted(d.items(), key=lambda kv: -kv[1])[:top]}

    return {"wall_s": round(wall, 1), "compile_s": round(sum(own.values()), 1),
            "top_level": roots, "own_s": ranked(own), "passes_s": ranked(passes)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=("cold", "warm", "profile"))
    ap.add_argument("--variants", default="-,NUMBA_OPT=0")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--reps", type=int, default=200, help="warm: passes over the frames")
    ap.add_argument("--frame", type=Path, default=DEFAULT_FRAME)
    a = ap.parse_args(argv)
    variants = a.variants.split(",")
    if a.mode == "profile":
        print(json.dumps({"mode": "profile", "machine": platform.node(),
                          "cpus": os.cpu_count(), **profile(a.frame)}, indent=1))
        return 0
    res = (cold(variants, a.runs, a.frame) if a.mode == "cold"
           else warm(variants, a.runs, a.reps))
    summary = {v: {"runs": xs, "median": statistics.median(xs)} for v, xs in res.items()}
    print(json.dumps({"mode": a.mode, "machine": platform.node(), "cpus": os.cpu_count(),
                      "results": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
