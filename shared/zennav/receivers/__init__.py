"""Live GNSS receivers: NMEA 0183 (pynmea2) and u-blox UBX (pyubx2) from a serial port (pyserial), a TCP stream or
a file, turned into zennav GNSS fixes (GPS time, SI units, radians) for the ingest (``zennav-ingest
--gnss-receiver LINK``).

framing (bytes -> NMEA sentences and UBX frames), epoch (messages of one time tag), nmea and ubx (-> GnssFix),
receiver (links and the reading thread, counted errors), live (the ingest's stream with the receiver's fixes),
encode and simulate (fixes -> receiver output, for tests and ``zennav gnss-sim``).
"""
