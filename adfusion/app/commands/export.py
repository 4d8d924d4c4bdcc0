"""``adfusion export``: a replay's estimates in flight-dynamics formats.
"""

from __future__ import annotations

import argparse

from adfusion.app.commands.args import _outputs_apart
from adfusion.app.errors import UsageError
from adfusion.outfiles import atomic_output


def cmd_export(args: argparse.Namespace) -> int:
    from adfusion.app.export import read_attitude_history, write_aem, write_csv

    if not (args.aem or args.csv):
        raise UsageError("nothing to export: give --aem FILE and/or --csv FILE")
    _outputs_apart([(flag, path) for flag, path in (("--aem", args.aem), ("--csv", args.csv))
                    if path], [args.log])
    history = read_attitude_history(args.log, smoothed=args.smoothed, start_utc=args.start_utc)
    if args.aem:
        with atomic_output(args.aem) as tmp:
            write_aem(history, tmp)
        print(f"AEM: {len(history.t)} attitudes → {args.aem}")
    if args.csv:
        with atomic_output(args.csv) as tmp:
            write_csv(history, tmp)
        print(f"CSV: {len(history.t)} rows → {args.csv}")
    for p in history.problems:  # an incomplete or damaged run: exported, and said (exit 1)
        print(f"problem: {p}")
    return 1 if history.problems else 0
