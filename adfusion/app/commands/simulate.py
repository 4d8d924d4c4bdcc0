"""``adfusion simulate``: a simulated flight log (frames, gyro, magnetometer, truth) as MCAP.
"""

from __future__ import annotations

import argparse
import sys
import time

from adfusion.app.commands.args import _new_folder, _output_file, _outputs_apart
from adfusion.app.errors import UsageError


def _scenario(name: str, duration: float, seed: int, render: bool, errors: bool = False):
    from adfusion.sensors import scenarios

    make = scenarios.leo_three_heads if name == "leo3" else getattr(scenarios, name)
    sc = make(duration_s=duration, seed=seed, render=render)
    if errors:
        from adfusion.sensors.errors import with_sensor_errors

        with_sensor_errors(sc)
    return sc


def cmd_simulate(args: argparse.Namespace) -> int:
    from adfusion.app.replay import simulate

    if not args.duration > 0:
        raise UsageError("--duration must be positive")
    if args.ros2 and args.no_render:
        raise UsageError("--ros2 writes camera images: drop --no-render")
    _output_file(args.output)
    if args.ros2:  # checked now, not after the simulation has run
        _new_folder(args.ros2, "--ros2")
        _outputs_apart([("-o", args.output), ("--ros2", args.ros2)], [])
    if args.sensor_errors and args.scenario == "tubsat":
        raise UsageError("--sensor-errors: the tubsat pass has no gyro or magnetometer log")
    if args.scenario == "tubsat":  # its own timeline: contact at 23:06:20 to the target
        from adfusion.app.tubsat_log import simulate_tubsat

        res = simulate_tubsat(args.output, seed=args.seed)
        print(f"tubsat: {'ok' if res.ok else 'not ok: ' + res.reason}; target at "
              f"{res.ref_time:%H:%M:%S} UTC, boresight {res.pointing_error_deg:.2f}° off "
              f"(1σ budget {res.predicted_sigma_deg:.2f}°) → {args.output}")
        return 0 if res.ok else 1
    t0 = time.perf_counter()
    n = simulate(_scenario(args.scenario, args.duration, args.seed, not args.no_render,
                           args.sensor_errors), args.output, progress=sys.stderr.isatty())
    print(f"{args.scenario}: {n} frames, {args.duration:g} s, seed {args.seed} → "
          f"{args.output} ({time.perf_counter() - t0:.1f} s)")
    if args.ros2:
        from adfusion.app.ros2bag import write_ros2_bag

        counts = write_ros2_bag(args.output, args.ros2)
        print(f"ROS 2 bag → {args.ros2}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0
