"""Live GNSS receivers without hardware: NMEA and UBX over a pseudo-terminal pair, with checksum errors, partial
sentences, line noise, a receiver that goes silent and comes back; and the time tags mapped to GPS time."""
from __future__ import annotations

import datetime as dt
import math
import os
import time

import numpy as np
import pytest

from zennav.gpstime import LEAP_S, NS, gps_ns_to_unix_ns, time_of_day_to_gps_ns, tow_to_gps_ns, utc_to_gps_ns
from zennav.nav.types import FixType, GnssFix
from zennav.receivers.encode import nmea_sentences, ubx_frames
from zennav.receivers.framing import Framer
from zennav.receivers.nmea import NmeaDecoder
from zennav.receivers.receiver import GnssReceiver, parse_link
from zennav.receivers.simulate import open_pty, write_all
from zennav.receivers.ubx import UbxDecoder

T0 = utc_to_gps_ns(dt.datetime(2026, 12, 2, 23, 59, 58, 500000))  # crosses midnight UTC


def _fixes(n: int, rate_hz: float = 4.0) -> list[GnssFix]:
    rng = np.random.default_rng(7)
    out = []
    for k in range(n):
        llh = np.array([math.radians(48.1 + 1e-5 * k), math.radians(-11.5 - 2e-5 * k), 512.3 + 0.01 * k])
        out.append(GnssFix(T0 + int(k * NS / rate_hz), llh, np.array([0.4, 0.5, 1.1]) + rng.uniform(0, 0.1, 3),
                           np.array([5.0, -2.0, 0.3]), np.array([0.1, 0.12, 0.2]), int(FixType.RTK_FLOAT), 12 + k % 3))
    return out


def test_gps_time():
    assert gps_ns_to_unix_ns(0) == (315964800 - LEAP_S) * NS
    t = utc_to_gps_ns(dt.datetime(2026, 12, 2, 0, 0, 1))
    assert time_of_day_to_gps_ns(dt.time(0, 0, 1), t + 3600 * NS) == t
    assert time_of_day_to_gps_ns(dt.time(23, 59, 59), t) == t - 2 * NS  # nearest day: the one before
    assert tow_to_gps_ns(t % (604800 * NS) // 1_000_000, t + 10 * NS) == t


@pytest.mark.parametrize("fmt", ["nmea", "ubx"])
def test_round_trip_through_the_decoders(fmt):
    fixes = _fixes(12)
    data = b"".join(nmea_sentences(f, vtg=True) if fmt == "nmea" else ubx_frames(f) for f in fixes)
    framer = Framer()
    dec = NmeaDecoder() if fmt == "nmea" else UbxDecoder()
    got = []
    for i in range(0, len(data), 5):  # arbitrary chunking
        for _kind, frame in framer.feed(data[i:i + 5]):
            got += dec.decode(frame)
    got += dec.flush()
    assert not framer.counts
    assert [g.t_ns for g in got] == [f.t_ns for f in fixes]  # across UTC midnight: RMC's date, iTOW's week
    for g, f in zip(got, fixes):
        e_n = (g.llh[0] - f.llh[0]) * 6.4e6
        e_e = (g.llh[1] - f.llh[1]) * 6.4e6 * math.cos(f.llh[0])
        assert abs(e_n) < 0.02 and abs(e_e) < 0.02 and abs(g.llh[2] - f.llh[2]) < 2e-3
        assert np.allclose(g.std_ned, f.std_ned, atol=2e-3)
        assert g.num_sats == f.num_sats and g.fix == FixType.RTK_FLOAT
        if fmt == "ubx":
            assert np.allclose(g.v_n, f.v_n, atol=1e-3) and np.allclose(g.std_v_n, f.std_v_n, atol=1e-3)
        else:  # horizontal only, with the assumed accuracy
            assert np.allclose(g.v_n[:2], f.v_n[:2], atol=1e-3) and g.v_n[2] == 0.0
            assert g.std_v_n[2] >= 1.0


def test_degraded_fixes_carry_quality_and_satellites():
    f = _fixes(1)[0]
    dec_n, dec_u = NmeaDecoder(), UbxDecoder()
    for dec, data in ((dec_n, nmea_sentences(f, quality=0, num_sats=3)),
                      (dec_u, ubx_frames(f, fix_type=0, num_sats=3))):
        got = []
        for _k, frame in Framer().feed(data):
            got += dec.decode(frame)
        got += dec.flush()
        assert len(got) == 1 and got[0].fix == FixType.NONE and got[0].num_sats == 3


def test_bad_links_are_refused_with_the_reason():
    assert parse_link("serial:/dev/ttyUSB0:9600") == ("serial", ("/dev/ttyUSB0", 9600))
    assert parse_link("tcp:127.0.0.1:5000") == ("tcp", ("127.0.0.1", 5000))
    for bad in ("serial:", "tcp:nohost", "usb:/dev/x", "/no/such/file"):
        with pytest.raises(ValueError, match="expected serial"):
            parse_link(bad)


def test_pseudo_terminal_noise_partial_checksum_silence_and_return():
    """A receiver on a pty: NMEA then UBX, a sentence with a wrong checksum, one cut by the next, a UBX frame
    with a broken checksum, baud-rate garbage; then 1.5 s of silence and more fixes. Every good fix comes through
    in order, every bad thing is counted under its reason, the reader thread survives."""
    fixes = _fixes(16)
    master, slave, path = open_pty()
    rx = GnssReceiver(f"serial:{path}:115200", ref_t_ns=T0, silence_s=0.5).start()
    write = write_all(master)
    try:
        assert rx.opened.wait(10)
        for f in fixes[:4]:
            write(nmea_sentences(f))
        bad = bytearray(nmea_sentences(fixes[4], rmc=False, gst=False))
        bad[10] ^= 0x01  # a bit error in the GGA: checksum mismatch
        write(bytes(bad))
        rng = np.random.default_rng(3)
        write(bytes(b for b in rng.integers(0, 256, 300, dtype=np.uint8).tobytes() if b not in (0x24, 0xB5)))
        write(b"\r\n$GNGGA,235959.00,4806.0")  # a sentence cut off by the next frame
        for f in fixes[5:8]:
            write(ubx_frames(f))
        broken = bytearray(ubx_frames(fixes[8], cov=False))
        broken[-1] ^= 0xFF
        write(bytes(broken))
        got = []
        deadline = time.monotonic() + 10
        while len(got) < 7 and time.monotonic() < deadline:
            got.append(rx.fixes.get(timeout=10))
        time.sleep(1.5)  # the receiver goes silent
        assert rx.counts.get("silences") == 1
        for f in fixes[9:]:
            write(nmea_sentences(f))
        deadline = time.monotonic() + 10
        while len(got) < 14 and time.monotonic() < deadline:
            got.append(rx.fixes.get(timeout=10))
        time.sleep(0.3)
        while not rx.fixes.empty():
            got.append(rx.fixes.get())
        assert rx._thread.is_alive()  # nothing it read stopped the reader
    finally:
        rx.stop()
        os.close(master)
        os.close(slave)
    c = rx.counts
    assert c["nmea_checksum"] == 1 and c["partial"] == 1 and c["ubx_checksum"] == 1
    assert c["garbage_bytes"] >= 250
    # an epoch goes out once it holds the sentences of the previous one (no wait for the next epoch)
    assert [g.t_ns for g in got] == [f.t_ns for f in fixes[:4] + fixes[5:8] + fixes[9:]]
