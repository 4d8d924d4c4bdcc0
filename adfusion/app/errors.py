"""The command line's error kinds and exit codes — the same for every command.

====  =====================================================================================
code  meaning
====  =====================================================================================
0     done: everything asked for came out, and no input problem was found
1     done in part: a frame not identified, input problems found and reported (the rest
      used, the output recording them), a run that failed after its output was started
      (the output holds what was done, marked ``incomplete``), a full disk or an I/O error
2     nothing done: the command line is wrong, or an input cannot be used at all (a file
      that is absent, not an image, not a log; a camera file of the wrong types; an output
      that is an input or is being written by another run)
====  =====================================================================================

:func:`exit_code` decides it from what a command raised; ``docs/reliability.md`` is the
user's page for it.

Example:
    >>> issubclass(UsageError, ValueError)
    True
    >>> exit_code(UsageError("--fps -1: a frame rate must be positive"))
    2
    >>> exit_code(PartlyDone("no frame could be identified"))
    1
    >>> exit_code(ValueError("frames/a.png: not a PNG, JPEG, TIFF image"))
    2
"""

from __future__ import annotations

import errno
from collections.abc import Sequence
from pathlib import Path

__all__ = ["PartlyDone", "UsageError", "exit_code", "incomplete_output", "mark_incomplete"]


class UsageError(ValueError):
    """The command line is wrong or incomplete — a flag's value, a flag that must be given
    (``--fps`` for a folder, ``--camera`` or ``--fov`` without a camera model), a path
    that names no file, an output that is a folder or the input: exit code 2, like
    argparse's own usage errors (as is an input refused, a ``ValueError``)."""


class PartlyDone(Exception):
    """The command ran, but what it was asked for did not come out — no frame of a
    calibration identified: exit code 1, as ``solve`` for a frame not identified."""


_MARK = "adfusion_incomplete_output"
# a full disk or quota, a file-size limit, an I/O error: the machine's failure
_MACHINE = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EIO})


def mark_incomplete(exc: BaseException, path: str | Path) -> None:
    """Say on ``exc`` that the run it ended had started ``path``, now closed marked
    ``incomplete``: the failure is exit code 1 (done in part), and its message names it."""
    setattr(exc, _MARK, str(path))


def incomplete_output(exc: BaseException) -> str | None:
    """The output ``exc`` left marked ``incomplete`` (:func:`mark_incomplete`), if any."""
    return getattr(exc, _MARK, None)


def exit_code(exc: BaseException, written: Sequence[str] = ()) -> int:
    """The exit code of a command that raised ``exc`` (the table above), having completed
    the outputs ``written`` before (:func:`adfusion.outfiles.written_outputs`): 1 for a
    run that had started or written an output or that was done in part, 2 for an input or
    command line that could not be used (``ValueError``, ``OSError``, ``MemoryError``:
    refused before any output), 1 for a full disk or an I/O error and for anything else (a
    failure of ours; ``ADFUSION_DEBUG=1`` shows where).

    >>> exit_code(ValueError("--csv out: is a folder"), written=["run.aem"])
    1
    """
    if incomplete_output(exc) is not None or isinstance(exc, PartlyDone) or written:
        return 1
    if isinstance(exc, OSError) and exc.errno in _MACHINE:  # the machine failed, not the
        return 1  # input: the same command may work on another disk
    if isinstance(exc, ValueError | OSError | MemoryError):
        return 2
    return 1
