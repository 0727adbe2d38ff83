"""GNSS fixes -> what a receiver sends: NMEA sentences (GGA, RMC, GST, VTG) and UBX frames (NAV-PVT, NAV-COV).

The inverse of zennav.receivers.nmea / ubx for tests and for ``zennav gnss-sim`` (a simulated receiver on a
serial port or TCP socket): the same fix decodes back within the formats' resolution (NMEA: 1e-7 arc-minute,
0.01 s; UBX: 1e-7 deg, 1 mm, 1 ms). Heights are written as ellipsoidal (geoid separation 0).
"""
from __future__ import annotations

import math

from ..gpstime import NS, WEEK_NS, gps_ns_to_utc
from ..nav.types import FixType, GnssFix
from .nmea import KNOT_MPS

NMEA_QUALITY = {FixType.NONE: 0, FixType.SINGLE: 1, FixType.DGPS: 2, FixType.RTK_FLOAT: 5, FixType.RTK_FIXED: 4}


def _checksum(body: str) -> str:
    c = 0
    for ch in body.encode("ascii"):
        c ^= ch
    return f"{c:02X}"


def _sentence(body: str) -> bytes:
    return f"${body}*{_checksum(body)}\r\n".encode("ascii")


def _angle(deg: float, pos: str, neg: str, width: int) -> tuple[str, str]:
    a = abs(deg)
    d = int(a)
    minutes = (a - d) * 60.0
    return f"{d:0{width}d}{minutes:010.7f}", pos if deg >= 0 else neg


def nmea_sentences(fix: GnssFix, talker: str = "GN", gst: bool = True, rmc: bool = True, vtg: bool = False,
                   quality: int | None = None, num_sats: int | None = None) -> bytes:
    """One epoch's sentences for ``fix`` (GGA first). quality / num_sats override the fix's (a degraded fix)."""
    utc = gps_ns_to_utc(fix.t_ns)
    hms = f"{utc:%H%M%S}.{utc.microsecond // 10000:02d}"
    lat, ns = _angle(math.degrees(fix.llh[0]), "N", "S", 2)
    lon, ew = _angle(math.degrees(fix.llh[1]), "E", "W", 3)
    q = NMEA_QUALITY.get(FixType(fix.fix), 1) if quality is None else quality
    sats = fix.num_sats if num_sats is None else num_sats
    hdop = max(float(fix.std_ned[0]), 0.01) / 3.0
    out = [_sentence(f"{talker}GGA,{hms},{lat},{ns},{lon},{ew},{q},{max(sats, 0):02d},{hdop:.2f},"
                     f"{fix.llh[2]:.4f},M,0.000,M,,")]
    speed = course = None
    if fix.v_n is not None:
        speed = math.hypot(fix.v_n[0], fix.v_n[1])
        course = math.degrees(math.atan2(fix.v_n[1], fix.v_n[0])) % 360.0
    if rmc:
        status = "A" if q > 0 else "V"
        spd = "" if speed is None else f"{speed / KNOT_MPS:.4f}"
        crs = "" if course is None else f"{course:.3f}"
        out.append(_sentence(f"{talker}RMC,{hms},{status},{lat},{ns},{lon},{ew},{spd},{crs},{utc:%d%m%y},,,A"))
    if gst:
        s = fix.std_ned
        out.append(_sentence(f"{talker}GST,{hms},{math.hypot(s[0], s[1]):.3f},{max(s[0], s[1]):.3f},"
                             f"{min(s[0], s[1]):.3f},0.0,{s[0]:.4f},{s[1]:.4f},{s[2]:.4f}"))
    if vtg and speed is not None and course is not None:
        out.append(_sentence(f"{talker}VTG,{course:.3f},T,,M,{speed / KNOT_MPS:.4f},N,{speed * 3.6:.4f},K,A"))
    return b"".join(out)


def ubx_frames(fix: GnssFix, cov: bool = True, fix_type: int | None = None, num_sats: int | None = None) -> bytes:
    """NAV-PVT (and NAV-COV) of ``fix``. fix_type / num_sats override the fix's (a degraded fix)."""
    from pyubx2 import UBXMessage

    utc = gps_ns_to_utc(fix.t_ns)
    itow = int((fix.t_ns % WEEK_NS) // 1_000_000)
    f = FixType(fix.fix)
    ft = (3 if f != FixType.NONE else 0) if fix_type is None else fix_type
    v = [0.0, 0.0, 0.0] if fix.v_n is None else [float(x) for x in fix.v_n]
    sv = [0.1, 0.1, 0.1] if fix.std_v_n is None else [float(x) for x in fix.std_v_n]
    s = [float(x) for x in fix.std_ned]
    pvt = UBXMessage(
        "NAV", "NAV-PVT", 0, iTOW=itow, year=utc.year, month=utc.month, day=utc.day, hour=utc.hour, min=utc.minute,
        second=utc.second, validDate=1, validTime=1, fullyResolved=1, tAcc=20,
        nano=int(fix.t_ns % NS),  # GPS - UTC is whole seconds: the same fraction of a second
        fixType=ft, gnssFixOk=1 if ft in (3, 4) else 0, diffSoln=1 if f >= FixType.DGPS else 0,
        carrSoln={FixType.RTK_FLOAT: 1, FixType.RTK_FIXED: 2}.get(f, 0),
        numSV=max(fix.num_sats if num_sats is None else num_sats, 0),
        lon=math.degrees(fix.llh[1]), lat=math.degrees(fix.llh[0]), height=round(fix.llh[2] * 1000.0),
        hMSL=round(fix.llh[2] * 1000.0), hAcc=round(math.hypot(s[0], s[1]) * 1000.0), vAcc=round(s[2] * 1000.0),
        velN=round(v[0] * 1000.0), velE=round(v[1] * 1000.0), velD=round(v[2] * 1000.0),
        gSpeed=round(math.hypot(v[0], v[1]) * 1000.0), sAcc=round(math.sqrt(sum(x * x for x in sv)) * 1000.0),
        pDOP=1.0)
    out = pvt.serialize()
    if cov:
        out += UBXMessage("NAV", "NAV-COV", 0, iTOW=itow, posCovValid=1, velCovValid=1, posCovNN=s[0] ** 2,
                          posCovEE=s[1] ** 2, posCovDD=s[2] ** 2, velCovNN=sv[0] ** 2, velCovEE=sv[1] ** 2,
                          velCovDD=sv[2] ** 2).serialize()
    return out
