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
    parse_fov,
)
from adfusion.app.commands.solve import _FOV_TOLERANCE
from adfusion.app.errors import UsageError


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


def _name_times(folder: str):
    """What the image file names of ``folder`` say of the frames' times."""
    from adfusion.logs.name_times import times_from_names
    from adfusion.logs.sources import image_names

    return times_from_names(image_names(folder))


def cmd_replay(args: argparse.Namespace) -> int:
    from adfusion.app.replay import ReplayOptions, replay

    _missing_inputs(args)
    _camera_or_fov(args)
    camera = None
    if args.camera:
        from adfusion.app.camera_file import load_camera

        camera = load_camera(args.camera)
    mount = None
    if args.mount:
        try:
            mount = [float(x) for x in args.mount.replace(" ", "").split(",")]
        except ValueError:
            mount = []
        if len(mount) != 4:
            raise UsageError(f"--mount {args.mount}: give q_body_cam as four numbers w,x,y,z")
    heads = None
    if args.heads:
        try:
            heads = [int(k) for k in args.heads.split(",")]
        except ValueError:
            raise UsageError(f"--heads {args.heads}: camera indices such as 0,2") from None
    if args.start_utc:
        from adfusion.logs.writer import utc_iso

        try:
            utc_iso(args.start_utc)  # checked here: a one-line error before any work
        except ValueError as exc:
            raise UsageError(f"--start-utc: {exc}") from None
    _output_file(args.output)
    # the input itself is checked by the replay (an output that is its input, or whose
    # temporary name is); here the files that come with it
    from adfusion.app.replay.sinks import LayoutSink

    _outputs_apart([("-o", args.output), ("the layout", str(LayoutSink.path_for(args.output)))],
                   [p for p in (args.imu, args.timestamps, args.config, args.camera) if p])
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
                            q_body_cam=mount, start_utc=args.start_utc, sigma=args.sigma,
                            fov_error_deg=fov_error, epoch=args.epoch,
                            exposure_s=args.exposure, arw_rad_sqrt_s=args.gyro_arw,
                            rrw_rad_s_sqrt_s=args.gyro_rrw, heads=heads,
                            imu_offset_s=args.imu_offset)
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
