"""``adfusion replay``: a flight log, folder, video or bag through detection, identification
and the filter, recorded to MCAP.
"""

from __future__ import annotations

import argparse
import json
import sys

from adfusion.app.commands.args import (
    _camera_or_fov,
    _input_file,
    _output_file,
    _outputs_apart,
    finite_float,
    magnitude_limit,
    parse_fov,
    positive_float,
)
from adfusion.app.commands.solve import _FOV_TOLERANCE
from adfusion.app.errors import UsageError


def add_replay_parser(sub) -> None:
    """``adfusion replay``'s options (``sub``: the command line's subparsers)."""
    rp = sub.add_parser(
        "replay", help="detect → identify → filter a log, a ROS 2 bag, images or a video",
        description="Replay INPUT — one of our MCAP logs, a ROS 2 bag in MCAP (a rosbag2 "
                    "folder or its .mcap), a folder of images, or a video file — through "
                    "detection, identification and the filter into an MCAP log (with "
                    "OUT.layout.json for Foxglove beside it).")
    rp.add_argument("input", help="MCAP log, ROS 2 bag, image folder or video file")
    rp.add_argument("-o", "--output", required=True, help="output .mcap")
    g = rp.add_argument_group("input")
    g.add_argument("--imu", metavar="FILE", help="gyro/magnetometer samples: CSV (t_s, "
                   "gyro_x..z rad/s, mag_x..z nT) or a PX4 ULog (.ulg); without it: the "
                   "input's own, else the frames alone (the filter estimates the rate)")
    g.add_argument("--imu-offset", type=finite_float, default=0.0, metavar="S",
                   help="seconds added to every gyro and magnetometer time, to put the IMU's "
                        "clock on the frames' (the replay's 'gyro clock' problem says by how "
                        "much)")
    recording_options(g)
    g.add_argument("--heads", metavar="K,K", help="cameras of a several-camera log to fuse "
                   "(default all; e.g. 0 for the first alone)")
    g.add_argument("--image-topic", help="ROS 2 bag: the image topic (default: by type)")
    g.add_argument("--imu-topic", help="ROS 2 bag: the Imu topic (default: by type)")
    g.add_argument("--mag-topic", help="ROS 2 bag: the MagneticField topic (default: by type)")
    run_options(rp, g)
    g = rp.add_argument_group("filter and output")
    filter_options(g)
    g.add_argument("--compression", choices=["auto", "lz4", "zstd", "none"], default="auto",
                   help="output chunk compression (default auto: none for logs with camera "
                        "images — noisy video gains 2 %% — else lz4; zstd: smallest)")
    g.add_argument("--smooth", action="store_true",
                   help="also smooth the whole log (GTSAM) into /smoothed/state and "
                        "/smoothed/pose")
    g.add_argument("--smoother", choices=["batch", "isam2"], default="batch",
                   help="with --smooth: Levenberg–Marquardt batch (default) or iSAM2")
    rp.set_defaults(func=cmd_replay)


def recording_options(g) -> None:
    """A recording's times: ``--fps``, ``--timestamps``, ``--start-utc`` (replay, and live
    ``--realtime``)."""
    g.add_argument("--fps", type=positive_float, help="frame rate of a folder or video (frame i at "
                   "i/fps s; without it: --timestamps, the times in the file names, or the "
                   "video's own rate)")
    g.add_argument("--timestamps", metavar="CSV", help="frame times of a folder: CSV with "
                   "columns filename,t_s (without it: --fps or the times in the file names)")
    g.add_argument("--start-utc", metavar="TIME", help="UTC time of t = 0 (ISO 8601, e.g. "
                   "1995-11-07T08:07:00Z): log times in UTC (without it: the input's or "
                   "its file names', else times from 0 s; export then asks for it)")


def run_options(parser, g) -> None:
    """The camera, mounting, noise and detection options of every run on frames (replay and
    live): ``g`` is the input group, the detection group is added to ``parser``."""
    g.add_argument("--camera", metavar="FILE", help="camera model: OpenCV camera YAML, ROS "
                   "camera_info YAML, or camera.json (without it: the input's, else --fov)")
    g.add_argument("--fov", metavar="DEG|LO:HI", help="horizontal field of view (a "
                   "pinhole camera of the frame size) when there is no camera model: degrees "
                   "or a range LO:HI, searched for lost-in-space (without it: the input's "
                   "camera model or --camera)")
    g.add_argument("--mount", metavar="W,X,Y,Z", help="camera mounting q_body_cam (rotates "
                   "camera vectors into the body frame), scalar first (without it: the "
                   "input's configuration, --config, or --assume-defaults' identity)")
    g.add_argument("--exposure", type=float, metavar="S", help="camera exposure, seconds "
                   "(tracking models the motion smear; default: the log's)")
    g.add_argument("--gyro-arw", type=float, metavar="RAD/√S", help="gyro angle random walk "
                   "(default: the log's, else 1e-4)")
    g.add_argument("--gyro-rrw", type=float, metavar="RAD/S/√S", help="gyro rate random walk"
                   " (default: the log's, else 1e-6)")
    g.add_argument("--config", metavar="JSON",
                   help="the run configuration (q_body_cam, gyro noise, camera, mag_limit) "
                        "for a log that lacks its config metadata (without it: the log's, "
                        "else --mount or --assume-defaults)")
    g.add_argument("--assume-defaults", action="store_true",
                   help="replay a log without configuration with an identity camera mount "
                        "and default noise (recorded in the output)")
    g = parser.add_argument_group("detection and identification")
    g.add_argument("--sigma", type=float, help="detection threshold, noise sigmas (default 5)")
    g.add_argument("--fov-error", type=float, default=0.0, metavar="DEG",
                   help="± uncertainty of the field of view for lost-in-space (default 0)")
    g.add_argument("--mag-limit", type=magnitude_limit, default=None,
                   help="catalogue limit, V (default: the log's, else 6.5, as solve)")
    g.add_argument("--epoch", type=float, help="catalogue epoch, Julian year (default: the "
                   "log's, else its start time's, else 2000)")


def filter_options(g) -> None:
    """``--no-gyro``, ``--no-mag``, ``--json`` (replay and live)."""
    g.add_argument("--no-gyro", action="store_true", help="ignore the gyro (video only: the "
                   "filter estimates the rate)")
    g.add_argument("--no-mag", action="store_true", help="ignore the magnetometer")
    g.add_argument("--json", action="store_true", help="print the summary as JSON")


def _missing_inputs(args: argparse.Namespace) -> None:
    """Everything a folder of frames (or a video) lacks, said at once: a folder replay
    took three failed tries, each naming one missing flag (new-user trial)."""
    import os

    from adfusion.app.replay.sources import VIDEO_SUFFIXES, is_ros2_bag

    path = args.input
    folder = os.path.isdir(path) and not is_ros2_bag(path)
    video = os.path.isfile(path) and path.lower().endswith(tuple(VIDEO_SUFFIXES))
    if not (folder or video):
        return  # a log or a bag carries its times, camera and configuration
    for flag, file in (("--imu", args.imu), ("--camera", args.camera),
                       ("--timestamps", args.timestamps), ("--config", args.config)):
        if file and not os.path.exists(file):  # a file named but absent, before what it
            raise FileNotFoundError(f"{flag} {file}: no such file")  # would have given
    missing = []
    named = _name_times(path) if folder and not args.timestamps else None
    if folder and not (args.fps or args.timestamps) and named.why:
        missing.append("the frames' times: give --fps HZ or --timestamps CSV (filename,t_s); "
                       f"the file names give none ({named.why})")
    if not (args.camera or args.fov):
        missing.append("the lens: give --camera FILE or --fov DEG (LO:HI when known roughly)")
    if args.imu and not (args.mount or args.config or args.assume_defaults):
        missing.append("how the camera sits on the IMU's body and the gyro's noise: give --mount "
                       "w,x,y,z, --config FILE.json or --assume-defaults")
    if missing:
        later = ("" if args.start_utc or (named is not None and not named.why) else
                 "; and for `adfusion export` later, --start-utc TIME (the UTC of t = 0)")
        raise UsageError(f"{path}: a {'folder of frames' if folder else 'video'} needs "
                         + "; ".join(missing) + later)
    if named is not None and not named.why and not args.start_utc:
        # said, not silent: names written on local time would shift every UTC
        what = "the UTC of t = 0" if args.fps else (
            f"frame times ({len(named.t_s)} frames over {max(named.t_s):.6g} s)")
        print(f"adfusion replay: {what} from the file names, from {named.start_utc}"
              + ("" if named.zoned else " (read as UTC: give --start-utc if they are local "
                 "time)"), file=sys.stderr)


def replay_options(args: argparse.Namespace, camera=None):
    """``(ReplayOptions, config)`` of the command line (replay's, or live's, which has no
    ``--heads`` nor ``--imu-offset``): every value checked, a one-line usage error naming
    the flag before any work."""
    from adfusion.app.replay import ReplayOptions

    mount = None
    if args.mount:
        try:
            mount = [float(x) for x in args.mount.replace(" ", "").split(",")]
        except ValueError:
            mount = []
        if len(mount) != 4:
            raise UsageError(f"--mount {args.mount}: give q_body_cam as four numbers w,x,y,z")
    heads = None
    if getattr(args, "heads", None):
        try:
            heads = [int(k) for k in args.heads.split(",")]
        except ValueError:
            raise UsageError(f"--heads {args.heads}: camera indices such as 0,2") from None
    start_utc = getattr(args, "start_utc", None)
    if start_utc:
        from adfusion.logs.writer import utc_iso

        try:
            utc_iso(start_utc)  # checked here: a one-line error before any work
        except ValueError as exc:
            raise UsageError(f"--start-utc: {exc}") from None
    config = None
    if args.config:
        _input_file(args.config, "JSON")
        try:
            with open(args.config, encoding="utf-8") as f:
                config = json.load(f)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{args.config}: not a JSON file ({exc})") from None
        if not isinstance(config, dict):
            raise ValueError(f"{args.config}: the configuration must be a JSON object")
    fov_deg, fov_error = None, args.fov_error
    if args.fov is not None:
        lo, hi = parse_fov(args.fov)
        if lo < hi and args.fov_error:
            raise UsageError("give --fov LO:HI or --fov-error, not both")
        fov_deg = 0.5 * (lo + hi)
        fov_error = 0.5 * (hi - lo) if lo < hi else args.fov_error
    options = ReplayOptions(use_gyro=not args.no_gyro, use_mag=not args.no_mag,
                            mag_limit=args.mag_limit, camera=camera, fov_deg=fov_deg,
                            q_body_cam=mount, start_utc=start_utc, sigma=args.sigma,
                            fov_error_deg=fov_error, epoch=args.epoch,
                            exposure_s=args.exposure, arw_rad_sqrt_s=args.gyro_arw,
                            rrw_rad_s_sqrt_s=args.gyro_rrw, heads=heads,
                            imu_offset_s=getattr(args, "imu_offset", 0.0), config=config,
                            assume_defaults=args.assume_defaults)
    return options, config


def _name_times(folder: str):
    """What the image file names of ``folder`` say of the frames' times."""
    from adfusion.logs.name_times import times_from_names
    from adfusion.logs.sources import image_names

    return times_from_names(image_names(folder))


def cmd_replay(args: argparse.Namespace) -> int:
    from adfusion.app.replay import replay

    _missing_inputs(args)
    _camera_or_fov(args)
    camera = None
    if args.camera:
        from adfusion.app.camera_file import load_camera

        camera = load_camera(args.camera)
    options, config = replay_options(args, camera)
    _output_file(args.output)
    # the input itself is checked by the replay (an output that is its input, or whose
    # temporary name is); here the files that come with it
    from adfusion.app.replay.sinks import LayoutSink

    _outputs_apart([("-o", args.output), ("the layout", str(LayoutSink.path_for(args.output)))],
                   [p for p in (args.imu, args.timestamps, args.config, args.camera) if p])
    s = replay(args.input, args.output, options=options, progress=sys.stderr.isatty(),
               smooth=args.smooth, smooth_mode=args.smoother, compression=args.compression,
               fps=args.fps, timestamps=args.timestamps, imu=args.imu,
               image_topic=args.image_topic, imu_topic=args.imu_topic,
               mag_topic=args.mag_topic, config=config,
               assume_defaults=args.assume_defaults)
    print(json.dumps(s.as_dict(), indent=2) if args.json else str(s))
    none_identified = s.frames > 0 and s.identified == 0
    if none_identified:  # a replay with no fix at all is a failure, not a quiet success
        why = (_FOV_TOLERANCE if args.fov is not None else
               "check the camera model (--camera), the mounting and the detection threshold "
               "(--sigma); `adfusion solve FRAME` on one frame says what it found")
        print(f"no frame of {s.frames} was identified: {why}", file=sys.stderr)
    # the output is written either way; 1 says it carries problems (listed above)
    return 1 if s.smoother.get("error") or s.problems or none_identified else 0
