"""NMEA 0183 sentences (pynmea2) -> GNSS fixes: GGA (position, fix quality, satellites, HDOP), RMC (date, status,
speed and course), GST (position standard deviations), VTG (speed and course); any talker (GP, GN, GL, GA, GB).

Times: NMEA tags epochs with the UTC time of day; RMC gives the date. A GGA epoch without a date takes the UTC
day nearest the reference time (the previous fix, or the stream's start). Fix times are GPS time
(zennav.gpstime). Heights: GGA altitude above the geoid plus the geoid separation = ellipsoidal height.
Accuracy: GST's latitude/longitude/altitude standard deviations [m] when the epoch has one, else HDOP times
``uere_m`` horizontally and ``vertical_dop_factor`` times that vertically (GGA carries no VDOP). Velocity (RMC,
else VTG): horizontal only, NMEA gives no vertical speed and no accuracy, so v_n = (v cos course, v sin course, 0)
with standard deviations (``speed_std_mps``, ``speed_std_mps``, ``vertical_speed_std_mps``).
Fix quality (GGA): 0 invalid, 6 dead reckoning, 7 manual, 8 simulator -> NONE; 1, 3 -> SINGLE; 2 -> DGPS;
5 -> RTK_FLOAT; 4 -> RTK_FIXED; an RMC status V makes the fix NONE. Rejected input is counted by reason:
``nmea_checksum``, ``nmea_parse``, ``nmea_no_gga``, ``nmea_no_position``, ``nmea_no_accuracy``,
``nmea_no_time``, ``nmea_ignored`` (other sentences).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..gpstime import time_of_day_to_gps_ns
from ..nav.types import FixType, GnssFix
from .epoch import EpochDecoder

KNOT_MPS = 1852.0 / 3600.0
GGA_FIX = {0: FixType.NONE, 1: FixType.SINGLE, 2: FixType.DGPS, 3: FixType.SINGLE, 4: FixType.RTK_FIXED,
           5: FixType.RTK_FLOAT, 6: FixType.NONE, 7: FixType.NONE, 8: FixType.NONE}
USED = ("GGA", "RMC", "GST", "VTG")


@dataclass(frozen=True)
class NmeaSettings:
    """Assumptions for what NMEA does not say (SI units)."""

    uere_m: float = 3.0  # user equivalent range error: horizontal std = HDOP * uere_m without GST [m]
    vertical_dop_factor: float = 1.5  # vertical std / horizontal std without GST
    velocity: bool = True  # emit RMC/VTG horizontal velocity
    speed_std_mps: float = 0.3  # std of each horizontal velocity component [m/s]
    vertical_speed_std_mps: float = 5.0  # std of the vertical velocity NMEA does not give [m/s]


def _float(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


class NmeaDecoder(EpochDecoder):
    """Sentences -> GnssFix (see the module docstring). ref_t_ns: a GPS time within half a day of the data, used
    until the first fix (None: wait for an RMC date)."""

    def __init__(self, settings: NmeaSettings | None = None, ref_t_ns: int | None = None):
        import pynmea2

        self._nmea = pynmea2
        self.settings = settings or NmeaSettings()
        super().__init__(ref_t_ns)

    def decode(self, line: bytes) -> list[GnssFix]:
        """One sentence (bytes, no line end) -> the fixes it completes."""
        try:
            msg = self._nmea.parse(line.decode("ascii"), check=True)
        except self._nmea.ChecksumError:
            self.counts["nmea_checksum"] += 1
            return []
        except (self._nmea.ParseError, UnicodeDecodeError, ValueError, AttributeError, TypeError):
            self.counts["nmea_parse"] += 1
            return []
        kind = getattr(msg, "sentence_type", "")
        if kind not in USED:
            self.counts["nmea_ignored"] += 1
            return []
        self.counts[f"nmea_{kind.lower()}"] += 1
        tag = getattr(msg, "timestamp", None) if kind != "VTG" else self.epochs.tag
        return self._fixes(self.epochs.add(tag, kind, msg))

    def _fix(self, parts: dict) -> GnssFix | None:
        gga, rmc, gst, vtg = (parts.get(k) for k in USED)
        if gga is None:  # RMC, GST or VTG without the epoch's GGA
            self.counts["nmea_no_gga"] += 1
            return None
        lat, lon = _float(getattr(gga, "latitude", None)), _float(getattr(gga, "longitude", None))
        alt, sep = _float(gga.altitude), _float(gga.geo_sep)
        if lat is None or lon is None or alt is None or not gga.lat or not gga.lon:
            self.counts["nmea_no_position"] += 1
            return None
        date = rmc.datestamp if rmc is not None and getattr(rmc, "datestamp", None) else None
        if gga.timestamp is None or (date is None and self.ref_t_ns is None):
            self.counts["nmea_no_time"] += 1
            return None
        t_ns = time_of_day_to_gps_ns(gga.timestamp, self.ref_t_ns or 0, date)
        q = int(_float(gga.gps_qual) or 0)
        fix = GGA_FIX.get(q, FixType.NONE)
        if rmc is not None and rmc.status != "A":
            fix = FixType.NONE
        sats = _float(gga.num_sats)
        s = self.settings
        std = None
        if gst is not None:
            std = [_float(gst.std_dev_latitude), _float(gst.std_dev_longitude), _float(gst.std_dev_altitude)]
            std = None if any(x is None for x in std) else std
        if std is None:
            hdop = _float(gga.horizontal_dil)
            if hdop is None:
                self.counts["nmea_no_accuracy"] += 1
                return None
            std = [hdop * s.uere_m, hdop * s.uere_m, hdop * s.uere_m * s.vertical_dop_factor]
        v_n = std_v = None
        if s.velocity:
            speed, course = None, None
            if rmc is not None and rmc.status == "A":
                speed, course = _float(rmc.spd_over_grnd), _float(rmc.true_course)
                speed = None if speed is None else speed * KNOT_MPS
            elif vtg is not None:
                speed, course = _float(vtg.spd_over_grnd_kmph), _float(vtg.true_track)
                speed = None if speed is None else speed / 3.6
            if speed is not None and (course is not None or speed == 0.0):
                c = math.radians(course or 0.0)
                v_n = np.array([speed * math.cos(c), speed * math.sin(c), 0.0])
                std_v = np.array([s.speed_std_mps, s.speed_std_mps, s.vertical_speed_std_mps])
        return GnssFix(t_ns=t_ns, llh=np.array([math.radians(lat), math.radians(lon), alt + (sep or 0.0)]),
                       std_ned=np.array(std, dtype=float), v_n=v_n, std_v_n=std_v, fix=int(fix),
                       num_sats=-1 if sats is None else int(sats))
