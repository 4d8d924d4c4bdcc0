"""``adfusion export``: a replay's estimates in flight-dynamics formats.
"""

from __future__ import annotations

import argparse

from adfusion.app.commands.args import _new_folder, _outputs_apart
from adfusion.app.errors import UsageError
from adfusion.outfiles import atomic_output


def cmd_export(args: argparse.Namespace) -> int:
    from adfusion.app.export import read_attitude_history, write_acm, write_aem, write_csv

    acm = getattr(args, "acm", None)
    ros2 = getattr(args, "ros2", None)
    if not (args.aem or args.csv or acm or ros2):
        raise UsageError("nothing to export: give --aem FILE, --acm FILE, --csv FILE and/or "
                         "--ros2 DIR")
    _new_folder(ros2, "--ros2")  # checked now, before reading the log
    _outputs_apart([(flag, path) for flag, path in (("--aem", args.aem), ("--acm", acm),
                                                    ("--csv", args.csv), ("--ros2", ros2))
                    if path], [args.log])
    import importlib.util

    if acm and importlib.util.find_spec("ccsds_ndm") is None:
        from adfusion.app.export import ACM_MISSING

        raise UsageError(ACM_MISSING)
    if ros2 and importlib.util.find_spec("rosbags") is None:
        from adfusion.app.export_ros2 import MISSING

        raise UsageError(MISSING)
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
    if ros2:
        from adfusion.app.export_ros2 import write_ros2_estimates

        counts = write_ros2_estimates(history, ros2)
        print(f"ROS 2 bag → {ros2}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for p in history.problems:  # an incomplete or damaged run: exported, and said (exit 1)
        print(f"problem: {p}")
    return 1 if history.problems else 0
