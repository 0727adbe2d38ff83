"""u-blox UBX frames (pyubx2) -> GNSS fixes: NAV-PVT (position, velocity, hAcc/vAcc/sAcc, numSV, fixType,
carrier solution) with NAV-COV's NED covariances where the receiver sends them in the same epoch (iTOW).

Times: iTOW (GPS time of week [ms]) in the GPS week of NAV-PVT's UTC date and time when valid (UTC + leap
seconds, zennav.gpstime), else the week nearest the reference time (the previous fix, or the stream's start).
Accuracy: NAV-COV's position and velocity covariance diagonals when valid; else hAcc / sqrt(2) north and east
(hAcc is a horizontal radius), vAcc down, sAcc / sqrt(3) per velocity component (sAcc is a 3-D speed accuracy).
Fix type: gnssFixOK unset, no fix, dead reckoning only, time only or a 2-D fix (no usable height) -> NONE;
carrier solution fixed -> RTK_FIXED, float -> RTK_FLOAT; differential -> DGPS; else SINGLE. Rejected input is
counted by reason: ``ubx_checksum``, ``ubx_parse``, ``ubx_no_time``, ``ubx_no_pvt``, ``ubx_ignored``.
"""
from __future__ import annotations

import datetime as dt
import math

import numpy as np

from ..gpstime import tow_to_gps_ns, utc_to_gps_ns
from ..nav.types import FixType, GnssFix
from .epoch import EpochDecoder

USED = ("NAV-PVT", "NAV-COV")


class UbxDecoder(EpochDecoder):
    """Frames -> GnssFix (see the module docstring). ref_t_ns: a GPS time within half a week of the data, used
    while NAV-PVT's date is not valid."""

    def __init__(self, ref_t_ns: int | None = None):
        super().__init__(ref_t_ns)

    def decode(self, frame: bytes) -> list[GnssFix]:
        """One whole UBX frame -> the fixes it completes."""
        from pyubx2 import UBXReader
        from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXTypeError

        try:
            msg = UBXReader.parse(frame)
        except UBXParseError as e:
            self.counts["ubx_checksum" if "checksum" in str(e).lower() else "ubx_parse"] += 1
            return []
        except (UBXMessageError, UBXTypeError, ValueError, KeyError, IndexError, TypeError):
            self.counts["ubx_parse"] += 1
            return []
        kind = msg.identity
        if kind not in USED:
            self.counts["ubx_ignored"] += 1
            return []
        self.counts[f"ubx_{kind.lower().replace('-', '_')}"] += 1
        return self._fixes(self.epochs.add(int(msg.iTOW), kind, msg))

    def _fix(self, parts: dict) -> GnssFix | None:
        pvt, cov = parts.get("NAV-PVT"), parts.get("NAV-COV")
        if pvt is None:
            self.counts["ubx_no_pvt"] += 1
            return None
        ref = self.ref_t_ns
        if pvt.validDate and pvt.validTime:
            try:
                utc = dt.datetime(pvt.year, pvt.month, pvt.day, pvt.hour, pvt.min, pvt.second, tzinfo=dt.timezone.utc)
                ref = utc_to_gps_ns(utc) + int(pvt.nano)
            except ValueError:
                pass
        if ref is None:
            self.counts["ubx_no_time"] += 1
            return None
        t_ns = tow_to_gps_ns(int(pvt.iTOW), ref)
        if not pvt.gnssFixOk or pvt.fixType not in (3, 4):
            fix = FixType.NONE
        elif pvt.carrSoln == 2:
            fix = FixType.RTK_FIXED
        elif pvt.carrSoln == 1:
            fix = FixType.RTK_FLOAT
        elif pvt.diffSoln:
            fix = FixType.DGPS
        else:
            fix = FixType.SINGLE
        h_std = pvt.hAcc / 1000.0 / math.sqrt(2.0)
        std = [h_std, h_std, pvt.vAcc / 1000.0]
        v_std = pvt.sAcc / 1000.0 / math.sqrt(3.0)
        std_v = [v_std] * 3
        if cov is not None and cov.posCovValid:
            std = [math.sqrt(max(cov.posCovNN, 0.0)), math.sqrt(max(cov.posCovEE, 0.0)),
                   math.sqrt(max(cov.posCovDD, 0.0))]
        if cov is not None and cov.velCovValid:
            std_v = [math.sqrt(max(cov.velCovNN, 0.0)), math.sqrt(max(cov.velCovEE, 0.0)),
                     math.sqrt(max(cov.velCovDD, 0.0))]
        llh = np.array([math.radians(pvt.lat), math.radians(pvt.lon), pvt.height / 1000.0])
        v_n = np.array([pvt.velN, pvt.velE, pvt.velD], dtype=float) / 1000.0
        return GnssFix(t_ns=t_ns, llh=llh, std_ned=np.array(std), v_n=v_n, std_v_n=np.array(std_v), fix=int(fix),
                       num_sats=int(pvt.numSV))
