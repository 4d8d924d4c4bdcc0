"""Frame times in file names (issue 33, item 7): every common way of writing a date and time
into a name reads back as the instant written, frame counters never do, and a folder whose
names cannot order its frames says why."""

from __future__ import annotations

import datetime as dt
import random

import pytest
from adfusion.logs.name_times import time_in_name, times_from_names

_STYLES: list = [  # how cameras and capture scripts write the time into a name
    lambda t: t.strftime("%Y-%m-%dT%H-%M-%S.%f")[:-3] + "Z.png",
    lambda t: t.strftime("IMG_%Y%m%d_%H%M%S.%f.jpg"),
    lambda t: t.strftime("%Y-%m-%d %H:%M:%S,%f.tiff"),
    lambda t: t.strftime("cam0_%Y%m%dT%H%M%S.%f_exp0.01.png"),
    lambda t: f"{_unix_us(t) // 1000}.png",  # Unix ms (ROS exports)
    lambda t: f"{_unix_us(t)}.pgm",  # Unix µs
    lambda t: f"{_unix_us(t) // 10**6}.{_unix_us(t) % 10**6:06d}.png",  # s and a fraction
    lambda t: f"{_unix_us(t) * 1000}.tif",  # Unix ns
]


def _unix_us(t: dt.datetime) -> int:
    return (t - dt.datetime(1970, 1, 1, tzinfo=dt.UTC)) // dt.timedelta(microseconds=1)


@pytest.mark.parametrize("style", range(len(_STYLES)))
def test_every_style_reads_back_the_instant_written(style):
    rng = random.Random(style)
    for _ in range(200):
        t = dt.datetime(2000, 1, 1, tzinfo=dt.UTC) + dt.timedelta(
            microseconds=rng.randrange(0, 80 * 365 * 86400 * 10**6))
        name = _STYLES[style](t)
        got = time_in_name(name)
        # the style's own precision: ms where it writes ms
        step = dt.timedelta(milliseconds=1) if style in (0, 4) else dt.timedelta(0)
        assert got is not None and abs(got - t) <= step, (name, got, t)


def test_a_zone_is_applied_and_a_name_without_one_is_read_as_utc():
    assert time_in_name("a_2023-11-07T08-07-00+01:00.png") == dt.datetime(
        2023, 11, 7, 7, 7, tzinfo=dt.UTC)
    assert time_in_name("a_2023-11-07T08-07-00-0230.png") == dt.datetime(
        2023, 11, 7, 10, 37, tzinfo=dt.UTC)
    assert not times_from_names(["20231107_080700.png"]).zoned
    assert times_from_names(["20231107_080700Z.png"]).zoned


@pytest.mark.parametrize("name", [
    "f000.png", "00001.png", "frame_000123.png", "IMG_4021.JPG", "2023.png",
    "20231307_080700.png",  # month 13
    "20231107_250700.png",  # hour 25
    "12345678901.png",  # 11 digits: not a Unix form
    "0000000001.png",  # 10 digits but 1970
    "1699344420123.5.png",  # a fraction of a ms count
])
def test_counters_and_impossible_dates_are_not_times(name):
    assert time_in_name(name) is None


def test_a_folder_of_named_frames_gives_its_times_and_start():
    names = [f"sky_2023-11-07T08-07-{s:06.3f}Z.png".replace(".", "_", 0) for s in
             (1.5, 0.25, 3.0)]
    nt = times_from_names(names)
    assert nt.why == "" and nt.t_s == [1.25, 0.0, 2.75]
    assert nt.start_utc == "2023-11-07T08:07:00.250000Z"


def test_names_that_cannot_order_the_frames_say_why():
    # a camera naming by the second: two frames in one second
    why = times_from_names(["IMG_20231107_080700_001.jpg",
                            "IMG_20231107_080700_002.jpg"]).why
    assert "same time" in why and "IMG_20231107_080700_001.jpg" in why
    why = times_from_names(["20231107_080700.png", "dark.png"]).why
    assert why == "dark.png: no date and time in the name"
