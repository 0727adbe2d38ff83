"""GPS time <-> UTC and Unix time (the one place that knows the epochs and the leap seconds).

zennav's ``t_ns`` is integer nanoseconds of GPS time since the GPS epoch 1980-01-06 00:00:00 (no leap seconds).
Receivers tag their output in UTC (NMEA) or in GPS time of week (UBX iTOW); viewers such as Foxglove show Unix
(UTC-based) nanoseconds. GPS - UTC has been 18 s since 2017-01-01 (``LEAP_S``); no leap second has been announced
since, so the constant holds for data from 2017 on.
"""
from __future__ import annotations

import datetime as _dt

NS = 1_000_000_000
WEEK_NS = 604_800 * NS
GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06 00:00:00 UTC as Unix seconds
LEAP_S = 18  # GPS - UTC [s] since 2017-01-01
DAY_NS = 86_400 * NS
_UNIX_EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)


def unix_ns_to_gps_ns(unix_ns: int) -> int:
    """UTC-based Unix nanoseconds -> GPS nanoseconds since the GPS epoch."""
    return int(unix_ns) - GPS_EPOCH_UNIX_S * NS + LEAP_S * NS


def gps_ns_to_unix_ns(t_ns: int) -> int:
    """GPS nanoseconds since the GPS epoch -> UTC-based Unix nanoseconds (what Foxglove and ROS show)."""
    return int(t_ns) + GPS_EPOCH_UNIX_S * NS - LEAP_S * NS


def utc_to_gps_ns(when: _dt.datetime) -> int:
    """An aware (or naive, taken as UTC) UTC datetime -> GPS nanoseconds, microsecond resolution kept exactly."""
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.timezone.utc)
    d = when - _UNIX_EPOCH
    unix_ns = (d.days * 86_400 + d.seconds) * NS + d.microseconds * 1000
    return unix_ns_to_gps_ns(unix_ns)


def gps_ns_to_utc(t_ns: int) -> _dt.datetime:
    """GPS nanoseconds -> aware UTC datetime (microsecond resolution)."""
    unix_ns = gps_ns_to_unix_ns(t_ns)
    return _UNIX_EPOCH + _dt.timedelta(microseconds=unix_ns // 1000)


def time_of_day_to_gps_ns(tod: _dt.time, ref_t_ns: int, date: _dt.date | None = None) -> int:
    """A UTC time of day -> GPS nanoseconds: on ``date`` when given, else on the UTC day that puts it nearest
    ``ref_t_ns`` (a GPS time known to be within half a day, e.g. the previous fix)."""
    day_ns = (tod.hour * 3600 + tod.minute * 60 + tod.second) * NS + tod.microsecond * 1000
    if date is not None:
        return utc_to_gps_ns(_dt.datetime.combine(date, _dt.time(0), _dt.timezone.utc)) + day_ns
    ref_unix = gps_ns_to_unix_ns(ref_t_ns)
    midnight = ref_unix - ref_unix % DAY_NS
    cands = [midnight + k * DAY_NS + day_ns for k in (-1, 0, 1)]
    return unix_ns_to_gps_ns(min(cands, key=lambda c: abs(c - ref_unix)))


def tow_to_gps_ns(tow_ms: int, ref_t_ns: int) -> int:
    """GPS time of week [ms] -> GPS nanoseconds, in the week that puts it nearest ``ref_t_ns``."""
    week = int(ref_t_ns) // WEEK_NS
    cands = [(week + k) * WEEK_NS + int(tow_ms) * 1_000_000 for k in (-1, 0, 1)]
    return min(cands, key=lambda c: abs(c - ref_t_ns))
