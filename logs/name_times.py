"""Frame times read from the frames' file names (``2023-11-07T08-07-00.125.png``).

Many cameras and capture scripts name each frame by the time it was taken; a folder of such
frames then carries its own clock, and a replay needs neither ``--fps`` nor ``--timestamps``
nor ``--start-utc``. A name gives a time when its stem holds a calendar date and a time of
day — year, month, day, hour, minute, second, each run of digits with or without
separators (``-``, ``_``, ``:``, ``.``, ``T``, a space), then optionally a fraction of the
second after ``.`` or ``,`` and a zone (``Z`` or ``±HH:MM``). Names without a zone are read
as UTC (the replay says so: a camera on local time needs ``--start-utc``). A counter after
the time (``_001``) is not a fraction: only ``.`` or ``,`` start one. A stem that is a
whole number of 9–10, 12–13, 15–16 or 18–19 digits (Unix seconds, ms, µs or ns, as ROS
and many loggers write; a fraction only after seconds) is a time when it falls in
2000–2100.

The times are used only when every name gives one and no two are equal (cameras that name
by the second write several frames per name): half a clock is not a clock, and
:func:`times_from_names` says why not otherwise.

Example:
    >>> nt = times_from_names(["cam_2023-11-07T08-07-00.500Z.png",
    ...                        "cam_2023-11-07T08-07-00.000Z.png"])
    >>> nt.t_s, nt.start_utc
    ([0.5, 0.0], '2023-11-07T08:07:00.000000Z')
    >>> times_from_names(["f000.png", "f001.png"]).why
    'f000.png: no date and time in the name'
"""

from __future__ import annotations

import datetime as dt
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = ["NameTimes", "time_in_name", "times_from_names"]

_SEP = r"[-_:. T]?"
_TIME = re.compile(
    r"(?<!\d)(?P<Y>(?:19|20|21)\d{2})" + _SEP + r"(?P<m>\d{2})" + _SEP + r"(?P<d>\d{2})"
    + r"[-_:. T]?(?P<H>\d{2})" + _SEP + r"(?P<M>\d{2})" + _SEP + r"(?P<S>\d{2})"
    + r"(?:[.,](?P<f>\d{1,9}))?(?P<z>Z|[+-]\d{2}:?\d{2})?(?!\d)")


@dataclass
class NameTimes:
    """What the names said: ``t_s`` (per name, in the names' order; s after the earliest),
    ``start_utc`` (ISO 8601 UTC of the earliest), ``zoned`` (every name carried its zone),
    or ``why`` they cannot be used (then ``t_s`` is empty)."""

    t_s: list[float] = field(default_factory=list)
    start_utc: str | None = None
    zoned: bool = False
    why: str = ""


def _match(name: str) -> re.Match | None:
    """The last date-and-time run of digits in ``name``'s base name."""
    found = None
    for m in _TIME.finditer(os.path.basename(name)):
        found = m
    return found


#: a whole stem of digits read as Unix time: seconds, ms, µs or ns by its digit count,
#: only between these instants (UTC 2000–2100), so frame counters never qualify
_EPOCH = re.compile(r"(?P<i>\d{9,10}|\d{12,13}|\d{15,16}|\d{18,19})(?:\.(?P<f>\d{1,9}))?")
_EPOCH_RANGE_S = (946_684_800, 4_102_444_800)


def _epoch(name: str) -> dt.datetime | None:
    stem = os.path.basename(name)
    stem = stem[: stem.rfind(".")] if stem.count(".") >= 1 else stem
    m = _EPOCH.fullmatch(stem) or _EPOCH.fullmatch(os.path.basename(name))
    if m is None:
        return None
    digits = m.group("i")
    scale = 10 ** (3 * ((len(digits) - 9) // 3))  # 9–10 digits s, 12–13 ms, ...
    us = int(digits) * 10**6 // scale  # integer maths: no float rounding of the ns
    if m.group("f"):
        if scale != 1:
            return None  # a fraction of a millisecond count: not a form anyone writes
        f = m.group("f")[:6]
        us += int(f) * 10 ** (6 - len(f))
    if not _EPOCH_RANGE_S[0] <= us // 10**6 <= _EPOCH_RANGE_S[1]:
        return None
    return dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=us)


def time_in_name(name: str) -> dt.datetime | None:
    """The UTC date and time in file name ``name`` (its last date-and-time run of digits,
    or a whole stem of Unix time), or None.

    >>> time_in_name("IMG_20231107_080700_001.jpg").isoformat()
    '2023-11-07T08:07:00+00:00'
    >>> time_in_name("1699344420.250.png").isoformat()
    '2023-11-07T08:07:00.250000+00:00'
    >>> time_in_name("2023-13-07T08-07-00.png") is None  # month 13
    True
    """
    found = _match(name)
    if found is None:
        return _epoch(name)
    g = found.groupdict()
    try:
        frac = (g["f"] or "0")[:6]
        us = int(frac) * 10 ** (6 - len(frac))
        tz = dt.UTC
        if g["z"] and g["z"] != "Z":
            sign = 1 if g["z"][0] == "+" else -1
            hh, mm = int(g["z"][1:3]), int(g["z"][-2:])
            tz = dt.timezone(sign * dt.timedelta(hours=hh, minutes=mm))
        t = dt.datetime(int(g["Y"]), int(g["m"]), int(g["d"]), int(g["H"]), int(g["M"]),
                        int(g["S"]), tzinfo=tz) + dt.timedelta(microseconds=us)
    except ValueError:  # month 13, hour 25, a zone past ±24 h: not a time
        return None
    return t.astimezone(dt.UTC)


def times_from_names(names: Sequence[str]) -> NameTimes:
    """The frame times the file names ``names`` give (:class:`NameTimes`), or why not."""
    if not names:
        return NameTimes(why="no frames")
    times = []
    for name in names:
        t = time_in_name(name)
        if t is None:
            return NameTimes(why=f"{os.path.basename(name)}: no date and time in the name")
        times.append(t)
    first: dict[dt.datetime, str] = {}
    for name, t in zip(names, times, strict=True):
        if t in first:
            return NameTimes(why=f"{os.path.basename(name)} and {first[t]} name the same "
                                 "time: the names are not precise enough to order the frames")
        first[t] = os.path.basename(name)
    t0 = min(times)
    return NameTimes(t_s=[(t - t0).total_seconds() for t in times],
                     start_utc=t0.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
                     zoned=all(_zoned(n) for n in names))


def _zoned(name: str) -> bool:
    """The name's time carries its zone (Unix time always does: it is UTC)."""
    m = _match(name)
    return bool(m.group("z")) if m is not None else _epoch(name) is not None
