"""Star detection in a separate process, a few frames ahead of the caller.

A replay spends about half its time in :func:`starid.detect`, which needs nothing from the
filter; on two cores it can run beside identification, filtering and logging. It is mostly
many small numpy calls holding the GIL, so a thread gains nothing; a process does. The
worker is a fresh interpreter (``python -m adfusion.detect_worker``) talking pickles over
its stdin/stdout — not ``multiprocessing``: forking a process that has used OpenCV can
deadlock the child (measured here: ``cv2.setNumThreads`` hung in a forked worker), and
the spawn/forkserver methods re-import the caller's ``__main__``, which breaks scripts
without a main guard. Results are those of a direct ``detect`` call, whatever the timing.

Example:
    >>> import numpy as np
    >>> from adfusion.detect_worker import DetectWorker
    >>> img = np.zeros((40, 40), np.uint8)
    >>> img[10, 10:12] = img[30, 20] = 200
    >>> with DetectWorker() as w:
    ...     w.submit(1, img, None, threshold=100, min_area=1, max_sharpness=None)
    ...     w.result(1).xy.shape
    (2, 2)
"""

from __future__ import annotations

import pickle
import queue
import subprocess
import sys
import threading
from typing import Any

__all__ = ["DetectWorker", "keep_freed_memory"]

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc <malloc.h>


def keep_freed_memory(mmap_threshold: int = 4 << 20, trim_threshold: int = 32 << 20) -> bool:
    """Have glibc's ``malloc`` keep freed blocks of up to ``mmap_threshold`` bytes for reuse
    (process-wide; returns ``False`` where there is no glibc ``mallopt``).

    Why: a replay allocates and frees a dozen buffers of 0.2–2 MB per frame (images, MCAP
    chunks). By default glibc serves the larger ones with ``mmap`` and hands freed heap tops
    back to the kernel, so every frame faulted ~300 fresh zeroed pages back in: measured
    1.5 ms of a 7 ms frame in the replay process (stime 2.5 s → 0.8 s over 1800 frames) and
    0.5 ms in the detection worker. With these thresholds the memory is reused instead; the
    process keeps at most ``trim_threshold`` bytes of free heap it would have returned.
    """
    for value in (mmap_threshold, trim_threshold):
        if not 0 <= int(value) < 2**31:  # a C int: ctypes would wrap a larger one silently
            raise ValueError(f"malloc threshold out of range: {value}")
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no such tuning)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))
                and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))


class DetectWorker:
    """A detection process: :meth:`submit` frames (keyed), :meth:`result` in any order.

    Requests go through a feeder thread (a pipe write blocks until the worker reads, and
    the caller should not wait for that); results come back in submission order and are
    kept until asked for. An exception in the worker is raised by :meth:`result`, as the
    direct call would have raised it. Use as a context manager, or call :meth:`close`.
    """

    def __init__(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "adfusion.detect_worker"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._outbox: queue.Queue = queue.Queue()
        self._order: list[Any] = []
        self._done: dict[Any, tuple[bool, Any]] = {}
        self._feeder = threading.Thread(target=self._feed, daemon=True, name="detect-feed")
        self._feeder.start()

    def _feed(self) -> None:
        pipe = self._proc.stdin
        while (item := self._outbox.get()) is not None:
            try:
                pickle.dump(item, pipe, protocol=pickle.HIGHEST_PROTOCOL)
                pipe.flush()
            except (BrokenPipeError, OSError):
                return
        pipe.close()

    def submit(self, key: Any, image, camera, **kwargs: Any) -> None:
        """Queue ``starid.detect(image, camera, **kwargs)`` under ``key``."""
        self._order.append(key)
        self._outbox.put((key, image, camera, kwargs))

    def result(self, key: Any):
        """The detections of frame ``key`` (waits for it); raises what ``detect`` raised."""
        while key not in self._done:
            if not self._order:
                raise KeyError(f"frame {key!r} was not submitted")
            try:
                got, ok, value = pickle.load(self._proc.stdout)
            except EOFError:
                raise RuntimeError("the detection worker died (exit code "
                                   f"{self._proc.poll()})") from None
            self._order.remove(got)
            self._done[got] = (ok, value)
        ok, value = self._done.pop(key)
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop the worker (pending results are dropped)."""
        if self._proc.poll() is None:
            self._outbox.put(None)
            self._feeder.join(timeout=5)
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc.stdout.close()

    def __enter__(self) -> DetectWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve() -> None:
    from starid import detect

    keep_freed_memory()  # every request unpickles a fresh frame (see the function)

    inp, out = sys.stdin.buffer, sys.stdout.buffer
    while True:
        try:
            key, image, camera, kwargs = pickle.load(inp)
        except EOFError:
            return
        try:
            reply = (key, True, detect(image, camera, **kwargs))
        except Exception as exc:  # handed to the caller, raised there
            reply = (key, False, exc)
        pickle.dump(reply, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    _serve()
