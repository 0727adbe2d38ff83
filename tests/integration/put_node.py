"""Test helper process for the secure bus: a zenoh client of the secure router (zennav.bus.open_config with
ZENNAV_SECURE_DIR and --identity's credentials, then the overrides below) that puts --count raw payloads on
each --key and prints one JSON line {"opened": bool, "put": {key: count}, "error": str}.

Overrides (an intruder): --cert/--key-file (another certificate), --no-cert (TLS without a client certificate),
--user/--password (other user/password credentials), --endpoint tcp/... (no TLS at all), --peer (a zenoh peer
instead of a client)."""
from __future__ import annotations

import argparse
import json
import sys
import time

import zenoh

from zennav.bus import open_config


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--endpoint", required=True)
    p.add_argument("--identity", required=True)
    p.add_argument("--key", dest="keys", action="append", required=True)
    p.add_argument("--count", type=int, default=50)
    p.add_argument("--cert")
    p.add_argument("--key-file")
    p.add_argument("--no-cert", action="store_true")
    p.add_argument("--user")
    p.add_argument("--password")
    p.add_argument("--tag", help="first word of every payload (default: the identity)")
    p.add_argument("--peer", action="store_true", help="open the session as a zenoh peer, not a client")
    args = p.parse_args(argv)
    tls = "transport/link/tls/"
    conf = open_config("client", connect=[args.endpoint.replace("tcp/", "tls/")], identity=args.identity)
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("connect/timeout_ms", '{"client": 5000}')  # refused: fail instead of retrying forever
    conf.insert_json5("connect/exit_on_failure", '{"client": true}')
    if args.peer:
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/timeout_ms", '{"peer": 5000}')
        conf.insert_json5("connect/exit_on_failure", '{"peer": true}')
    if args.no_cert:
        conf.insert_json5(tls + "connect_certificate", "null")
        conf.insert_json5(tls + "connect_private_key", "null")
    if args.cert:
        conf.insert_json5(tls + "connect_certificate", json.dumps(args.cert))
        conf.insert_json5(tls + "connect_private_key", json.dumps(args.key_file))
    if args.user:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(args.user))
    if args.password:
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(args.password))
    zenoh.init_log_from_env_or("error")
    try:
        session = zenoh.open(conf)
    except Exception as e:
        print(json.dumps({"opened": False, "put": {}, "error": str(e).splitlines()[0]}), flush=True)
        return 0
    pubs = {k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK,
                                         reliability=zenoh.Reliability.RELIABLE) for k in args.keys}
    time.sleep(1.0)  # let the router's declarations reach this client
    put = {}
    for k, pub in pubs.items():
        for i in range(args.count):
            pub.put(f"{args.tag or args.identity} {i}".encode())
        put[k] = args.count
    time.sleep(1.0)  # flush before closing
    session.close()
    print(json.dumps({"opened": True, "put": put, "error": ""}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
