"""``adfusion bench``: the benchmark harness's commands, run from the command line.
"""

from __future__ import annotations

import argparse


def _run_bench(module, args: argparse.Namespace) -> int:
    module.run(args)
    return 0
