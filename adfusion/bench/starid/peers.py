"""The solvers of ``adfusion bench starid``: our solver and the peers behind one interface.

:class:`Adapter` is what the run drives (``setup`` per condition, ``solve`` per frame, an
:class:`Outcome` back); the adapters are ours (:func:`solver_for`, memoised per process; with
a tracking prior, :func:`tracking_prior`, or another matcher), ``tetra3rs`` (in this process,
its database cached) and ``cedar-solve`` (in its own venv, :func:`ensure_cedar_venv`, behind a
JSON-lines worker). :func:`make_adapters` builds them by name, :func:`conversion_check` checks
their centroid and attitude conventions on noise-free frames, :func:`peer_match_max_error`
scales the peers' tolerance with the centroid noise, :func:`cache_root` is where the peers'
databases and the cedar venv are kept.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from adfusion.bench.starid.frames import Condition, Frame, _cond_key, load_catalog, make_frame

if TYPE_CHECKING:
    from adfusion.bench.starid.driver import BenchConfig


SOLVER_NAMES = ("ours", "tetra3rs", "cedar")
_CHECK_LIMIT_ARCSEC = 60.0  # a convention slip (½ px, axis swap, roll sign) is ≥ 30″


# --- what a solve returns ----------------------------------------------------------------


@dataclass
class Outcome:
    ok: bool
    q: NDArray[np.float64] | None
    time_s: float
    status: str = ""
    own_time_s: float | None = None  # the solver's self-reported time, if any
    matches: list[tuple[int, int]] | None = None  # (detection, catalogue id), ours only
    covariance: NDArray[np.float64] | None = None  # 3×3 rad², camera frame, ours only
    #: the solve's CPU time (this thread), for solvers running in this process: unlike the
    #: wall time it leaves out what other processes on a loaded machine take
    cpu_s: float | None = None


def peer_match_max_error(sigma_px: float, width: int) -> float | None:
    """``match_max_error`` (edge-ratio tolerance) for the tetra3 family at centroid noise σ.

    Their database defaults (tetra3rs 0.001, cedar 0.002) suit σ ≲ 0.5 px: above that,
    patterns whose edge ratios moved by more than the tolerance are never looked up, and
    too large a tolerance makes every lookup slow. Tuned on 30–40 frames (seed 0, 1024 px)
    to ``5·σ/width`` (0.005 at σ = 1 px, 0.01 at 2 px): tetra3rs σ = 1: default 19/40
    correct, 0.003 39/40, 0.005 40/40; σ = 2: default 2/40, 0.005–0.012 37–38/40; cedar
    σ = 1: default 29/30, 0.005 30/30 (fastest); σ = 2: default 22/30, 0.008–0.012 30/30.
    ``None`` = keep the peer's default.

    >>> peer_match_max_error(0.1, 1024) is None, round(peer_match_max_error(2.0, 1024), 4)
    (True, 0.0098)
    """
    if sigma_px <= 0.5:
        return None
    return 5.0 * sigma_px / width


# --- solver adapters ---------------------------------------------------------------------


class Adapter:
    name = ""

    def setup(self, cond: Condition, camera) -> None:
        """Prepare for a (resolved) condition seen by ``camera``: catalogue, database, …"""

    def solve(self, frame: Frame) -> Outcome:
        raise NotImplementedError

    def info(self) -> dict[str, Any]:
        return {}

    def params(self) -> dict[str, Any]:
        """The settings used for the current condition (recorded per condition)."""
        return {}

    def close(self) -> None:
        pass


SOLVERS: dict[tuple[Any, ...], Any] = {}


def solver_for(mag_limit: float, sigma_px: float, camera, epoch: float = 2025.0,
               method: str = "nstar"):
    """Our :class:`starid.solver.Solver` for a visible limit, centroid σ and camera
    (memoised per process: the tracking and lost-in-space runs share one index).

    ``centroid_sigma_px`` is ``max(0.5, σ)``, as a user would configure a camera;
    ``method`` is the solver's matcher (``nstar``, ``triad``, ``bleif``).
    """
    from adfusion.starid.solver import Solver

    sigma = max(0.5, float(sigma_px))
    key = (float(mag_limit), sigma, camera.width, camera.height, round(camera.fov_x_deg, 9),
           float(epoch), method)
    if key not in SOLVERS:
        SOLVERS[key] = Solver(load_catalog(float(mag_limit), epoch), camera,
                               centroid_sigma_px=sigma, method=method)
    return SOLVERS[key]


class _Ours(Adapter):
    name = "ours"
    method = "nstar"

    def __init__(self, cfg: BenchConfig, camera=None) -> None:
        self.cfg = cfg
        self._builds: dict[str, dict[str, Any]] = {}
        self.solver = None
        self._params: dict[str, Any] = {}

    def setup(self, cond: Condition, camera) -> None:
        from adfusion.starid.catalog.pair_index import PatternIndex

        limit = float(cond.mag_limit if cond.mag_limit is not None else self.cfg.mag_limit)
        s = solver_for(limit, float(cond.sigma_px or 0.0), camera, self.cfg.epoch,
                       self.method)
        base = getattr(self.cfg, "fov_deg", None)
        fov = "" if base is not None and abs(camera.fov_x_deg - base) < 1e-6 else \
            f", FOV {camera.fov_x_deg:.4g}°"
        label = f"V<{limit:g}, sigma={s.centroid_sigma_px:g}px{fov}"
        if label not in self._builds:
            t0 = time.perf_counter()  # the solver may have loaded its index from the cache
            PatternIndex.from_vectors(s.vectors, s.max_sep_rad, cache_tag=None)
            fresh = time.perf_counter() - t0
            self._builds[label] = {
                "catalog_stars": len(s.vectors), "index_build_s": round(s.index_build_s, 4),
                "index_build_fresh_s": round(fresh, 4),
                "index_nbytes": int(s.index.nbytes), "index_pairs": int(s.index.n_pairs)}
        s.warm_up()  # kernels loaded (or compiled) here, not in the first timed frames
        self.solver = s
        self._params = {"catalog": f"hipparcos V<{limit:g}",
                        "centroid_sigma_px": s.centroid_sigma_px}

    def params(self) -> dict[str, Any]:
        return self._params

    def _prior(self, frame: Frame):
        return None

    def solve(self, frame: Frame) -> Outcome:
        assert self.solver is not None
        prior = self._prior(frame)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            sol = self.solver.solve(frame.xy, prior=prior)
        except Exception as e:  # a crash is a finding, not a reason to stop the run
            return Outcome(False, None, time.perf_counter() - t0, f"exception: {e!r}")
        dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
        return Outcome(bool(sol.ok), sol.q_cam_icrs, dt, sol.reason, sol.time_s, sol.matches,
                        sol.covariance, cpu)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "indexes": self._builds}


def tracking_prior(frame: Frame, sigma_deg: float):
    """A filter-like prior for tracking: the true attitude tilted by a random error drawn
    from N(0, σ²) per axis, with that σ (deterministic per seed, frame and condition).
    On a rendered (streaked) frame the prior also carries the exposure's rotation
    (``smear_cam_rad`` = ω·T), as a filter with a gyro knows it.

    >>> from adfusion.bench.starid.frames import random_attitude
    >>> f = Frame("x", 4, random_attitude(0, 4), np.zeros((0, 2)), np.zeros(0, np.int64), 0)
    >>> p = tracking_prior(f, 0.1)
    >>> from adfusion.starid import rotations as rot
    >>> float(np.degrees(rot.angle_between(p.q_cam_icrs, f.q_cam_icrs))) < 0.6, p.sigma_deg
    (True, 0.1)
    """
    from adfusion.maths import rotations as rot
    from adfusion.starid.solver import Prior

    rng = np.random.default_rng([frame.seed, frame.index, _cond_key(frame.condition), 1])
    dtheta = np.radians(sigma_deg) * rng.normal(size=3)
    smear = None
    if frame.omega_cam_rad_s is not None and frame.exposure_s > 0:
        smear = np.asarray(frame.omega_cam_rad_s, dtype=np.float64) * frame.exposure_s
    return Prior(rot.multiply(rot.exp_map(dtheta), frame.q_cam_icrs), float(sigma_deg),
                 smear_cam_rad=smear)


class _OursTracking(_Ours):
    """Ours with a prior (:func:`tracking_prior`): the tracking path, falling back to
    lost-in-space when it fails, as in a filter loop."""

    name = "ours_tracking"

    def __init__(self, cfg, camera=None, sigma_deg: float = 0.1) -> None:
        super().__init__(cfg, camera)
        self.sigma_deg = float(sigma_deg)

    def _prior(self, frame: Frame):
        return tracking_prior(frame, self.sigma_deg)

    def params(self) -> dict[str, Any]:
        return {**self._params, "prior_sigma_deg": self.sigma_deg}


class _OursMethod(_Ours):
    """Ours with another matcher (``Solver(method=...)``): ``ours_triad`` (Yee's triads),
    ``ours_bleif`` (Bleif's MusterPr reference-star patterns) — the same verification."""

    def __init__(self, cfg, camera=None, method: str = "triad") -> None:
        super().__init__(cfg, camera)
        self.method = method
        self.name = f"ours_{method}"

    def params(self) -> dict[str, Any]:
        return {**self._params, "method": self.method}


# ``--methods`` names → solver names
METHOD_SOLVERS = {"nstar": "ours", "triad": "ours_triad", "bleif": "ours_bleif"}


class _Tetra3rs(Adapter):
    name = "tetra3rs"

    def __init__(self, cfg: BenchConfig, camera, cache: Path) -> None:
        import tetra3rs

        self.t3 = tetra3rs
        self.cfg, self.camera, self.cache = cfg, camera, cache
        self._dbs: dict[tuple[float, float], Any] = {}
        self._db_info: dict[str, dict[str, Any]] = {}
        self.db = None
        self.kw: dict[str, Any] = {}

    def _database(self, mag_limit: float, fov_deg: float):
        key = (mag_limit, round(fov_deg, 6))
        if key in self._dbs:
            return self._dbs[key]
        from adfusion.starid.catalog.cache import cache_key

        params = {
            "tetra3rs": self.t3.__version__, "max_fov_deg": key[1],
            "star_max_magnitude": mag_limit + 0.5, "epoch": self.cfg.epoch,
        }  # fmt: skip
        path = self.cache / f"tetra3rs-db-{cache_key('tetra3rs-db', params)}.bin"
        t0 = time.perf_counter()
        built = not path.exists()
        if built:
            db = self.t3.SolverDatabase.generate_from_gaia(
                max_fov_deg=params["max_fov_deg"],
                star_max_magnitude=params["star_max_magnitude"],
                epoch_proper_motion_year=self.cfg.epoch)
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            db.save_to_file(str(tmp))
            os.replace(tmp, path)
        else:
            db = self.t3.SolverDatabase.load_from_file(str(path))
        label = f"G<{params['star_max_magnitude']:g}"
        if key[1] != round(getattr(self.cfg, "fov_deg", key[1]), 6):
            label += f", FOV {key[1]:g}°"
        self._db_info[label] = {
            "path": str(path), "file_bytes": path.stat().st_size,
            "built_now": built, "build_or_load_s": round(time.perf_counter() - t0, 3),
            "num_stars": int(db.num_stars), "num_patterns": int(db.num_patterns),
            "params": params}
        self._dbs[key] = db
        return db

    def setup(self, cond: Condition, camera) -> None:
        limit = self.cfg.mag_limit if cond.mag_limit is None else cond.mag_limit
        self.camera = camera
        self.centre = np.array([(camera.width - 1) / 2, (camera.height - 1) / 2])
        self.db = self._database(float(limit), camera.fov_x_deg)
        self.kw = {
            "fov_estimate_deg": self.camera.fov_x_deg, "image_width": self.camera.width,
            "image_height": self.camera.height, "fov_max_error_deg": 0.5,
            "solve_timeout_ms": int(self.cfg.peer_timeout_ms),
        }  # fmt: skip
        mme = peer_match_max_error(float(cond.sigma_px or 0.0), self.camera.width)
        if mme is not None:
            self.kw["match_max_error"] = mme

    def to_peer(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Our pixel centres → tetra3rs (x, y) from the geometric image centre."""
        return np.ascontiguousarray(xy - self.centre)

    def solve(self, frame: Frame) -> Outcome:
        assert self.db is not None
        c = self.to_peer(frame.xy)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            r = self.db.solve_from_centroids(c, **self.kw)
        except Exception as e:
            return Outcome(False, None, time.perf_counter() - t0, f"exception: {e!r}")
        dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if not r:
            return Outcome(False, None, dt, str(r.status), r.solve_time_ms / 1e3, cpu_s=cpu)
        q = np.asarray(r.quaternion, dtype=np.float64)  # already q_cam_icrs (checked)
        return Outcome(True, q / np.linalg.norm(q), dt, "", r.solve_time_ms / 1e3, cpu_s=cpu)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "version": self.t3.__version__, "databases": self._db_info}

    def params(self) -> dict[str, Any]:
        return {"database": f"G<{self.db.parameters.get('star_max_magnitude', '?')}"
                if self.db is not None else None, **self.kw}


_CEDAR_WORKER = textwrap.dedent('''
    import json, logging, sys, time
    out = sys.stdout
    sys.stdout = sys.stderr  # anything the library prints must not corrupt the protocol
    lg = logging.getLogger("tetra3.Tetra3")
    lg.addHandler(logging.NullHandler())
    lg.setLevel(logging.WARNING)
    lg.propagate = False
    import numpy as np
    import tetra3
    from importlib.metadata import version
    t0 = time.perf_counter()
    t3 = tetra3.Tetra3()
    props = {k: (v.tolist() if hasattr(v, "tolist") else v)
             for k, v in t3.database_properties.items()}
    out.write(json.dumps({"ready": True, "version": version("cedar-solve"),
                          "numpy": np.__version__, "load_s": time.perf_counter() - t0,
                          "database": props}) + "\\n")
    out.flush()
    for line in sys.stdin:
        msg = json.loads(line)
        yx = np.asarray(msg["yx"], dtype=np.float64).reshape(-1, 2)
        t0 = time.perf_counter()
        try:
            r = t3.solve_from_centroids(yx, msg["size"], **msg["kw"])
            err = ""
        except Exception as e:
            r, err = {"status": -1}, repr(e)
        dt = time.perf_counter() - t0
        res = {"id": msg["id"], "t_s": dt, "status": int(r.get("status") or -1), "error": err}
        for k in ("RA", "Dec", "Roll", "FOV", "Prob", "Matches", "T_solve"):
            v = r.get(k)
            res[k] = None if v is None else float(v)
        out.write(json.dumps(res) + "\\n")
        out.flush()
''')

_CEDAR_STATUS = {1: "match_found", 2: "no_match", 3: "timeout", 4: "cancelled", 5: "too_few",
                 -1: "error"}


def ensure_cedar_venv(cache: Path, timeout_s: float = 900.0) -> Path:
    """The Python of a venv with ``cedar-solve`` (created on first use); raises on failure.

    A ``.ok`` stamp marks a complete install, so an interrupted one is redone.
    """
    venv = cache / "cedar-venv"
    py = venv / "bin" / "python"
    stamp = venv / ".ok"
    if stamp.exists() and py.exists():
        return py
    if venv.exists():
        shutil.rmtree(venv)
    print(f"bench starid: creating the cedar-solve venv in {venv} (once) …", file=sys.stderr)
    base = sys.executable  # the running Python: its version is known to work here
    steps = [[base, "-m", "venv", str(venv)],
             [str(py), "-m", "pip", "install", "--disable-pip-version-check", "-q",
              "cedar-solve"]]
    for cmd in steps:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
        if p.returncode != 0:
            tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
            raise RuntimeError(f"{' '.join(cmd[:3])} … failed: {' | '.join(tail)}")
    stamp.write_text("ok\n")
    return py


class _Cedar(Adapter):
    name = "cedar"

    def __init__(self, cfg: BenchConfig, camera, cache: Path) -> None:
        self.cfg, self.camera = cfg, camera
        py = ensure_cedar_venv(cache)
        self._log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(
            [str(py), "-u", "-c", _CEDAR_WORKER], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self._log, text=True, bufsize=1)
        self.hello = self._read()
        self.kw: dict[str, Any] = {}
        self._n = 0
        self._dead = ""

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            self._log.seek(0)
            tail = self._log.read().strip().splitlines()[-3:]
            raise RuntimeError(f"cedar worker exited: {' | '.join(tail)}")
        return json.loads(line)

    def setup(self, cond: Condition, camera) -> None:
        self.camera = camera
        self.kw = {"fov_estimate": self.camera.fov_x_deg, "fov_max_error": 0.5,
                   "solve_timeout": self.cfg.peer_timeout_ms}
        mme = peer_match_max_error(float(cond.sigma_px or 0.0), self.camera.width)
        if mme is not None:
            self.kw["match_max_error"] = mme

    @staticmethod
    def to_peer(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Our pixel centres → tetra3 (y, x) from the top-left corner of the image."""
        return xy[:, ::-1] + 0.5

    def solve(self, frame: Frame) -> Outcome:
        from adfusion.maths import rotations as rot

        assert self.proc.stdin is not None
        if self._dead:
            return Outcome(False, None, 0.0, f"error: {self._dead}")
        self._n += 1
        msg = {"id": self._n, "yx": self.to_peer(frame.xy).tolist(),
               "size": [self.camera.height, self.camera.width], "kw": self.kw}
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
            r = self._read()
        except (OSError, RuntimeError, json.JSONDecodeError) as e:
            self._dead = f"cedar worker died: {e}"
            return Outcome(False, None, 0.0, f"error: {self._dead}")
        if r.get("id") != self._n:
            raise RuntimeError(f"cedar worker out of step: sent {self._n}, got {r.get('id')}")
        status = _CEDAR_STATUS.get(r["status"], str(r["status"]))
        own = None if r["T_solve"] is None else r["T_solve"] / 1e3
        if r["status"] != 1 or r["RA"] is None:
            return Outcome(False, None, r["t_s"], status + (f": {r['error']}" if r["error"]
                                                             else ""), own)
        q = rot.q_cam_icrs_from_radec_roll(*np.radians([r["RA"], r["Dec"], -r["Roll"]]))
        return Outcome(True, q, r["t_s"], "", own)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "version": self.hello.get("version"),
                "numpy": self.hello.get("numpy"), "database": self.hello.get("database"),
                "database_load_s": round(self.hello.get("load_s", 0.0), 3),
                "worker_error": self._dead or None}

    def params(self) -> dict[str, Any]:
        return {"database": "default_database", **self.kw}

    def close(self) -> None:
        with contextlib.suppress(Exception):
            if self.proc.stdin:
                self.proc.stdin.close()
            self.proc.wait(timeout=10)
        if self.proc.poll() is None:
            self.proc.kill()
        self._log.close()


def cache_root(cfg: BenchConfig) -> tuple[Path, tempfile.TemporaryDirectory | None]:
    if cfg.cache_dir:
        p = Path(cfg.cache_dir).expanduser()
        p.mkdir(parents=True, exist_ok=True)
        return p, None
    from adfusion.starid.catalog.cache import cache_dir

    root = cache_dir()
    if root is not None:
        return root, None
    tmp = tempfile.TemporaryDirectory(prefix="adfusion-bench-")
    return Path(tmp.name), tmp


# --- start-up: conventions check, adapters by name ---------------------------------------


def conversion_check(adapters: Sequence[Adapter], cfg: BenchConfig, camera,
                      n: int = 3) -> dict[str, dict[str, Any]]:
    """Noise-free frames at the base settings: every solver's error must be ≈ 0.

    Doubles as the warm-up, so first-call costs stay out of the timings.
    """
    from adfusion.maths import rotations as rot

    cond = Condition("conversion-check", sigma_px=0.0, mag_limit=cfg.mag_limit)
    cat = load_catalog(cfg.mag_limit, cfg.epoch)
    frames = [make_frame(cat, camera, cond, seed=cfg.seed + 10_007, index=i, mag_noise=0.0)
              for i in range(n)]
    out: dict[str, dict[str, Any]] = {}
    for a in adapters:
        a.setup(cond, camera)
        errs = []
        for f in frames:
            o = a.solve(f)
            if o.ok and o.q is not None:
                errs.append(float(np.degrees(rot.angle_between(o.q, f.q_cam_icrs))) * 3600)
        worst = max(errs) if errs else None
        out[a.name] = {"frames": n, "solved": len(errs),
                       "max_error_arcsec": None if worst is None else round(worst, 3),
                       "passed": worst is not None and worst < _CHECK_LIMIT_ARCSEC}
    return out


def make_adapters(cfg: BenchConfig, camera, cache: Path) -> tuple[list[Adapter],
                                                                     dict[str, Any]]:
    adapters: list[Adapter] = []
    skipped: dict[str, Any] = {}
    for name in cfg.solvers:
        try:
            if name == "ours":
                adapters.append(_Ours(cfg, camera))
            elif name == "ours_tracking":
                adapters.append(_OursTracking(cfg, camera,
                                              getattr(cfg, "prior_sigma_deg", 0.1)))
            elif name in ("ours_triad", "ours_bleif"):
                adapters.append(_OursMethod(cfg, camera, name.removeprefix("ours_")))
            elif name == "tetra3rs":
                adapters.append(_Tetra3rs(cfg, camera, cache))
            elif name == "cedar":
                adapters.append(_Cedar(cfg, camera, cache))
            else:
                raise ValueError(f"unknown solver {name!r} (choose from "
                                 f"{(*SOLVER_NAMES, 'ours_tracking', 'ours_triad', 'ours_bleif')})")
        except ImportError as e:
            skipped[name] = {"status": "skipped", "reason": f"not importable: {e}"}
        except (RuntimeError, OSError, subprocess.SubprocessError, json.JSONDecodeError) as e:
            skipped[name] = {"status": "skipped", "reason": str(e)}
    return adapters, skipped
