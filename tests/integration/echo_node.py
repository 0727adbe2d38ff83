"""Test helper process: republishes every valid message of --in (a key of the grammar) on --out, unchanged
except for the header (src, seq, pub_ns).
Run as ``python echo_node.py --in KEY --out KEY <bus options>``; announces liveliness as 'echo'."""
from __future__ import annotations

import argparse
import sys

from zennav.service import ServiceRunner, add_bus_args


def main(argv=None) -> int:
    p = add_bus_args(argparse.ArgumentParser())
    p.add_argument("--in", dest="inp", required=True)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    run = ServiceRunner("echo", args)
    pub = run.bus.publisher(args.out)
    n = {"echoed": 0}

    def on(key, msg, recv_ns):
        pub.put(msg)
        n["echoed"] += 1

    run.counters = lambda: dict(n)
    run.bus.subscribe(args.inp, on, channel="fifo")
    return run.serve()


if __name__ == "__main__":
    sys.exit(main())
