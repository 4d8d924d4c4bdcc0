"""Latency of ``adfusion live``: a frame on disk → its estimate received by a Foxglove
client, for 1 Mpx frames in tracking.

``python -P benchmarks/bench_live.py`` runs ``adfusion live DIR`` as a user would (its own
process, the Foxglove WebSocket on), writes rendered 1024×1024 frames of a slowly turning
sky into DIR at ``--rate`` frames a second (each written under a hidden name and renamed:
the moment of the rename is "on disk"), and receives ``/estimate/state`` with a client of
the Foxglove protocol written here (``websockets``). The latency of frame k is the client's
receipt of estimate k minus the rename of file k (one machine clock, ``time.time``); the
run's own figure (arrival seen → estimate published, ``/live/status``) is reported beside
it. One run per file format (PNG, uncompressed TIFF, PGM). JSON out
(``benchmarks/results/live.json``); ``benchmarks/figures.py`` puts it on the benchmark page.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
from adfusion.sensors.render import render_sky
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog

from adfusion.maths import rotations as rot

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "live.json"


def frames(n: int, size: int, fov_deg: float) -> tuple[Camera, list[np.ndarray], list[int]]:
    """``n`` frames of a sky turning 0.05° a frame (tracking keeps them), and the stars in
    each."""
    cam = Camera.pinhole(size, size, fov_deg)
    cat = Catalog.hipparcos(mag_limit=6.5)
    q0 = rot.q_cam_icrs_from_radec_roll(np.radians(84.0), np.radians(-2.0), 0.3)
    images, stars = [], []
    for k in range(n):
        q = rot.multiply(rot.exp_map(np.radians([0.03 * k, 0.02 * k, 0.03 * k])), q0)
        img, xy, _ = render_sky(cam, q, cat.vectors, cat.mag, seed=k)
        images.append(img)
        stars.append(len(xy))
    return cam, images, stars


class _Estimates:
    """Receipt times of ``/estimate/state`` on a Foxglove WebSocket."""

    def __init__(self, url: str) -> None:
        self.url, self.times = url, []
        self.ops: list[str] = []  # what the server said (shown when nothing came)

        self.ready = threading.Event()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self.thread.start()

    async def _main(self) -> None:
        import websockets

        async with websockets.connect(self.url, subprotocols=["foxglove.sdk.v1"],
                                      max_size=None) as ws:
            wanted = None
            while not self.stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.1)
                except TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    return
                if isinstance(msg, str):
                    op = json.loads(msg)
                    self.ops.append(op["op"] if op["op"] != "status" else
                                    f"status: {op.get('message')}")
                    for ch in op.get("channels", []) if op["op"] == "advertise" else []:
                        # once: a channel can be advertised twice (created as we connected)
                        if ch["topic"] == "/estimate/state" and wanted is None:
                            wanted = ch["id"]
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": 1, "channelId": wanted}]}))
                            self.ready.set()
                elif msg[0] == 0x01 and struct.unpack_from("<I", msg, 1)[0] == 1:
                    self.times.append(time.time())


def _live(folder: Path, camera: Path, out: Path) -> tuple[subprocess.Popen, list[str]]:
    proc = subprocess.Popen(
        [sys.executable, "-P", "-m", "adfusion", "live", str(folder), "--camera", str(camera),
         "--port", "0", "--idle", "3", "--json", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")),
                     daemon=True).start()
    return proc, lines


def _wait(lines: list[str], text: str, proc: subprocess.Popen, timeout: float = 300) -> str:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        for line in list(lines):
            if text in line:
                return line
        if proc.poll() is not None:
            raise SystemExit("adfusion live ended: " + "".join(lines))
        time.sleep(0.02)
    raise SystemExit(f"no {text!r} from adfusion live: " + "".join(lines))


def run_format(fmt: str, cam: Camera, images: list[np.ndarray], rate_hz: float) -> dict:
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        folder = d / "in"
        folder.mkdir()
        camera = d / "camera.json"
        camera.write_text(json.dumps(cam.to_dict()))
        encoded = [cv2.imencode(f".{fmt}", img)[1].tobytes() for img in images]
        proc, lines = _live(folder, camera, d / "live.mcap")
        try:
            url = _wait(lines, "ws://", proc).split("live view: ")[1].split(" ")[0]
            client = _Estimates(url)
            _wait(lines, "ready:", proc)
            if not client.ready.wait(30):
                raise SystemExit(f"{fmt}: the client saw no /estimate/state channel")
            written = []
            for k, data in enumerate(encoded):
                tmp = folder / f".f{k:04d}.{fmt}"
                tmp.write_bytes(data)
                os.replace(tmp, folder / f"f{k:04d}.{fmt}")
                written.append(time.time())
                time.sleep(max(0.0, written[0] + (k + 1) / rate_hz - time.time()))
            stdout, _ = proc.communicate(timeout=120)
        finally:
            proc.kill()
        client.stop.set()
        client.thread.join(5)
    summary = json.loads(stdout)
    live = summary["live"]
    if live["frames_dropped"] or len(client.times) != len(written):
        raise SystemExit(f"{fmt}: {live['frames_dropped']} dropped, {len(client.times)} "
                         f"estimates received of {len(written)} (the server said "
                         f"{client.ops}): lower --rate")
    lat = (np.asarray(client.times) - np.asarray(written)) * 1e3
    return {"frames": len(written), "identified": summary["identified"],
            "modes": summary["modes"], "file_kb": round(np.mean([len(e) for e in encoded])
                                                        / 1024, 1),
            "latency_ms": {"median": float(np.median(lat)), "p95": float(np.percentile(lat, 95)),
                           "max": float(lat.max())},
            "run_latency_ms": live["latency_ms"]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--rate", type=float, default=5.0, help="frames a second written")
    p.add_argument("--size", type=int, default=1024, help="frame side, pixels")
    p.add_argument("--fov", type=float, default=10.0, help="field of view, degrees")
    p.add_argument("--formats", default="png,tiff,pgm")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    cam, images, stars = frames(args.frames, args.size, args.fov)
    doc = {"command": "python -P benchmarks/bench_live.py"
                      + ("" if argv is None else " " + " ".join(argv)),
           "frame_size": [args.size, args.size], "fov_deg": args.fov, "rate_hz": args.rate,
           "stars_per_frame_median": float(np.median(stars)), "formats": {},
           "machine": {"python": platform.python_version(), "cores": os.cpu_count(),
                       "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}}
    for fmt in args.formats.split(","):
        doc["formats"][fmt] = r = run_format(fmt, cam, images, args.rate)
        print(f"{fmt}: latency {r['latency_ms']['median']:.1f} ms median, "
              f"{r['latency_ms']['p95']:.1f} p95 (run's own {r['run_latency_ms']['median']:.1f}"
              f"); identified {r['identified']} of {r['frames']}, {r['modes']}",
              file=sys.stderr)
    doc["machine"]["load_average_1min"] = os.getloadavg()[0]
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
