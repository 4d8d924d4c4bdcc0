"""First use (issue 37): the kernels a wheel ships compiled (``adfusion/starid/_jit``,
``_backend/adfusion_build.py``) serve a process with an empty numba cache, so its first
solve loads them instead of compiling for a minute — and solves the frame as before."""

from __future__ import annotations

import json
import math
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numba
import pytest
from adfusion.starid import jit_cache

REPO = Path(__file__).resolve().parents[1]
FRAME = "2019-07-29T204726_Alt40_Azi-135_Try1"


def _angle_deg(ra1: float, dec1: float, ra2: float, dec2: float) -> float:
    r1, d1, r2, d2 = map(math.radians, (ra1, dec1, ra2, dec2))
    c = math.sin(d1) * math.sin(d2) + math.cos(d1) * math.cos(d2) * math.cos(r1 - r2)
    return math.degrees(math.acos(min(1.0, c)))


@pytest.mark.shared
def test_a_fresh_cache_solves_a_real_frame_with_the_shipped_kernels(tmp_path, shared_dir):
    """What ``pip install .`` ships — the cache entries :func:`jit_cache.export` writes
    after ``prepare()`` — loaded by ``adfusion solve FRAME --fov 11.4`` in a fresh
    process with empty caches: it compiles nothing (numba saves no entry) and the
    attitude is the astrometry.net one. Without the shipped entries, numba compiled the
    whole lost-in-space search in that process (~1 min here)."""
    prebuilt = tmp_path / "prebuilt"
    code = ("import sys\n"
            "from adfusion.starid import jit_cache, prepare\n"
            "from adfusion.estimation import mekf_kernels\n"
            "prepare.prepare(); mekf_kernels.warm_up()\n"
            "print(jit_cache.export(sys.argv[1]))\n")
    p = subprocess.run([sys.executable, "-P", "-c", code, str(prebuilt)], capture_output=True,
                       text=True, timeout=600, check=False)
    assert p.returncode == 0, p.stderr
    assert int(p.stdout.split()[-1]) > 10  # the search's, tracking's and windows' kernels

    frames = shared_dir / "data" / "real-images"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "ADFUSION_CACHE_DIR": str(tmp_path / "adfusion"),
           "ADFUSION_JIT_PREBUILT": str(prebuilt), "NUMBA_DEBUG_CACHE": "1"}
    p = subprocess.run([sys.executable, "-P", "-m", "adfusion", "solve",
                        str(frames / f"{FRAME}.tiff"), "--fov", "11.4", "--json"],
                       capture_output=True, text=True, timeout=600, check=False, env=env,
                       cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    log = [ln for ln in p.stdout.splitlines() if ln.startswith("[cache]")]
    saved = [ln for ln in log if "saved to" in ln]
    assert not saved, saved[:5]  # nothing compiled
    assert any("data loaded from" in ln and str(tmp_path / "numba") in ln for ln in log)

    out = json.loads("\n".join(ln for ln in p.stdout.splitlines()
                               if not ln.startswith("[cache]")))
    truth = json.loads((frames / "truth.json").read_text())[FRAME]
    assert out["ok"], out
    assert _angle_deg(out["ra_deg"], out["dec_deg"], truth["ra_center_deg"],
                      truth["dec_center_deg"]) < 0.01


def test_entries_of_other_sources_are_not_copied(tmp_path, monkeypatch):
    """A shipped index whose stamp is not this process's (another source, numpy or
    numba) is left where it is: numba would not load it, and it must not replace a
    current one."""
    from adfusion.starid.camera import projection_kernels

    locator = projection_kernels.predict_pinhole._cache._impl.locator
    name = projection_kernels.predict_pinhole._cache._cache_file._index_name
    src = tmp_path / "prebuilt" / locator._module
    src.mkdir(parents=True)
    with open(src / name, "wb") as f:
        pickle.dump(numba.__version__, f)
        f.write(pickle.dumps((("another", "stamp"), {})))
    target = tmp_path / "cache"
    target.mkdir()
    twin = jit_cache._DependsLocator(locator._inner, locator._py_file, locator._module)
    twin.get_cache_path = lambda: str(target)  # type: ignore[method-assign]
    monkeypatch.setenv("ADFUSION_JIT_PREBUILT", str(tmp_path / "prebuilt"))
    assert jit_cache.seed(twin) == 0
    assert list(target.iterdir()) == []
