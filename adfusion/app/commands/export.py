"""``adfusion export``: a replay's estimates in flight-dynamics formats.
"""

from __future__ import annotations

import argparse

from adfusion.app.commands.args import _outputs_apart
from adfusion.app.errors import UsageError
from adfusion.outfiles import atomic_output


def cmd_export(args: argparse.Namespace) -> int:
    from adfusion.app.export import read_attitude_history, write_acm, write_aem, write_csv

    acm = getattr(args, "acm", None)
    if not (args.aem or args.csv or acm):
        raise UsageError("nothing to export: give --aem FILE, --acm FILE and/or --csv FILE")
    _outputs_apart([(flag, path) for flag, path in (("--aem", args.aem), ("--acm", acm),
                                                    ("--csv", args.csv)) if path], [args.log])
    if acm:
        import importlib.util

        if importlib.util.find_spec("ccsds_ndm") is None:
            raise UsageError("--acm needs the ccsds-ndm package: pip install ccsds-ndm")
    history = read_attitude_history(args.log, smoothed=args.smoothed, start_utc=args.start_utc)
    if args.aem:
        with atomic_output(args.aem) as tmp:
            write_aem(history, tmp)
        print(f"AEM: {len(history.t)} attitudes → {args.aem}")
    if acm:
        with atomic_output(acm) as tmp:
            write_acm(history, tmp)
        print(f"ACM: {len(history.t)} attitudes with covariance → {acm}")
    if args.csv:
        with atomic_output(args.csv) as tmp:
            write_csv(history, tmp)
        print(f"CSV: {len(history.t)} rows → {args.csv}")
    for p in history.problems:  # an incomplete or damaged run: exported, and said (exit 1)
        print(f"problem: {p}")
    return 1 if history.problems else 0
