"""``adfusion report``: the report page and plots of a replay.
"""

from __future__ import annotations

import argparse
import sys

from adfusion.app.commands.args import _input_file, _output_folder


def cmd_report(args: argparse.Namespace) -> int:
    from adfusion.app.report import log_assumed, log_problems, report

    _input_file(args.log, "MCAP")
    _output_folder(args.output)
    from adfusion.logs import McapLogReader

    files = report(args.log, args.output, progress=sys.stderr.isatty())
    print("\n".join(str(f) for f in files))
    reader = McapLogReader(args.log, warn=False)
    problems = log_problems(reader)
    for p in problems:
        print(f"problem: {p}")
    for n in log_assumed(reader):
        print(f"note: {n}")
    return 1 if problems else 0
