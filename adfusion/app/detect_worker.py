"""Star detection in a separate process, a few frames ahead of the caller.

A replay spends about half its time in :func:`starid.detection.detect`, which needs nothing from the
filter; on two cores it can run beside identification, filtering and logging. It is mostly
many small numpy calls holding the GIL, so a thread gains nothing; a process does. The
worker is a fresh interpreter (``python -m adfusion.app.detect_worker``) talking pickles over
its stdin/stdout — not ``multiprocessing``: forking a process that has used OpenCV can
deadlock the child (measured here: ``cv2.setNumThreads`` hung in a forked worker), and
the spawn/forkserver methods re-import the caller's ``__main__``, which breaks scripts
without a main guard. Results are those of a direct ``detect`` call, whatever the timing.

Frames do not travel through the pipe: on POSIX systems they are copied into a shared
memory file (``memfd``, inherited by the worker as a file descriptor, so nothing is left
behind if either process dies) and the request names the slot. A 512×480 frame pickled
through a 64 kB pipe cost both processes a copy, several system calls and a fresh
allocation each; the slot costs one ``memcpy``.

Example:
    >>> import numpy as np
    >>> from adfusion.app.detect_worker import DetectWorker
    >>> img = np.zeros((40, 40), np.uint8)
    >>> img[10, 10:12] = img[30, 20] = 200
    >>> with DetectWorker() as w:
    ...     w.submit(1, img, None, threshold=100, min_area=1, max_sharpness=None)
    ...     w.result(1).xy.shape
    (2, 2)
"""

from __future__ import annotations

import mmap
import os
import pickle
import queue
import subprocess
import sys
import tempfile
import threading
from typing import Any

import numpy as np

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

    Numeric image arrays go through ``slots`` shared-memory slots (:meth:`submit` waits
    for the oldest result when all are in use; the slot size grows with the largest frame
    seen); anything else (a path, an exotic array) is pickled into the request. Requests are
    written by the caller (each is a few hundred bytes, and at most ``slots`` are pending,
    so the pipe never fills); results come back in submission order and are kept until
    asked for. The camera is pickled only when a different object is passed than last time
    (the worker keeps the last one): do not mutate a camera between submissions.
    Where there is no shared memory (not POSIX), every request is pickled whole and written
    by a feeder thread, as a pipe write then blocks until the worker reads. An exception in
    the worker is raised by :meth:`result`, as the direct call would have raised it. Use as
    a context manager, or call :meth:`close`.
    """

    def __init__(self, slots: int = 16) -> None:
        if slots < 1:
            raise ValueError(f"slots must be >= 1, got {slots}")
        self._slots = int(slots)
        self._fd = -1
        self._tmp = None
        args = [sys.executable, "-m", "adfusion.app.detect_worker"]
        if os.name == "posix":
            if hasattr(os, "memfd_create"):
                self._fd = os.memfd_create("adfusion-frames", getattr(os, "MFD_CLOEXEC", 0))
            else:  # an unlinked temporary file does the same where memfd is missing
                self._tmp = tempfile.TemporaryFile()
                self._fd = self._tmp.fileno()
            args.append(str(self._fd))
        self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      pass_fds=(self._fd,) if self._fd >= 0 else ())
        self._map: mmap.mmap | None = None
        self._slot_bytes = 0
        self._free = list(range(self._slots))[::-1]
        self._slot_of: dict[Any, int] = {}
        self._camera: Any = None
        self._camera_sent = False
        self._hello = False  # the worker announces itself once it has imported starid
        self._order: list[Any] = []
        self._done: dict[Any, tuple[bool, Any]] = {}
        self._outbox: queue.Queue | None = None
        if self._fd < 0:
            self._outbox = queue.Queue()
            self._feeder = threading.Thread(target=self._feed, daemon=True,
                                            name="detect-feed")
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

    def _send(self, item: tuple) -> None:
        if self._outbox is not None:
            self._outbox.put(item)
            return
        pipe = self._proc.stdin
        pickle.dump(item, pipe, protocol=pickle.HIGHEST_PROTOCOL)
        pipe.flush()

    def ready(self) -> bool:
        """Whether the worker has started up (imported ``starid``); never blocks. Where
        pipes cannot be polled (not POSIX) the answer is always ``True``."""
        if self._hello or os.name != "posix":
            return True
        import select

        if select.select([self._proc.stdout], [], [], 0)[0]:
            self._load()  # the hello, or EOF of a worker that died (raised later)
            self._hello = True
        return self._hello

    def _load(self) -> Any:
        try:
            return pickle.load(self._proc.stdout)
        except EOFError:
            raise RuntimeError("the detection worker died (exit code "
                               f"{self._proc.poll()})") from None

    def _receive(self) -> None:
        """Read the next result from the worker (blocks) and free its slot."""
        if not self._hello:
            self._load()
            self._hello = True
        try:
            got, ok, value = pickle.load(self._proc.stdout)
        except EOFError:
            raise RuntimeError("the detection worker died (exit code "
                               f"{self._proc.poll()})") from None
        self._order.remove(got)
        self._done[got] = (ok, value)
        slot = self._slot_of.pop(got, None)
        if slot is not None:
            self._free.append(slot)

    def _drain(self) -> None:
        """Wait until the worker has answered everything submitted so far."""
        while self._order:
            self._receive()

    def _place(self, image: np.ndarray) -> tuple[int, int]:
        """Copy ``image`` into a free slot: (slot, byte offset)."""
        n = image.nbytes
        if n > self._slot_bytes:  # a larger frame: wait for the worker, then regrow
            self._drain()
            self._slot_bytes = max(n, 2 * self._slot_bytes)
            os.ftruncate(self._fd, self._slot_bytes * self._slots)
            self._map = None  # views taken from the old map are gone; it closes with them
            self._map = mmap.mmap(self._fd, self._slot_bytes * self._slots)
        while not self._free:
            self._receive()
        slot = self._free.pop()
        offset = slot * self._slot_bytes
        np.ndarray(image.shape, image.dtype, buffer=self._map, offset=offset)[...] = image
        return slot, offset

    def submit(self, key: Any, image, camera, **kwargs: Any) -> None:
        """Queue ``starid.detect(image, camera, **kwargs)`` under ``key``."""
        if key in self._order:
            raise ValueError(f"frame {key!r} is already pending")
        frame: Any = image
        slot = None
        if (self._fd >= 0 and isinstance(image, np.ndarray) and image.dtype.kind in "biuf"
                and image.size):
            slot, offset = self._place(image)
            frame = (offset, image.shape, image.dtype.str)
        elif self._fd >= 0 and isinstance(image, np.ndarray):
            self._drain()  # a large pickle: the worker must be reading, not writing results
        if self._camera_sent and camera is self._camera:
            cam_item: tuple = ()
        else:  # a new camera object: send it once, the worker keeps it
            cam_item = (camera,)
            self._camera, self._camera_sent = camera, True
        self._order.append(key)
        if slot is not None:
            self._slot_of[key] = slot
        try:
            self._send((key, frame, slot is not None, cam_item, kwargs))
        except BaseException:
            self._order.remove(key)
            self._camera_sent = False
            if slot is not None:
                self._free.append(self._slot_of.pop(key))
            raise

    def result(self, key: Any):
        """The detections of frame ``key`` (waits for it); raises what ``detect`` raised."""
        while key not in self._done:
            if key not in self._order:
                raise KeyError(f"frame {key!r} was not submitted")
            self._receive()
        ok, value = self._done.pop(key)
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop the worker (pending results are dropped)."""
        if self._proc.poll() is None:
            if self._outbox is not None:
                self._outbox.put(None)
                self._feeder.join(timeout=5)
            else:
                try:
                    self._proc.stdin.close()
                except OSError:
                    pass
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc.stdout.close()
        self._map = None
        if self._tmp is not None:
            self._tmp.close()
        elif self._fd >= 0:
            os.close(self._fd)
        self._fd = -1

    def __enter__(self) -> DetectWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(fd: int = -1) -> None:
    import cv2

    # One thread: the caller's process keeps the other core busy, and OpenCV's pool spent
    # ~0.7 ms of CPU per 512×480 frame handing small images between threads (detect took
    # 2.6 ms of CPU on one thread, 3.3 ms on two).
    cv2.setNumThreads(1)
    from adfusion.starid.detection.detect import detect

    keep_freed_memory()  # pickled requests still allocate; see the function
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    pickle.dump("ready", out)
    out.flush()
    shared: mmap.mmap | None = None
    camera = None
    while True:
        try:
            key, frame, in_slot, cam_item, kwargs = pickle.load(inp)
        except EOFError:
            # nothing to clean up (results are flushed, the shared memory dies with us):
            # skipping the interpreter's teardown saves the caller ~0.1 s waiting for us
            os._exit(0)
        if cam_item:
            camera = cam_item[0]
        try:
            if in_slot:
                offset, shape, dtype = frame
                dtype = np.dtype(dtype)
                end = offset + dtype.itemsize * int(np.prod(shape))
                if shared is None or len(shared) < end:  # the caller grew the file
                    shared = mmap.mmap(fd, os.fstat(fd).st_size)
                frame = np.ndarray(shape, dtype, buffer=shared, offset=offset)
            reply = (key, True, detect(frame, camera, **kwargs))
        except Exception as exc:  # handed to the caller, raised there
            reply = (key, False, exc)
        frame = None  # no view of the old map may outlive a regrowth
        pickle.dump(reply, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    _serve(int(sys.argv[1]) if len(sys.argv) > 1 else -1)
