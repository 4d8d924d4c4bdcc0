"""The detection worker process gives exactly what a direct call gives, and its errors."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from adfusion.sensors.scenarios import oedipus

from adfusion import starid
from adfusion.app.detect_worker import DetectWorker, keep_freed_memory


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


def _stars(shape, dtype, spots):
    img = np.zeros(shape, dtype)
    for y, x in spots:
        img[y, x] = img[y, x + 1] = 200
    return img


def test_frames_of_growing_size_through_few_slots_match_direct_calls():
    # two slots for six frames: submit has to wait for results to free one, and the third
    # frame is larger than the slots so far (the shared memory grows under pending work)
    kw = dict(threshold=100, min_area=1, max_sharpness=None)
    frames = [_stars((40, 40), np.uint8, [(10, 10)]),
              _stars((40, 40), np.uint8, [(20, 5), (30, 30)]),
              _stars((120, 90), np.uint16, [(100, 80), (5, 5), (60, 40)]),
              _stars((120, 90), np.uint16, [(7, 7)])[::-1, ::-1],  # not contiguous
              _stars((30, 50), np.float32, [(15, 40)]),
              _stars((40, 40), np.uint8, [(1, 1), (38, 30)])]
    with DetectWorker(slots=2) as w:
        for k, img in enumerate(frames):
            w.submit(k, img, None, **kw)
        for k, img in enumerate(frames):
            got, want = w.result(k), starid.detect(img, None, **kw)
            np.testing.assert_array_equal(got.xy, want.xy)
            np.testing.assert_array_equal(got.flux, want.flux)
        assert w._slot_bytes >= 120 * 90 * 2  # the frames did travel through the slots
    assert [len(starid.detect(f, None, **kw).xy) for f in frames] == [1, 2, 3, 1, 1, 2]


def test_a_new_camera_object_reaches_the_worker():
    # the camera is sent only when a different object is passed: the second one must win
    small, large = starid.Camera.pinhole(64, 48, 10.0), starid.Camera.pinhole(80, 60, 10.0)
    img = _stars((60, 80), np.uint8, [(30, 40)])
    kw = dict(threshold=100, min_area=1, max_sharpness=None)
    with DetectWorker() as w:
        w.submit("small", img, small, **kw)
        w.submit("large", img, large, **kw)
        w.submit("large again", img, large, **kw)
        with pytest.raises(ValueError, match="camera is 64x48"):
            w.result("small")
        assert w.result("large").xy.shape == (1, 2)
        assert w.result("large again").xy.shape == (1, 2)
        with pytest.raises(ValueError, match="already pending"):
            w.submit("x", img, large, **kw)
            w.submit("x", img, large, **kw)


def test_ready_reports_the_started_worker_and_results_follow():
    import time

    img = _stars((40, 40), np.uint8, [(10, 10)])
    kw = dict(threshold=100, min_area=1, max_sharpness=None)
    with DetectWorker() as w:
        deadline = time.monotonic() + 60.0
        while not w.ready():  # polls: each call returns at once
            assert time.monotonic() < deadline, "the worker never announced itself"
            time.sleep(0.01)
        assert w.ready()  # stays ready; the announcement is not mistaken for a result
        w.submit("a", img, None, **kw)
        assert w.result("a").xy.shape == (1, 2)
