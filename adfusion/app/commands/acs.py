"""``adfusion acs``: a closed-loop attitude-control run on Basilisk.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections.abc import Iterator

from adfusion.app.errors import UsageError


@contextlib.contextmanager
def _c_stdout_to_stderr() -> Iterator[None]:
    """File descriptor 1 points at stderr for the block (what C and C++ code print there
    too), then back. Where that cannot be done (no stdout, a closed descriptor, no C
    library to flush) the block runs as it is."""
    try:
        import ctypes

        fflush = ctypes.CDLL(None).fflush
        if sys.stdout is not None:
            sys.stdout.flush()
        fflush(None)
        saved = os.dup(1)
    except (OSError, TypeError, AttributeError, ValueError):
        yield
        return
    try:
        os.dup2(2, 1)
        yield
    finally:
        if sys.stdout is not None:
            sys.stdout.flush()
        fflush(None)
        os.dup2(saved, 1)
        os.close(saved)


def cmd_acs(args: argparse.Namespace) -> int:
    try:
        from adfusion.basilisk.acs import run_acs
    except ModuleNotFoundError as e:
        if (e.name or "").split(".")[0] != "Basilisk":
            raise
        raise ValueError("Basilisk is not installed: pip install 'adfusion[bsk]'") from None
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise UsageError("--duration must be a finite number > 0")
    from adfusion.basilisk.scenarios import SCENARIOS

    if args.scenario not in SCENARIOS:
        raise UsageError(f"unknown scenario {args.scenario!r}; choose one of "
                         f"{sorted(SCENARIOS)}")
    t0 = time.perf_counter()

    def progress(line: str) -> None:
        print(f"{line} …", file=sys.stderr, flush=True)

    # Basilisk's C++ layer prints its start-up notes (a message read before its first write,
    # a recorder on a message not yet written) on the process's stdout: they go to stderr,
    # so that stdout holds the report, and --json valid JSON
    with _c_stdout_to_stderr():
        rep = run_acs(args.scenario, args.output, seed=args.seed, duration_s=args.duration,
                      images=args.images, progress=progress)
    print(json.dumps(rep.as_dict(), indent=2) if args.json else rep.table())
    print(f"→ {args.output} and its report ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0
