"""``adfusion live``: frames solved as they arrive — a folder being filled, a camera, or a
recording at its recorded pace — recorded to MCAP and shown live in Foxglove.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys

from adfusion.app.commands.args import (
    _camera_or_fov,
    _output_file,
    _outputs_apart,
    positive_float,
)
from adfusion.app.commands.replay import (
    filter_options,
    recording_options,
    replay_options,
    run_options,
)
from adfusion.app.errors import UsageError

SOURCES = """\
SOURCE is one of:
  DIR               a folder another program writes frames into (PNG, TIFF, JPEG, FITS …):
                    each new file is solved once complete (files already there are left
                    alone unless --include-existing)
  0, 1, …           a camera, by OpenCV's index (/dev/video0 is 0)
  rtsp://… http://… a network stream (anything OpenCV's FFmpeg opens)
  '… ! appsink'     a GStreamer pipeline (text with '!'), when OpenCV has GStreamer
  LOG --realtime    a recording (our MCAP log, a ROS 2 bag, a folder with --fps or
                    --timestamps, a video) played at its recorded pace (--speed)

Frames that arrive while one is being solved are dropped (the newest is kept) and counted.
Ctrl-C ends the run; the output is complete. In Foxglove: Open connection → Foxglove
WebSocket → ws://127.0.0.1:8765, and import OUT.layout.json (Layouts → Import from file).
"""


def add_live_parser(sub) -> None:
    """``adfusion live``'s options (``sub``: the command line's subparsers)."""
    lv = sub.add_parser(
        "live", help="solve frames as they arrive (a folder, a camera, a recording at its "
                     "pace), recorded to MCAP and shown live in Foxglove",
        description="Detection, identification and the filter on frames as they arrive; "
                    "the run is recorded to MCAP as a replay is and published on a Foxglove "
                    "WebSocket with the same topics.",
        epilog=SOURCES, formatter_class=argparse.RawDescriptionHelpFormatter)
    lv.add_argument("source", help="a folder being filled, a camera index, a stream URL or "
                    "GStreamer pipeline, or with --realtime a recording (see below)")
    lv.add_argument("-o", "--output", help="output .mcap (without it: "
                    "live-YYYYmmddTHHMMSSZ.mcap in the current folder)")
    g = lv.add_argument_group("input")
    g.add_argument("--imu", metavar="FILE|udp://HOST:PORT", help="gyro/magnetometer lines as "
                   "they come: a CSV file another program appends to (t_s in Unix seconds, "
                   "gyro_x..z rad/s, mag_x..z nT), or UDP datagrams of lines t_s,gx,gy,gz[,mx,"
                   "my,mz]; with --realtime, the recording's IMU file as replay --imu "
                   "(without it: the frames alone, the filter estimates the rate)")
    g.add_argument("--realtime", action="store_true", help="SOURCE is a recording, played at "
                   "its recorded pace (without it: a folder being filled or a camera)")
    g.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                   help="with --realtime: the pace, × the recorded one")
    g.add_argument("--include-existing", action="store_true",
                   help="a folder's files already there are solved too (without it: only "
                        "files that land after the start)")
    recording_options(g)
    run_options(lv, g)
    g = lv.add_argument_group("when it ends (without any: at Ctrl-C or the source's end)")
    g.add_argument("--frames", type=int, metavar="N", help="after N frames solved (without "
                   "it: no count)")
    g.add_argument("--duration", type=positive_float, metavar="S", help="after S seconds "
                   "(without it: no time limit)")
    g.add_argument("--idle", type=positive_float, metavar="S",
                   help="after S seconds without a new frame, once ready (without it: it "
                        "waits)")
    g = lv.add_argument_group("live view and output")
    g.add_argument("--host", default="127.0.0.1", help="the Foxglove WebSocket's address "
                   "(0.0.0.0: every interface)")
    g.add_argument("--port", type=int, default=8765, help="the Foxglove WebSocket's port (0: "
                   "a free one, printed)")
    g.add_argument("--no-view", action="store_true", help="no Foxglove WebSocket (the MCAP "
                   "log only)")
    filter_options(g)
    lv.set_defaults(func=cmd_live)


def _say(text: str) -> None:
    print(f"adfusion live: {text}", file=sys.stderr, flush=True)


def cmd_live(args: argparse.Namespace) -> int:
    from adfusion.app.live import LiveOptions, live
    from adfusion.app.replay.sinks import LayoutSink

    if not args.realtime and (args.fps or args.timestamps or args.start_utc):
        raise UsageError("--fps, --timestamps and --start-utc describe a recording: give "
                         "--realtime (live frames are timed as they arrive)")
    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames {args.frames}: a number of frames, 1 or more")
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: a TCP port, 0–65535 (0: a free one)")
    if not args.realtime:  # a recording may carry its camera model
        _camera_or_fov(args)
        if not (args.camera or args.fov):
            raise UsageError("the lens: give --camera FILE (OpenCV or ROS camera_info YAML, "
                             "or camera.json) or --fov DEG (LO:HI when known roughly)")
    camera = None
    if args.camera:
        from adfusion.app.camera_file import load_camera

        camera = load_camera(args.camera)
    options, _config = replay_options(args, camera)
    out = args.output or dt.datetime.now(dt.UTC).strftime("live-%Y%m%dT%H%M%SZ.mcap")
    _output_file(out)
    _outputs_apart([("-o", out), ("the layout", str(LayoutSink.path_for(out)))],
                   [p for p in (args.imu, args.timestamps, args.config, args.camera) if p])
    live_options = LiveOptions(
        realtime=args.realtime, speed=args.speed, imu=args.imu,
        include_existing=args.include_existing, max_frames=args.frames,
        duration_s=args.duration, idle_s=args.idle,
        view=None if args.no_view else (args.host, args.port),
        input_args={"fps": args.fps, "timestamps": args.timestamps} if args.realtime else None)
    s = live(args.source, out, live_options, options, say=_say)
    print(json.dumps(s.as_dict(), indent=2) if args.json else str(s))
    _say(f"recorded to {out}")
    none_identified = s.frames > 0 and s.identified == 0
    if none_identified:
        print(f"no frame of {s.frames} was identified: check the camera model (--camera or "
              "--fov) and the detection threshold (--sigma)", file=sys.stderr)
    # frames dropped because they came faster than solved are the live record, not a
    # problem: 1 only for an input's problems or nothing identified (docs/live.md)
    return 1 if s.problems or none_identified else 0
