"""Writing output files safely: never over an input, one writer at a time, never half there.

Every command's outputs go through this module (issue 33):

* :func:`refuse_overwrite` — the one guard: an output that *is* an input (the same file by
  device and inode, so ``./x``, a symlink and a hard link count; by resolved name when the
  output does not exist yet), or two outputs that are one file, is refused with a one-line
  :class:`OutputClash` before any work is done;
* :class:`OutputLock` — an exclusive lock on an output (``fcntl.flock`` on a short lock
  file beside it, released by the kernel when a writer dies): a second writer of the same
  output gets a one-line :class:`OutputBusy` naming the file and the process holding it;
* :func:`atomic_output` — the output is written under a private temporary name in its own
  folder (``.adf-<random>.tmp<suffix>``: short, so an output name at the file system's
  255-byte limit still works, and unique, so two writers never share it) and renamed over
  the output only when complete.

A leaf below every layer (it imports nothing of ours): the log writer (:mod:`adfusion.logs`),
the benchmark harness and the application share it.

Example:
    >>> import os, tempfile
    >>> d = tempfile.mkdtemp()
    >>> out = os.path.join(d, "out.txt")
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> open(out).read(), sorted(os.listdir(d))
    ('done', ['out.txt'])
    >>> try:
    ...     refuse_overwrite([("-o", out)], [out])
    ... except OutputClash as e:
    ...     print(str(e).endswith("give another name (an output never replaces an input)"))
    True
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import secrets
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

__all__ = ["OutputBusy", "OutputClash", "OutputLock", "atomic_output", "files_in",
           "forget_written", "note_written", "refuse_overwrite", "replace_into", "same_file",
           "temp_name", "write_atomic", "written_outputs"]

PathLike = str | os.PathLike[str]

TEMP_PREFIX = ".adf-"  # temporary outputs and lock files: hidden, short, ours
_WRITTEN: list[str] = []  # outputs completed since forget_written(): see written_outputs


def note_written(path: PathLike) -> None:
    """Record that the output ``path`` is now complete (renamed into place)."""
    _WRITTEN.append(os.fspath(path))


def written_outputs() -> list[str]:
    """Every output completed in this process since :func:`forget_written`, in order — so
    a command that fails after writing some of its outputs can say which (and exit 1, done
    in part, rather than 2, nothing done).

    >>> import os, tempfile
    >>> forget_written()
    >>> p = write_atomic(os.path.join(tempfile.mkdtemp(), "a.txt"), "x")
    >>> [os.path.basename(w) for w in written_outputs()]
    ['a.txt']
    """
    return list(_WRITTEN)


def forget_written() -> None:
    """Start a new record for :func:`written_outputs` (at the start of each command)."""
    _WRITTEN.clear()


class OutputClash(ValueError):
    """An output names an input (or another output): a usage error, exit code 2."""


class OutputBusy(BlockingIOError):
    """Another writer holds the output's lock: exit code 2 (give another name or wait)."""


def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether two names are one file: by device and inode when both exist (so ``./x``, a
    symlink and a hard link count), else by resolved name, compared as the file system
    compares names (``normcase`` folds case where it is insensitive).

    >>> same_file("/tmp/../tmp/x", "/tmp/x")
    True
    """
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        pass
    return (os.path.normcase(os.path.realpath(a))
            == os.path.normcase(os.path.realpath(b)))


def refuse_overwrite(outputs: Iterable[tuple[str, PathLike]],
                     inputs: Iterable[PathLike]) -> None:
    """The one guard of every command that writes: each ``(label, path)`` of ``outputs``
    (``label`` the flag that named it, such as ``"-o"``) against every input and every
    other output. Raises :class:`OutputClash` (one line naming both) on the first clash.

    >>> refuse_overwrite([("--csv", "/tmp/a.csv"), ("--aem", "/tmp/a.aem")], ["/tmp/log.mcap"])
    """
    outs = [(label, os.fspath(p)) for label, p in outputs if p is not None]
    ins = [os.fspath(p) for p in inputs if p is not None]
    for label, path in outs:  # found now, not after the work when the rename fails
        if os.path.isdir(path):
            raise OutputClash(f"{label} {path} is a folder: give the name of a file to "
                              "write")
    for k, (label, path) in enumerate(outs):
        for src in ins:
            if same_file(path, src):
                raise OutputClash(f"{label} {path} is the input {src}: give another name "
                                  "(an output never replaces an input)")
        for other_label, other in outs[k + 1:]:
            if same_file(path, other):
                raise OutputClash(f"{label} and {other_label} both name {path}: give each "
                                  "output its own file")


def _suffix(path: Path) -> str:
    """The output's last suffix when it is a plain one (writers such as OpenCV choose the
    format by it), else none: the temporary name stays short whatever the output's name."""
    s = path.suffix
    return s if 1 < len(s) <= 10 and s[1:].isalnum() and s.isascii() else ""


def temp_name(path: PathLike) -> Path:
    """A new, empty, private file beside ``path`` for its writer: ``.adf-<random>.tmp<suffix>``
    in the same folder (so the final rename stays on one file system), created exclusively
    (two writers never get the same one).

    >>> import os, tempfile
    >>> p = temp_name(os.path.join(tempfile.mkdtemp(), "x" * 250 + ".png"))
    >>> p.name.startswith(".adf-") and p.name.endswith(".tmp.png"), len(p.name)
    (True, 25)
    """
    target = Path(path)
    folder = target.parent
    while True:
        tmp = folder / f"{TEMP_PREFIX}{secrets.token_hex(6)}.tmp{_suffix(target)}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # 2⁻⁴⁸: another writer's name
            continue
        except OSError as exc:  # the folder is the output's: name the output
            raise OSError(exc.errno, exc.strerror, os.fspath(target)) from None
        os.close(fd)
        return tmp


def _lock_path(path: PathLike) -> Path:
    """The lock file of an output: beside it, named by a digest of its resolved name (so
    every name of one output — relative, through a symlinked folder — finds one lock, and
    the lock's name stays short); inside it for a folder."""
    target = Path(os.path.abspath(os.fspath(path)))
    if target.is_dir():
        return Path(os.path.realpath(target)) / f"{TEMP_PREFIX}folder.lock"
    folder = Path(os.path.realpath(target.parent))
    digest = hashlib.sha256(os.fsencode(target.name)).hexdigest()[:16]
    return folder / f"{TEMP_PREFIX}{digest}.lock"


class OutputLock:
    """An exclusive lock on one output for as long as it is written (a context manager).

    ``fcntl.flock`` on the lock file :func:`_lock_path`: the kernel releases it when the
    writer exits, however it exits, so a crashed writer never blocks the next one. The
    holder writes its process id into the file, for the message the next writer gets. A
    released lock's file is removed (the lock is re-checked after taking it, as a holder
    may remove the file between another's open and lock).

    >>> import os, tempfile
    >>> out = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with OutputLock(out):
    ...     try:
    ...         OutputLock(out).acquire()
    ...     except OutputBusy as e:
    ...         print("being written by another run now" in str(e))
    True
"""

    def __init__(self, path: PathLike) -> None:
        self.path = os.fspath(path)
        self.lock_path = _lock_path(path)
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: an exclusively created file
            return self._acquire_exclusive()
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as exc:
                raise OSError(exc.errno, exc.strerror, self.path) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                holder = _read_pid(fd)
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise self._busy(holder) from None
                raise
            try:
                same = os.fstat(fd).st_ino == os.stat(self.lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # its holder removed it meanwhile: take the new one
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def _acquire_exclusive(self) -> OutputLock:  # pragma: no cover - not POSIX
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            raise self._busy(None, stale_hint=True) from None
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def _busy(self, holder: int | None, stale_hint: bool = False) -> OutputBusy:
        who = f" (process {holder})" if holder else ""
        hint = (f"; remove {self.lock_path} if no run is writing it" if stale_hint else "")
        return OutputBusy(f"{self.path} is being written by another run now{who}: wait for "
                          f"it to finish, or give another output name{hint}")

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.lock_path)  # while still held: no one can be waiting on it
        os.close(self._fd)
        self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        return int(text) if text.isdigit() else None
    except (OSError, ValueError):
        return None


@contextlib.contextmanager
def atomic_output(path: PathLike, *, lock: bool = True) -> Iterator[Path]:
    """Write ``path`` through a private temporary file: yields the temporary file's path
    (:func:`temp_name`, keeping the output's suffix for writers that choose the format by
    it), renamed over ``path`` when the block ends; removed if the block raises. With
    ``lock`` the output is held (:class:`OutputLock`) meanwhile.

    >>> import os, tempfile
    >>> out = os.path.join(tempfile.mkdtemp(), "a.csv")
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("t_s\\n")
    >>> open(out).read()
    't_s\\n'
    """
    held = OutputLock(path).acquire() if lock else None
    try:
        tmp = temp_name(path)
        try:
            yield tmp
            replace_into(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    finally:
        if held is not None:
            held.release()


def replace_into(tmp: PathLike, path: PathLike) -> None:
    """Rename the finished temporary file ``tmp`` over the output ``path`` and record it
    (:func:`note_written`); a failure names the output, not the temporary file."""
    try:
        os.replace(tmp, path)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, os.fspath(path)) from None
    note_written(path)


def write_atomic(path: PathLike, data: str | bytes, *, lock: bool = True,
                 encoding: str = "utf-8") -> Path:
    """Write ``data`` (text or bytes) to ``path`` as :func:`atomic_output` does.

    >>> import os, tempfile
    >>> p = write_atomic(os.path.join(tempfile.mkdtemp(), "r.json"), "{}")
    >>> p.read_text()
    '{}'
    """
    with atomic_output(path, lock=lock) as tmp:
        if isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data, encoding=encoding)
    return Path(path)


def files_in(folders: Sequence[PathLike], suffixes: Iterable[str] | None = None) -> list[Path]:
    """The files directly inside those of ``folders`` that are folders (with one of
    ``suffixes``, compared in lower case, when given): what a command reads from a folder
    it is given, for :func:`refuse_overwrite`.

    >>> files_in(["/no/such/folder"])
    []
    """
    want = None if suffixes is None else {s.lower() for s in suffixes}
    out: list[Path] = []
    for folder in folders:
        p = Path(folder)
        if not p.is_dir():
            continue
        with contextlib.suppress(OSError):
            out += sorted(f for f in p.iterdir()
                          if f.is_file() and (want is None or f.suffix.lower() in want))
    return out
