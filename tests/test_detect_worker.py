"""The detection worker process gives exactly what a direct call gives, and its errors."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import starid
from adfusion.detect_worker import DetectWorker, keep_freed_memory
from sensors.scenarios import oedipus


def test_worker_results_equal_direct_detection_in_any_order():
    sc = oedipus(duration_s=0.2, seed=3, render=True)
    frames = [sc.frame(i)["image"] for i in range(len(sc.t_frame))]
    with DetectWorker() as w:
        for k, img in enumerate(frames):
            w.submit(k, img, sc.camera)
        for k in reversed(range(len(frames))):  # asked for out of order
            got, want = w.result(k), starid.detect(frames[k], sc.camera)
            np.testing.assert_array_equal(got.xy, want.xy)
            np.testing.assert_array_equal(got.flux, want.flux)
            assert len(got.xy) >= 5


def test_worker_raises_what_detect_raises_and_goes_on():
    cam = starid.Camera.pinhole(64, 48, 10.0)
    good = np.zeros((48, 64), np.uint16)
    good[20, 30] = good[21, 30] = 3000
    with DetectWorker() as w:
        w.submit("wrong size", np.zeros((10, 10), np.uint8), cam)
        w.submit("ok", good, cam, threshold=1000, min_area=1, max_sharpness=None)
        with pytest.raises(ValueError, match="camera is 64x48"):
            w.result("wrong size")
        assert w.result("ok").xy.shape == (1, 2)
        with pytest.raises(KeyError):
            w.result("never submitted")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt only")
def test_keep_freed_memory_reaches_glibc_mallopt():
    # both mallopt calls must succeed (mallopt returns 1); a wrong constant or signature
    # makes glibc refuse and the replay would silently fault its buffers back in
    assert keep_freed_memory() is True
    with pytest.raises(ValueError, match="out of range"):
        keep_freed_memory(mmap_threshold=1 << 40)
