"""Argument types and checks shared by the ``adfusion`` sub-commands: numbers, paths,
outputs that must not overwrite inputs, the field of view, one-line errors and warnings.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import math
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from adfusion.app.errors import PartlyDone, UsageError
from adfusion.outfiles import OutputClash, refuse_overwrite

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".pgm", ".ppm")


def _number(text: str, what: str = "a number") -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    return _number(text)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number ≥ 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be ≥ 0")
    return value


def magnitude_limit(text: str) -> float:
    """argparse type: a catalogue limit, a finite V magnitude (99: every star — deep
    catalogues are thinned per field, see ``--stars-per-fov``)."""
    value = _number(text)
    if value < -1.5:
        raise argparse.ArgumentTypeError(
            f"{value:g} is brighter than every star (the brightest, Sirius, is V −1.46)")
    return value


def image_path(text: str) -> str:
    """argparse type: an output image name OpenCV can write (by its suffix)."""
    if not text.lower().endswith(IMAGE_SUFFIXES):
        raise argparse.ArgumentTypeError(
            f"{text!r}: give an image file name ending in one of {', '.join(IMAGE_SUFFIXES)}")
    return text


def _output_file(path: str, flag: str = "-o") -> None:
    """A file the command will write: not a folder, in a folder that exists."""
    if os.path.isdir(path):
        raise UsageError(f"{flag} {path} is a folder; give a file name")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise UsageError(f"{flag} {path}: the folder {parent} does not exist")


def fov_error_fits(fov_error_deg: float | None, camera) -> None:
    """``--fov-error`` must stay below the camera's field of view (the solver's bound,
    said in the flag's words): a usage error naming the flag and the fix.

    >>> from adfusion.starid.camera.model import Camera
    >>> try:
    ...     fov_error_fits(6.0, Camera.pinhole(64, 48, 5.7))
    ... except UsageError as e:
    ...     print(str(e).split(";")[0])
    --fov-error 6: must be below the camera's 5.7° field of view
    """
    if fov_error_deg and not fov_error_deg < camera.fov_x_deg:
        raise UsageError(f"--fov-error {fov_error_deg:g}: must be below the camera's "
                         f"{camera.fov_x_deg:.3g}° field of view; for a field of view known "
                         "only roughly give its range, --fov LO:HI")


def _outputs_apart(outputs: list[tuple[str, str]], inputs: list) -> None:
    """Outputs never overwrite inputs, nor each other (:func:`adfusion.outfiles.refuse_overwrite`,
    the one guard of every command: same file by inode, else by resolved name); a usage
    error naming both."""
    try:
        refuse_overwrite(outputs, inputs)
    except OutputClash as exc:
        raise UsageError(str(exc)) from None


def _new_folder(path: str | None, flag: str) -> None:
    """A folder the command will create (a ROS 2 bag): it must not exist yet — checked
    before any work, not when the writer meets it."""
    if path and os.path.lexists(path):
        raise UsageError(f"{flag} {path} exists: a ROS 2 bag is written as a new folder; "
                         "give a name that does not exist")


def _output_folder(path: str, flag: str = "-o") -> None:
    """A folder the command will write into (created if missing): not an existing file."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"{flag} {path} exists and is not a folder; give a folder name")


def _input_file(path: str, what: str = "input") -> None:
    """An input file named on the command line: it exists and is not a folder (a usage
    error otherwise; what is wrong inside a file is an input problem, exit 1)."""
    if os.path.isdir(path):
        raise UsageError(f"{path}: is a folder, not an {what} file")
    if not os.path.exists(path):
        raise UsageError(f"{path}: no such file")


def describe_error(exc: BaseException) -> str:
    """One line saying what went wrong, for any exception a command can meet.

    >>> describe_error(IsADirectoryError(21, "Is a directory", "out"))
    'out: is a folder, not a file'
    >>> describe_error(MemoryError())
    'out of memory: the request is too large (a shorter --duration, a lower --mag-limit)'
    """
    if isinstance(exc, MemoryError):
        return "out of memory: the request is too large (a shorter --duration, a lower " \
               "--mag-limit)"
    if isinstance(exc, OSError) and exc.filename is None and exc.errno is None and exc.args:
        return " ".join(str(exc).split())  # raised with a message of ours
    if isinstance(exc, OSError) and not isinstance(exc, ValueError):
        name = exc.filename if exc.filename is not None else "output"
        if exc.errno == errno.ENOSPC:
            return f"{name}: no space left on the device"
        if isinstance(exc, IsADirectoryError):
            return f"{name}: is a folder, not a file"
        if isinstance(exc, NotADirectoryError):
            return f"{name}: part of this path is not a folder"
        if isinstance(exc, FileExistsError):
            return f"{name}: exists already"
        if isinstance(exc, FileNotFoundError):
            return f"{name}: no such file or folder"
        if isinstance(exc, PermissionError):
            return f"{name}: permission denied"
        return f"{name}: {exc.strerror or exc}"
    if type(exc).__module__.startswith("cv2"):
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        return "OpenCV: " + (lines[-1] if lines else type(exc).__name__)
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, ValueError | KeyError | TypeError | ArithmeticError | LookupError
                  | PartlyDone):
        if isinstance(exc, ValueError | PartlyDone):
            return text
        return f"{type(exc).__name__}: {text}"
    return (f"internal error: {type(exc).__name__}: {text} (set ADFUSION_DEBUG=1 for the "
            "traceback)")


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors in one line (argparse prints the whole usage block first):
    what is wrong, the closest flag for a misspelt one, and where the flags are listed."""

    def error(self, message: str) -> NoReturn:
        import difflib

        hint = f" (see `{self.prog} --help`)"
        if message.startswith("unrecognized arguments:"):
            words = message.split(":", 1)[1].split()
            flags = [o for a in self._actions for o in a.option_strings]
            for sp in self._subparsers._group_actions if self._subparsers else []:
                for name, sub in getattr(sp, "choices", {}).items():
                    if name in sys.argv[1:2]:
                        flags += [o for a in sub._actions for o in a.option_strings]
            close = [m for w in words if w.startswith("-")
                     for m in difflib.get_close_matches(w, flags, n=1)]
            if close:
                hint = f" (did you mean {close[0]}?)"
        self.exit(2, f"{self.prog}: error: {message}{hint}\n")


def quiet_opencv() -> None:
    """OpenCV logs a failed decode itself (``[ERROR:0@1.1] global grfmt_png.cpp …``) ahead
    of our one-line message: silenced unless the user set ``OPENCV_LOG_LEVEL``."""
    if "OPENCV_LOG_LEVEL" in os.environ:
        return
    os.environ["OPENCV_LOG_LEVEL"] = "OFF"  # read when cv2 is first imported
    cv2 = sys.modules.get("cv2")  # already imported (an in-process caller)
    if cv2 is not None:
        with contextlib.suppress(AttributeError):
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def one_line_warnings(prog: str) -> None:
    """Warnings (a skipped image, a damaged chunk) as ``prog: warning: …`` lines, not Python's
    ``file.py:250: McapReadWarning: …`` plus the source line that raised them."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"{prog}: warning: {message}", file=sys.stderr if file is None else file)

    warnings.showwarning = show


def parse_fov(text: str) -> tuple[float, float]:
    """``--fov``: one value (degrees) or a range ``LO:HI``; (lo, hi) with lo = hi for one.

    >>> parse_fov("12"), parse_fov("8:16")
    ((12.0, 12.0), (8.0, 16.0))
    """
    parts = str(text).split(":")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise UsageError(f"--fov must be degrees (12) or a range LO:HI (8:16), got {text!r}"
                         ) from None
    if len(vals) not in (1, 2) or not all(math.isfinite(v) and 0 < v < 179 for v in vals):
        raise UsageError(f"--fov must be degrees in (0, 179) or LO:HI, got {text!r}")
    lo, hi = (vals[0], vals[0]) if len(vals) == 1 else (vals[0], vals[1])
    if lo > hi:
        raise UsageError(f"--fov LO:HI needs LO ≤ HI, got {text!r}")
    return lo, hi


def _fov_nominal(fov: tuple[float, float]) -> float:
    """The camera model's FOV for ``--fov``: the value, or a range's geometric middle."""
    return math.sqrt(fov[0] * fov[1])


_IMAGE_SUFFIXES = {".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".fits",
                   ".webp"}


def _image_paths(items: Sequence[str]) -> list:
    """The image files named, folders expanded to their images (sorted)."""
    from pathlib import Path

    out = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES)
            if not found:
                raise UsageError(f"no images ({', '.join(sorted(_IMAGE_SUFFIXES))}) in {p}")
            out.extend(found)
        elif not p.exists():
            raise UsageError(f"{p}: no such file")
        else:
            out.append(p)
    return out


def _camera_or_fov(args: argparse.Namespace) -> None:
    """--camera and --fov both name the field of view; which one should win is the user's
    call, so neither does silently (the camera file's focal length fixes it, --fov-error
    widens it)."""
    if getattr(args, "camera", None) and getattr(args, "fov", None) is not None:
        raise UsageError("give --camera or --fov, not both (the camera file's focal length "
                         "fixes the field of view; --fov-error widens it)")


def _julian_year_now() -> float:
    import datetime as dt

    now = dt.datetime.now(dt.UTC)
    j2000 = dt.datetime(2000, 1, 1, 12, tzinfo=dt.UTC)
    return 2000.0 + (now - j2000).total_seconds() / (365.25 * 86400)
