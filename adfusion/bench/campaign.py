"""Campaigns: many independent, seeded tasks on ``dask.distributed`` (or in this process).

A campaign is a list of :class:`Task` — a unique ``key`` and a small picklable
``payload`` — and one importable function ``fn(payload) -> result`` (JSON-able). Results
come back keyed, in task order, whatever order the tasks finished in; the caller derives
every random number from ``(seed, point, trial)`` inside ``fn``, never from the worker or
the order, so a campaign gives the same results on 1, 2 or 200 workers.

Where it runs (:func:`run_campaign`):

* ``scheduler="tcp://host:8786"`` — an existing ``dask.distributed`` cluster (its workers
  need this package importable, and build their own caches on first use);
* ``workers=N`` (default: the CPU count) — a ``LocalCluster`` of N single-threaded worker
  *processes*: star identification is pure-Python/NumPy work that holds the GIL, and one
  thread per process keeps every timing single-threaded;
* ``workers=0``, or ``dask`` not installed — serially in this process (dask is the
  optional ``adfusion[dist]`` extra; a note says so).

Losing work (the decision): every finished task's result is appended to a JSON-lines
*partial file* (``partial=PATH``) as soon as it arrives, with a fingerprint of the task
(function, key, payload). A lost worker loses only its in-flight tasks: the scheduler
re-runs them elsewhere (dask's ``allowed-failures``, 3 by default; the nanny restarts the
worker). A task that still fails is reported, not fatal: the others finish, the partial
file keeps what is done, and :class:`CampaignError` lists what is missing — running the
campaign again reads the partial file back and computes only the tasks not in it (or
changed), so a grown campaign (more points) also reuses the finished ones. On complete
success the partial file is removed unless ``keep_partial``. The alternatives — dask's own
result persistence, or a database — would add a dependency for what a 20-line append-only
file does.

Worker-side state (catalogues, pattern indexes, a peer solver's subprocess) is memoised per
process with :func:`worker_memo`; it lives in this module, so task functions defined in a
script (pickled by value) still share it.

Example (in-process; the same call with ``workers=2`` runs on a local dask cluster):
    >>> tasks = [Task(f"t{i}", i) for i in range(4)]
    >>> r = run_campaign(square, tasks, workers=0, progress=False)
    >>> list(r.results.values()), r.backend
    ([0, 1, 4, 9], 'serial')
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import logging
import os
import sys
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from adfusion.starid.catalog.cache import source_digest

__all__ = [
    "MEASURED_KEYS",
    "CampaignError",
    "CampaignResult",
    "Task",
    "dask_available",
    "fingerprint",
    "release_all",
    "run_campaign",
    "source_digest",
    "square",
    "strip_measured",
    "worker_memo",
]

#: Keys of result documents that hold measurements of *this* run (times, machine, the
#: campaign's own bookkeeping) rather than results; :func:`strip_measured` drops them
#: before two runs are compared.
MEASURED_KEYS = frozenset({
    "time_ms", "time_ms_correct", "own_reported_time_ms", "slowest_frames",
    "time_ratio_ours_over_peer", "wall_s", "machine", "campaign", "solvers", "code",
    "estimate", "database_load_s",
})


@dataclass(frozen=True)
class Task:
    """One unit of work: a unique ``key``, the ``payload`` passed to the task function,
    and a ``weight`` (e.g. its number of trials) for the progress bar."""

    key: str
    payload: Any
    weight: int = 1


@dataclass
class CampaignResult:
    """Results by task key (in task order) and how the campaign ran."""

    results: dict[str, Any]
    backend: str  # "serial" | "dask-local" | "dask-scheduler"
    workers: int
    resumed: int = 0  # tasks read back from the partial file
    wall_s: float = 0.0
    note: str = ""
    failed: dict[str, str] = field(default_factory=dict)

    def info(self) -> dict[str, Any]:
        """How it ran, for the result document (not a result: see :data:`MEASURED_KEYS`)."""
        return {"backend": self.backend, "workers": self.workers, "tasks": len(self.results),
                "resumed_from_partial": self.resumed, "wall_s": round(self.wall_s, 2),
                "note": self.note}


class CampaignError(RuntimeError):
    """Some tasks failed even after the scheduler's retries; the rest are in the partial
    file (``partial``), so running the campaign again computes only the missing ones."""

    def __init__(self, failed: dict[str, str], partial: Path | None) -> None:
        self.failed, self.partial = failed, partial
        first = next(iter(failed.items()))
        where = f"; finished tasks are kept in {partial}" if partial else ""
        super().__init__(f"{len(failed)} task(s) failed (first: {first[0]}: {first[1]})"
                         f"{where}")


def dask_available() -> bool:
    """Whether ``dask.distributed`` can be imported (the ``adfusion[dist]`` extra)."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


def square(x: int) -> int:
    """A trivial task function (doctests, smoke checks of a cluster).

    >>> square(3)
    9
    """
    return x * x


def fingerprint(fn: Callable[..., Any], task: Task) -> str:
    """A digest of the task function's name and the task (key, payload): a result in a
    partial file is reused only by the very same task, so a campaign can grow (more points,
    more trials) on top of an earlier run's file.

    >>> fingerprint(square, Task("a", 1)) == fingerprint(square, Task("a", 1))
    True
    >>> fingerprint(square, Task("a", 1)) == fingerprint(square, Task("a", 2))
    False
    """
    h = hashlib.sha256(f"{fn.__module__}.{fn.__qualname__}\0{task.key}\0{task.payload!r}"
                       .encode())
    return h.hexdigest()[:24]


# --- worker-side state ------------------------------------------------------------------

_STATE: dict[Any, Any] = {}


def worker_memo(key: Any, factory: Callable[[], Any]) -> Any:
    """``factory()`` once per process and ``key``; objects with a ``close()`` are closed
    by :func:`release_all` (and at exit).

    >>> worker_memo("doc-example", lambda: [1]) is worker_memo("doc-example", lambda: [2])
    True
    """
    if key not in _STATE:
        _STATE[key] = factory()
    return _STATE[key]


def release_all() -> int:
    """Close and forget every memoised object of this process; returns how many."""
    n = len(_STATE)
    while _STATE:
        _, obj = _STATE.popitem()
        for o in obj if isinstance(obj, list | tuple) else (obj,):
            close = getattr(o, "close", None)
            if callable(close):
                with contextlib.suppress(Exception):
                    close()
    return n


atexit.register(release_all)


# --- partial results --------------------------------------------------------------------


def _read_partial(path: Path) -> dict[str, tuple[str, Any]]:
    """key → (task fingerprint, result) of the lines of an earlier run (last one wins)."""
    done: dict[str, tuple[str, Any]] = {}
    if not path.exists():
        return done
    with path.open() as f:
        for line in f:
            try:
                rec = json.loads(line)
                done[rec["key"]] = (rec["task"], rec["result"])
            except (json.JSONDecodeError, KeyError, TypeError):
                continue  # a line cut short by a crash: that task is recomputed
    return done


class _PartialWriter:
    def __init__(self, path: Path | None) -> None:
        self.f = None
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.f = path.open("a")

    def add(self, key: str, fp: str, result: Any) -> None:
        if self.f is not None:
            self.f.write(json.dumps({"key": key, "task": fp, "result": result},
                                    separators=(",", ":")) + "\n")
            self.f.flush()  # one line per task: a crash loses at most the line being written

    def close(self) -> None:
        if self.f is not None:
            self.f.close()


# --- running ----------------------------------------------------------------------------


def _bar(total: int, desc: str, unit: str, progress: bool, initial: int = 0):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr,
                disable=None if progress else True, smoothing=0.05)


def _run_serial(fn: Callable[[Any], Any], todo: Sequence[Task],
                on_done: Callable[[Task, Any], None],
                on_fail: Callable[[Task, str], None]) -> None:
    for t in todo:
        try:
            r = fn(t.payload)
        except Exception as e:  # reported like a task lost on a cluster
            on_fail(t, repr(e))
        else:
            on_done(t, r)


def _run_dask(client, fn: Callable[[Any], Any], todo: Sequence[Task],
              on_done: Callable[[Task, Any], None],
              on_fail: Callable[[Task, str], None]) -> None:
    from distributed import as_completed

    tag = uuid.uuid4().hex[:8]  # keys unique per run: a shared scheduler caches by key
    futures = {client.submit(fn, t.payload, key=f"campaign-{tag}-{t.key}", pure=False): t
               for t in todo}
    for fut in as_completed(list(futures)):
        t = futures[fut]
        try:
            r = fut.result()
        except Exception as e:  # KilledWorker after the retries, or the task raised
            on_fail(t, repr(e))
        else:
            on_done(t, r)
        fut.release()


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None):
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client, "dask-scheduler", len(client.scheduler_info()["workers"])
        return
    n = workers or os.cpu_count() or 1
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        yield client, "dask-local", n


def run_campaign(fn: Callable[[Any], Any], tasks: Iterable[Task], *,
                 workers: int | None = None, scheduler: str | None = None,
                 partial: str | os.PathLike[str] | None = None, progress: bool = True,
                 desc: str = "campaign", unit: str = "task",
                 keep_partial: bool = False) -> CampaignResult:
    """Run ``fn`` on every task's payload; results by key, in task order.

    Args:
        fn: a module-level function (it is pickled to the workers); its result must be
            JSON-able when ``partial`` is given.
        tasks: the tasks; keys must be unique.
        workers: local worker processes (None: the CPU count; 0: serial in this process).
        scheduler: address of an existing dask scheduler (``workers`` is then ignored).
        partial: JSON-lines file for finished results (resumed when it belongs to the same
            campaign; removed after a complete run unless ``keep_partial``).
        progress: a tqdm bar on stderr, advanced by each task's ``weight``.

    Raises:
        CampaignError: when tasks still failed after the retries (the others are kept).
    """
    tasks = list(tasks)
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ValueError("task keys must be unique")
    t0 = time.perf_counter()
    fps = {t.key: fingerprint(fn, t) for t in tasks}
    path = Path(partial) if partial is not None else None
    earlier = _read_partial(path) if path is not None else {}
    done = {k: r for k, (fp, r) in earlier.items() if fps.get(k) == fp}
    todo = [t for t in tasks if t.key not in done]
    writer = _PartialWriter(path)
    failed: dict[str, str] = {}
    resumed = len(done)
    bar = _bar(sum(t.weight for t in tasks), desc, unit, progress,
               initial=sum(t.weight for t in tasks if t.key in done))

    def on_done(t: Task, r: Any) -> None:
        done[t.key] = r
        writer.add(t.key, fps[t.key], r)
        bar.update(t.weight)

    def on_fail(t: Task, why: str) -> None:
        failed[t.key] = why
        bar.set_postfix_str(f"{len(failed)} failed")

    note = ""
    use_dask = bool(todo) and (scheduler is not None or workers != 0)
    if use_dask and not dask_available():
        use_dask = False
        note = ("dask is not installed (pip install 'adfusion[dist]'): ran serially in this "
                "process")
        print(f"{desc}: {note}", file=sys.stderr)
    try:
        if use_dask:
            with _client(workers, scheduler) as (client, backend, n_workers):
                try:
                    _run_dask(client, fn, todo, on_done, on_fail)
                finally:
                    with contextlib.suppress(Exception):
                        client.run(release_all)  # e.g. peer subprocesses on a shared cluster
        else:
            backend, n_workers = "serial", 1
            try:
                _run_serial(fn, todo, on_done, on_fail)
            finally:
                release_all()  # as on a cluster: per-campaign state ends with the campaign
    finally:
        bar.close()
        writer.close()
    if failed:
        raise CampaignError(failed, path)
    if path is not None and not keep_partial:
        path.unlink(missing_ok=True)
    return CampaignResult({k: done[k] for k in keys}, backend, n_workers, resumed,
                          time.perf_counter() - t0, note, failed)


def strip_measured(doc: Any, measured: frozenset[str] = MEASURED_KEYS) -> Any:
    """``doc`` without the keys that hold this run's measurements (:data:`MEASURED_KEYS`):
    what must be identical between runs of the same campaign on any number of workers.

    >>> strip_measured({"n": 3, "time_ms": {"median": 1.2}, "x": [{"wall_s": 4, "k": 1}]})
    {'n': 3, 'x': [{'k': 1}]}
    """
    if isinstance(doc, dict):
        return {k: strip_measured(v, measured) for k, v in doc.items() if k not in measured}
    if isinstance(doc, list):
        return [strip_measured(v, measured) for v in doc]
    return doc
