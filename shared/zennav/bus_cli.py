"""`zennav` subcommands of the transport layer: router, launch, monitor, record, bus-replay, certs.

Bus options (every command): --vehicle, --mode, --zenoh-config, --connect, --listen (or the ZENNAV_*
environment variables; see zennav.bus).
"""
from __future__ import annotations

import sys
import threading
import time

import click

from .stopsignals import on_stop_signals

_PASS = dict(ignore_unknown_options=True, allow_extra_args=True, help_option_names=[])


def _bus_options(f):
    f = click.option("--listen", default=None, help="comma-separated endpoints to listen on")(f)
    f = click.option("--connect", default=None, help="comma-separated endpoints to connect to")(f)
    f = click.option("--zenoh-config", default=None, help="zenoh json5 config file")(f)
    f = click.option("--mode", type=click.Choice(["peer", "client", "router"]), default=None)(f)
    f = click.option("--vehicle", default=None, envvar="ZENNAV_VEHICLE", help="key-space vehicle [car]")(f)
    return f


def _stop_event() -> threading.Event:
    """Set at the first SIGINT/SIGTERM (zennav.stopsignals), for the process's lifetime."""
    ev = threading.Event()
    on_stop_signals(lambda _name: ev.set())
    return ev


@click.command("router")
@click.option("--listen", default=None, help="endpoints, default deploy/zenoh-router.json5 (tcp/127.0.0.1:7447)")
@click.option("--connect", default=None, help="other routers to connect to")
@click.option("--zenoh-config", default=None, help="router config (default deploy/zenoh-router.json5)")
@click.option("--vehicle", default=None, envvar="ZENNAV_VEHICLE")
def router_cmd(listen, connect, zenoh_config, vehicle):
    """Run a Zenoh router (a zenoh session in router mode): the rendezvous of the peers on one host and the
    hub that clients on other hosts connect to. Announces liveliness as service 'router'."""
    from .bus import Bus
    from .service import setup_logging

    setup_logging("INFO")
    bus = Bus("router", vehicle, mode="router", config=zenoh_config, listen=listen, connect=connect or "")
    ev = _stop_event()
    click.echo(f"zennav router {bus.zid} listening on {listen or 'deploy/zenoh-router.json5 endpoints'}", err=True)
    try:
        last = None
        while not ev.wait(5.0):
            peers = (len(bus.peers()), len(bus.routers()))
            if peers != last:
                click.echo(f"router: {peers[0]} peers, {peers[1]} routers connected", err=True)
                last = peers
    finally:
        bus.close()
        click.echo("router stopped", err=True)


@click.command("launch")
@click.argument("launch_file", type=click.Path(exists=True, dir_okay=False))
@click.option("--rendezvous", default=None,
              help="the router's endpoint, overriding the file's (deploy/trainer.yaml has none: the edge's address)")
@click.option("--vehicle", default=None, help="override the file's vehicle")
@click.option("--until", default=None, help="stop everything once this service exits (e.g. ingest)")
@click.option("--secure", "secure_dir", default=None, type=click.Path(exists=True, file_okay=False),
              help="secure variant with the credentials in this directory (`zennav certs DIR`): every service a "
                   "client of the router over mutual TLS with user/password, the router's access control "
                   "(deploy/secure/); the rendezvous becomes tls/")
def launch_cmd(launch_file, rendezvous, vehicle, until, secure_dir):
    """Start the process set described in LAUNCH_FILE (deploy/local.yaml, deploy/edge.yaml, and on another host
    deploy/trainer.yaml --rendezvous tcp/<edge-ip>:7447), wait on liveliness until all are up, prefix each log
    line with the service name, restart per policy, stop all cleanly on Ctrl-C."""
    from .launch import launch_main

    try:
        code = launch_main(launch_file, rendezvous, vehicle, until, secure_dir)
    except (ValueError, KeyError, OSError) as e:
        raise click.ClickException(f"launch file: {e}") from None
    sys.exit(code)


@click.command("monitor", context_settings=_PASS)
@click.pass_context
def monitor_cmd(ctx):
    """Live per-key rate, lag, drops and rejections; services alive, GNSS state, alignment, live GNSS R estimate,
    test ratios, attitude, model version.
    Options: --json, --once, --duration S, --interval S, plus the bus options (see zennav-monitor --help)."""
    from zennav.services.monitor import main

    sys.exit(main(list(ctx.args)))


@click.command("record")
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("-k", "--key", "keys", multiple=True, help="key expression(s) to record [zennav/@v1/<vehicle>/**]")
@click.option("--encoding", type=click.Choice(["json", "msgpack"]), default="json",
              help="json: Foxglove-readable with JSON schemas; msgpack: the raw payloads")
@click.option("--duration", type=float, default=None, help="stop after this many seconds")
@click.option("--until-stream-end", is_flag=True,
              help="stop once every ins seen (also those with a --nav-prefix) acknowledged its stream end and all "
                   "its solutions are recorded")
@click.option("--count", type=int, default=None, help="stop after this many messages")
@_bus_options
def record_cmd(output, keys, encoding, duration, until_stream_end, count, vehicle, mode, zenoh_config, connect,
               listen) -> None:
    """Record every sample on the chosen keys to an MCAP file (Foxglove-openable)."""
    from .bus import Bus
    from .recording import McapRecorder, SolutionTally
    from .service import setup_logging

    setup_logging("INFO")
    bus = Bus("record", vehicle, mode=mode, config=zenoh_config, connect=connect, listen=listen, token=False)
    rec = McapRecorder(output, encoding)
    ev = _stop_event()
    tally = SolutionTally()  # per ins: solutions of its finished stream against the distinct ones recorded

    def on_sample(key: str, payload: bytes, recv_ns: int) -> None:
        msg = rec.add(key, payload, recv_ns)
        if count is not None and rec.count >= count:
            ev.set()
        if until_stream_end:
            tally.add(key, msg)
            if tally.complete():
                ev.set()

    for k in keys or [bus.keys.all()]:
        # recovering: what the cached publishers (sensors, solutions) sent while a link was down is fetched
        bus.recovering_subscribe(k, on_sample, validate=False, channel="fifo", capacity=65536, name="record")
    bus.announce()
    click.echo(f"recording {', '.join(keys or [bus.keys.all()])} to {output} ({encoding})", err=True)
    t0 = time.monotonic()
    try:
        if until_stream_end:  # every ins acknowledged its end: its missing solutions get END_GRACE_S to arrive
            ended_at = None
            while not ev.wait(0.5) and (duration is None or time.monotonic() - t0 < duration):
                if ended_at is None and tally.ended():
                    ended_at = time.monotonic()
                if ended_at is not None and time.monotonic() - ended_at > END_GRACE_S:
                    click.echo("solutions missing after the stream end (sent by a killed ins before its checkpoint, "
                               "lost with it; see zennav.recording.SolutionTally)", err=True)
                    break
            if tally.expected:
                click.echo(f"solutions: {tally.summary()}; not recovered by the subscription: "
                           f"{dict(bus.missed) or 0}", err=True)
        else:
            ev.wait(duration)
    finally:
        bus.close()
        rec.close()
    click.echo(f"recorded {rec.count} messages on {len(rec.per_key)} keys in {time.monotonic() - t0:.1f} s "
               f"to {output}" + (f" ({rec.skipped} invalid payloads not recorded)" if rec.skipped else ""),
               err=True)


END_GRACE_S = 10.0  # `zennav record --until-stream-end`: [s] to wait for solutions after every end acknowledged


@click.command("bus-replay")
@click.argument("recording", type=click.Path(exists=True, dir_okay=False))
@click.option("-k", "--key", "keys", multiple=True,
              help="key patterns to publish ('*' one chunk, '**' any) [zennav/@v1/*/sensor/**]")
@click.option("--speed", default="1", help="1 original timing, N times faster, 0/max as fast as possible")
@click.option("--wait-for", default="ins", help="comma-separated services to wait for before publishing")
@click.option("--wait-timeout", type=float, default=60.0)
@click.option("--raw", is_flag=True, help="republish msgpack payloads as recorded (no header restamp)")
@_bus_options
def bus_replay_cmd(recording, keys, speed, wait_for, wait_timeout, raw, vehicle, mode, zenoh_config, connect,
                   listen):
    """Publish an MCAP recording back onto the bus with its original timing or faster."""
    from .bus import Bus
    from .recording import replay
    from .service import EndAcks, setup_logging

    setup_logging("INFO")
    sp = 0.0 if str(speed).lower() in ("0", "max", "inf") else float(speed)
    bus = Bus("replay", vehicle, mode=mode, config=zenoh_config, connect=connect, listen=listen)
    ev = _stop_event()
    try:
        waits = [w for w in wait_for.split(",") if w]
        if waits and not bus.wait_alive(waits, wait_timeout):
            click.echo(f"gave up waiting for {waits}", err=True)
            sys.exit(2)
        pats = list(keys) or ["zennav/@v1/*/sensor/**"]
        # declare the publishers first and let the subscribers match them
        from .recording import glob_to_regex, read_mcap

        for key, _m, _p, _t in read_mcap(recording, [glob_to_regex(k) for k in pats]):
            if vehicle:
                parts = key.split("/", 3)
                key = f"{parts[0]}/{parts[1]}/{vehicle}/{parts[3]}"
            bus.publisher(key)
        deadline = time.monotonic() + wait_timeout
        while waits and not all(p.matching for p in bus._pubs.values()) and time.monotonic() < deadline:
            if ev.wait(0.01):
                break
        acks = EndAcks(bus)
        t0 = time.monotonic()
        counts = replay(bus, recording, pats, sp, vehicle, ev, raw)
        click.echo(f"replayed {sum(counts.values())} messages on {len(counts)} keys in "
                   f"{time.monotonic() - t0:.2f} s", err=True)
        if "ins" in waits:  # keep the session open until every ins acknowledged the replayed stream's end
            acks.wait(None, wait_timeout, ev.is_set)
    finally:
        bus.close()


@click.command("certs")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--host", "hosts", multiple=True,
              help="a DNS name or IP address clients use to reach the router (repeatable; localhost and 127.0.0.1 "
                   "always): its certificate's subject alternative names")
@click.option("--days", type=float, default=365.0, show_default=True, help="validity of the certificates")
@click.option("--force", is_flag=True, help="replace the credentials already in OUT_DIR")
def certs_cmd(out_dir, hosts, days, force):
    """Write development credentials for the secure bus to OUT_DIR: a CA, a certificate and key per service
    identity (common name = identity), the router's user/password dictionary and each identity's password.
    Use with `zennav launch <set>.yaml --secure OUT_DIR`. Development only: keep ca.key off the vehicle."""
    from pathlib import Path

    from .certs import make_certs

    if (Path(out_dir) / "ca.pem").exists() and not force:
        raise click.ClickException(f"{out_dir} already holds credentials (--force to replace them)")
    files = make_certs(out_dir, hosts, days)
    click.echo(f"wrote {len(files)} files to {out_dir}: CA, {(len(files) - 3) // 3} identities, usrpwd.txt")
