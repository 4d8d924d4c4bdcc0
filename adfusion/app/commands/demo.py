"""``adfusion demo``: simulate a flight, replay it and write its report, on built-in defaults.
"""

from __future__ import annotations

import argparse
import sys
import time

from adfusion.app.commands.args import _output_folder
from adfusion.app.commands.simulate import _scenario


def cmd_demo(args: argparse.Namespace) -> int:
    from pathlib import Path

    from adfusion.app.replay import replay, simulate
    from adfusion.app.report import report

    _output_folder(args.output)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sim, rep = out / "flight.mcap", out / "replay.mcap"
    n = simulate(_scenario("oedipus", args.duration, 0, True), sim,
                 progress=sys.stderr.isatty())
    print(f"simulated an OEDIPUS-C-like flight: {n} intensified frames + gyro + magnetometer "
          f"→ {sim} ({time.perf_counter() - t0:.1f} s)")
    s = replay(sim, rep, progress=sys.stderr.isatty())
    print(f"replayed → {rep}\n{s}")
    files = report(rep, out / "report", progress=sys.stderr.isatty())
    print(f"report → {files[-1]} (+{len(files) - 2} plots); open {rep} in Foxglove with "
          f"{rep.with_name(rep.stem + '.layout.json')}\n"
          f"total {time.perf_counter() - t0:.1f} s")
    return 0
