"""The ``adfusion`` command line.

The parser and the dispatch; each sub-command lives in its own module of
:mod:`adfusion.app.commands`, where heavy imports happen inside the command so that
``adfusion --help`` is instant.

Example:
    >>> from adfusion.app.cli import build_parser
    >>> sorted(build_parser()._subparsers._group_actions[0].choices)[:5]
    ['acs', 'bench', 'cache', 'calibrate', 'catalog']
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from adfusion.app.commands.acs import cmd_acs
from adfusion.app.commands.args import (
    OneLineParser,
    describe_error,
    finite_float,
    image_path,
    magnitude_limit,
    non_negative_float,
    one_line_warnings,
    positive_float,
    quiet_opencv,
)
from adfusion.app.commands.bench import _run_bench
from adfusion.app.commands.cache import cmd_cache
from adfusion.app.commands.calibrate import cmd_calibrate
from adfusion.app.commands.catalog import cmd_catalog
from adfusion.app.commands.demo import cmd_demo
from adfusion.app.commands.detect import cmd_detect
from adfusion.app.commands.export import cmd_export
from adfusion.app.commands.live import add_live_parser
from adfusion.app.commands.replay import add_replay_parser
from adfusion.app.commands.report import cmd_report
from adfusion.app.commands.simulate import cmd_simulate
from adfusion.app.commands.solve import cmd_solve
from adfusion.app.errors import UsageError, exit_code, incomplete_output
from adfusion.outfiles import OutputBusy, OutputClash, forget_written, written_outputs


def build_parser(bench: bool = True) -> argparse.ArgumentParser:
    """The whole command line. ``bench=False`` leaves out the benchmark commands' own
    arguments, whose modules import numpy and OpenCV (``adfusion --help`` stays instant)."""
    p = OneLineParser(
        prog="adfusion",
        description="Star-camera attitude determination: detection, identification, fusion.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    d = sub.add_parser("detect", help="find stars in an image (or the built-in example)")
    d.add_argument("image", nargs="?", help="image file (TIFF, PNG, JPEG)")
    d.add_argument("--example", action="store_true",
                   help="render and use the built-in synthetic example frame")
    d.add_argument("--sigma", type=positive_float, default=5.0,
                   help="threshold in noise sigmas")
    d.add_argument("--max", type=int, default=20, help="rows to print (default 20)")
    d.add_argument("--json", action="store_true", help="print JSON instead of a table")
    d.set_defaults(func=cmd_detect)

    s = sub.add_parser("solve", help="identify the stars of images: attitude, lost in space",
                       description="Identify the stars of one image, many, or every image "
                       "of a folder (loaded once, solved in turn with a progress bar).")
    s.add_argument("images", nargs="*", metavar="IMAGE",
                   help="image files (TIFF, PNG, JPEG) or folders of them")
    s.add_argument("--example", action="store_true",
                   help="render and solve the built-in synthetic example frame")
    s.add_argument("--fov", metavar="DEG|LO:HI",
                   help="horizontal field of view, degrees: an estimate (12, with "
                        "--fov-error) or a range LO:HI (8:16; the camera is then fitted); "
                        "without it, --camera is needed")
    s.add_argument("--fov-error", type=non_negative_float, default=0.0,
                   help="± uncertainty of --fov, degrees (default 0: known)")
    s.add_argument("--camera", metavar="YAML",
                   help="OpenCV camera file (e.g. from `adfusion calibrate`) instead of --fov "
                        "(without it: a pinhole camera of the image's size and --fov)")
    s.add_argument("--mag-limit", type=magnitude_limit, default=6.5,
                   help="catalogue limit, estimated Johnson V (default 6.5)")
    s.add_argument("--stars-per-fov", type=int, default=None,
                   help="deep catalogues: keep the brightest N stars per field-sized patch "
                        "of sky (default: 30, applied when the catalogue holds more)")
    s.add_argument("--epoch", type=finite_float, default=None,
                   help="observation epoch, Julian year (default: now)")
    s.add_argument("--method", choices=["nstar", "triad", "bleif"], default="nstar",
                   help="lost-in-space method: Renken's n-star patterns, Yee's triads, or "
                        "Bleif's reference-star matcher (default nstar)")
    s.add_argument("--sigma", type=positive_float, default=5.0,
                   help="detection threshold, sigmas")
    s.add_argument("--overlay", metavar="PNG", type=image_path,
                   help="write an overlay image (one image only; .png, .jpg, .tif, ...; "
                        "default: none)")
    s.add_argument("-o", "--out-dir", metavar="DIR",
                   help="write <image>.json per image here (and .wcs / .corr if asked; "
                        "without it: printed only, or with --wcs / --corr all three into .)")
    s.add_argument("--wcs", action="store_true",
                   help="write <image>.wcs: FITS TAN-SIP header (into --out-dir, default .)")
    s.add_argument("--corr", action="store_true",
                   help="write <image>.corr: FITS table of the matched stars")
    s.add_argument("--json", action="store_true", help="print JSON instead of text")
    s.set_defaults(func=cmd_solve)

    ca = sub.add_parser("cache", help="the on-disk cache of catalogues and pattern indexes")
    ca.add_argument("action", choices=["info", "clear"],
                    help="info: where the cache is and what it holds; clear: empty it")
    ca.add_argument("--kind", help="clear only entries of this kind (e.g. pattern-index; "
                    "default: every kind)")
    ca.add_argument("--json", action="store_true", help="print JSON instead of text")
    ca.set_defaults(func=cmd_cache)

    cb = sub.add_parser("calibrate", help="fit a camera (focal length, principal point, "
                        "distortion) jointly over many frames → OpenCV camera YAML")
    cb.add_argument("images", nargs="+", metavar="FRAME",
                    help="image files or folders, one camera, same size")
    cb.add_argument("-o", "--output", required=True, metavar="YAML",
                    help="camera file to write (accepted by --camera)")
    cb.add_argument("--fov", metavar="DEG|LO:HI",
                    help="horizontal field of view, degrees: an estimate or a range LO:HI "
                         "(without it, --camera is needed)")
    cb.add_argument("--fov-error", type=float, default=None,
                    help="± uncertainty of --fov, degrees (default 5 %% of the FOV)")
    cb.add_argument("--camera", metavar="YAML", help="starting camera instead of --fov "
                    "(without it: a pinhole camera of the frames' size and --fov)")
    cb.add_argument("--mag-limit", type=float, default=7.5,
                    help="catalogue limit for the fit's stars (default 7.5)")
    cb.add_argument("--epoch", type=float, default=None,
                    help="observation epoch, Julian year (default: now)")
    cb.add_argument("--sigma", type=float, default=5.0, help="detection threshold, sigmas")
    cb.add_argument("--terms", default="focal,principal,k1,k2,tangential",
                    help="what to fit, comma-separated from focal, principal, aspect, k1, k2, "
                         "tangential (default: all but aspect), or 'auto' (chosen by BIC)")
    cb.add_argument("--json", action="store_true", help="print JSON instead of text")
    cb.set_defaults(func=cmd_calibrate)

    sm = sub.add_parser("simulate", help="simulate a flight into an MCAP log (oedipus, leo, "
                        "leo3: three star-tracker heads 90° apart, tubsat: Bleif's night "
                        "pass to Berlin)")
    sm.add_argument("scenario", choices=["oedipus", "leo", "leo3", "tubsat"],
                    help="the flight to simulate (see above)")
    sm.add_argument("-o", "--output", required=True, help="output .mcap")
    sm.add_argument("--duration", type=positive_float, default=60.0,
                    help="seconds (default 60)")
    sm.add_argument("--seed", type=int, default=0,
                    help="seed of every noise source (default 0)")
    sm.add_argument("--no-render", action="store_true",
                    help="write star centroids instead of rendered images (fast)")
    sm.add_argument("--sensor-errors", action="store_true",
                    help="random magnetometer hard/soft iron and gyro scale/misalignment of "
                         "the seed, stated in the log's config (sensor_errors) for a "
                         "calibration to find")
    sm.add_argument("--ros2", metavar="DIR", help="also write the flight as a ROS 2 bag "
                    "(a rosbag2 folder, MCAP storage; Image + CameraInfo + Imu + "
                    "MagneticField) with rosbags; default: the MCAP log only)")
    sm.set_defaults(func=cmd_simulate)

    add_replay_parser(sub)
    add_live_parser(sub)

    ex = sub.add_parser("export", help="flight-dynamics products of a replayed log (AEM, ACM, "
                        "CSV, ROS 2 bag)")
    ex.add_argument("log", help="a replayed .mcap")
    ex.add_argument("--aem", metavar="FILE", help="CCSDS Attitude Ephemeris Message (KVN); "
                    "default: none (give at least one of --aem, --acm, --csv, --ros2)")
    ex.add_argument("--acm", metavar="FILE", help="CCSDS Attitude Comprehensive Message 2.0 "
                    "(XML): quaternion, gyro bias or rate, covariance; needs ccsds-ndm; "
                    "default: none")
    ex.add_argument("--csv", metavar="FILE", help="CSV: UTC, quaternion, RA/Dec/roll, 1σ, "
                    "mode, stars; default: none")
    ex.add_argument("--ros2", metavar="DIR", help="ROS 2 bag (a new folder, MCAP storage): "
                    "per estimate sensor_msgs/Imu on /adfusion/imu and "
                    "PoseWithCovarianceStamped on /adfusion/pose, orientation of body in "
                    "icrs with its covariance; needs rosbags; default: none")
    ex.add_argument("--smoothed", action="store_true", help="export /smoothed/state instead "
                    "of the filter's /estimate/state")
    ex.add_argument("--start-utc", metavar="TIME", help="UTC of the log's t = 0 (ISO 8601), "
                    "for a log that does not know it (an acs run, a replay without "
                    "--start-utc; default: the log's own)")
    ex.set_defaults(func=cmd_export)

    tp = sub.add_parser("topics", help="the log topics: schema, fields, units, frame")
    tp.add_argument("--markdown", action="store_true", help="as a Markdown table")
    tp.set_defaults(func=lambda a: __import__("adfusion.logs.topics", fromlist=["main"]).main(
        ["--markdown"] if a.markdown else []))

    rq = sub.add_parser("report", help="plots and a summary of a replayed log")
    rq.add_argument("log", help="a replayed .mcap")
    rq.add_argument("-o", "--output", required=True, help="output folder")
    rq.set_defaults(func=cmd_report)

    dm = sub.add_parser("demo", help="simulate a short OEDIPUS-like flight, replay it, report")
    dm.add_argument("-o", "--output", default="adfusion-demo", help="folder (default "
                    "./adfusion-demo)")
    dm.add_argument("--duration", type=positive_float, default=20.0,
                    help="seconds (default 20)")
    dm.set_defaults(func=cmd_demo)

    b = sub.add_parser("bench", help="benchmarks against the peers (tetra3rs, cedar-solve)")
    bsub = b.add_subparsers(dest="bench", metavar="BENCH", required=True)
    bs = bsub.add_parser("starid", help="lost-in-space identification: ours vs the peers")
    sw = bsub.add_parser("sweep", help="robustness sweeps vs the peers (dask campaigns)")
    if bench:
        from adfusion.bench import starid as bench_starid
        from adfusion.bench import sweep as bench_sweep

        bench_starid.add_arguments(bs)
        bs.set_defaults(func=lambda a: _run_bench(bench_starid, a))
        bench_sweep.add_arguments(sw)
        sw.set_defaults(func=bench_sweep.cli)

    a = sub.add_parser("acs", help="closed-loop attitude control on Basilisk, camera in the "
                       "loop (needs the bsk extra)")
    a.add_argument("scenario", help="leo, slew, outage or misaligned")
    a.add_argument("-o", "--output", required=True, help="MCAP log; the report is written "
                   "beside it (.report.md, .report.json, .png)")
    a.add_argument("--seed", type=int, default=0, help="seed of every noise source (default 0)")
    a.add_argument("--duration", type=float, default=None, help="seconds (default: the "
                   "scenario's, 600)")
    a.add_argument("--images", choices=("preview", "all"), default="preview",
                   help="log every frame's image, or one in 40 with every frame's centroids "
                   "(default preview)")
    a.add_argument("--json", action="store_true", help="print the report as JSON")
    a.set_defaults(func=cmd_acs)

    c = sub.add_parser("catalog", help="star counts of the built-in catalogues per magnitude")
    c.add_argument("--json", action="store_true", help="print JSON instead of a table")
    c.set_defaults(func=cmd_catalog)
    _say_defaults(p)
    return p


def _say_defaults(parser: argparse.ArgumentParser) -> None:
    """Every option's help ends with its default when it has one the help does not name
    already (the command line says everything it knows)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _say_defaults(sub)
        elif (action.option_strings and action.help and action.help != argparse.SUPPRESS
              and action.default not in (None, False, True, argparse.SUPPRESS)
              and "default" not in action.help and "%(default)" not in action.help):
            action.help += " (default: %(default)s)"


class _PipeGuard:
    """Standard output that a closed pipe cannot turn into an exit status: ``adfusion solve
    BAD | head -1`` exited 0, because the write that met the closed pipe ended the command
    before its own status. Once the reader has gone, the rest of the output goes to
    ``/dev/null`` (the reader asked for no more of it) and the command ends as it would
    have: 0, 1 or 2."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.broken = False

    @classmethod
    def install(cls) -> None:
        import stat

        out = sys.stdout
        if isinstance(out, cls):
            return
        try:
            if not stat.S_ISFIFO(os.fstat(out.fileno()).st_mode):
                return  # a terminal, a file, a test's capture: nothing to guard
        except (AttributeError, OSError, ValueError):
            return
        sys.stdout = cls(out)

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._to_devnull()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._to_devnull()

    def _to_devnull(self) -> None:
        self.broken = True
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, self._stream.fileno())  # Python's own flush at exit finds no pipe
        os.close(null)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``adfusion`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    quiet_opencv()
    try:
        args = build_parser(bench=bool(argv) and argv[0] == "bench").parse_args(argv)
    except SystemExit as e:  # --help (0) or a usage error (2), already printed by argparse
        return e.code if isinstance(e.code, int) else 2
    one_line_warnings(f"adfusion {args.command}")
    _PipeGuard.install()
    # One handler for every command: a failure is one line on stderr and an exit code —
    # 0 done, 1 done in part, 2 nothing done (usage or an unusable input): errors.exit_code
    forget_written()
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # a write past the guard (not through sys.stdout) met the
        return 0  # closed pipe: the reader asked for no more
    except KeyboardInterrupt as e:
        out = incomplete_output(e)
        print(f"adfusion {args.command}: interrupted"
              + (f" ({out} holds what was done before, marked incomplete)" if out else ""),
              file=sys.stderr)
        return 130
    except Exception as e:
        if os.environ.get("ADFUSION_DEBUG") and not isinstance(e, UsageError | OutputClash
                                                                 | OutputBusy):
            raise
        said = describe_error(e)
        out, written = incomplete_output(e), written_outputs()
        if out is not None:
            said += f" ({out} holds what was done before, marked incomplete)"
        elif written:  # done in part: say what is there
            from adfusion.plain import listed  # numpy: not for --help

            said += f" (written before it: {listed(written)})"
        print(f"adfusion {args.command}: error: {said}", file=sys.stderr)
        return exit_code(e, written)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
