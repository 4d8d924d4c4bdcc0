"""Check that a change to `starid.detection.detect` leaves its output on the real frames unchanged.

Records every field of ``detect(frame)`` (positions, fluxes, areas, peaks, order, rejections,
background, noise, bright-pixel count, noise model) for each frame of both shared real sets
into a pickle, and later compares the same fields, bit for bit, against that record. Run
``record`` before a speed-up and ``compare`` after it (the record lives outside the
repository: it is derived from ../shared data)::

    python -P benchmarks/detect_identical.py record /tmp/detect-before.pkl
    python -P benchmarks/detect_identical.py compare /tmp/detect-before.pkl

Exit status 0 when identical, 1 with one line per differing field otherwise.

Example:
    >>> import numpy as np
    >>> a = {"f": _fields(detect(np.full((32, 32), 7, np.uint8)))}
    >>> differences(a, a)
    []
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.starid.detection.detect import detect
from adfusion.starid.detection.detections import Detections
from adfusion.starid.detection.image import read_image

_SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT_DATA = [_SHARED / "real-images", _SHARED / "real-images-cedar"]
_IMAGE_SUFFIXES = (".tiff", ".tif", ".png", ".jpg", ".jpeg")


def _fields(d: Detections) -> dict[str, Any]:
    return {"xy": d.xy, "flux": d.flux, "area": d.area, "peak": d.peak, "ok": d.ok,
            "reason": d.reason, "rejected": [tuple(r) for r in d.rejected],
            "background_level": d.background_level, "noise_sigma": d.noise_sigma,
            "bright_pixels": d.bright_pixels, "noise_model": d.noise_model}


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    return a == b or (a != a and b != b)  # NaN equals NaN here


def differences(ref: dict[str, dict[str, Any]], new: dict[str, dict[str, Any]]) -> list[str]:
    """One line per frame and field that differs (or is missing) between two records."""
    out = []
    for frame, fields in ref.items():
        if frame not in new:
            out.append(f"{frame}: not in the new record")
            continue
        out += [f"{frame}: {k} differs" for k, v in fields.items() if not _same(v, new[frame][k])]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=("record", "compare"))
    ap.add_argument("file", type=Path, help="the pickle to write (record) or read (compare)")
    ap.add_argument("--data", type=Path, nargs="+", default=DEFAULT_DATA)
    args = ap.parse_args(argv)
    frames = sorted(p for d in args.data for p in d.glob("*")
                    if p.suffix.lower() in _IMAGE_SUFFIXES)
    if not frames:
        print(f"no image frames in {[str(d) for d in args.data]}", file=sys.stderr)
        return 2
    rec = {f"{p.parent.name}/{p.name}": _fields(detect(read_image(p))) for p in frames}
    if args.mode == "record":
        args.file.write_bytes(pickle.dumps(rec))
        print(f"{len(rec)} frames, {sum(len(v['xy']) for v in rec.values())} detections "
              f"recorded in {args.file}")
        return 0
    diff = differences(pickle.loads(args.file.read_bytes()), rec)
    print("\n".join(diff) if diff else f"identical on {len(rec)} frames")
    return 1 if diff else 0


if __name__ == "__main__":
    raise SystemExit(main())
