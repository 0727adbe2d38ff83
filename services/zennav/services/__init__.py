"""zennav services: one thin module per process wiring Zenoh keys to the core."""
