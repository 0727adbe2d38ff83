"""`zennav gnss-sim`: a simulated NMEA/UBX receiver for `zennav-ingest --gnss-receiver` without hardware."""
from __future__ import annotations

import socket
import sys

import click


@click.command("gnss-sim")
@click.argument("dataset", default="sim:car")
@click.option("-o", "--option", "options", multiple=True, help="loader option key=value (as zennav-ingest)")
@click.option("--pty", "use_pty", is_flag=True, help="write to a new pseudo-terminal; its path is printed")
@click.option("--tcp", "tcp_port", type=int, default=None, help="serve one client on this loopback TCP port")
@click.option("--file", "file_path", type=click.Path(dir_okay=False), default=None, help="write to this file")
@click.option("--format", "fmt", type=click.Choice(["nmea", "ubx", "both", "alternate"]), default="nmea",
              show_default=True, help="alternate: NMEA for the first half of the fixes, UBX for the rest")
@click.option("--speed", type=float, default=1.0, show_default=True, help="times real time; 0: at once")
@click.option("--few-sats", multiple=True, metavar="START:DURATION", help="send 3 satellites in this window [s]")
@click.option("--no-fix", multiple=True, metavar="START:DURATION", help="send fix quality 0 in this window [s]")
def gnss_sim(dataset, options, use_pty, tcp_port, file_path, fmt, speed, few_sats, no_fix):
    """Send DATASET's GNSS fixes (times from its first IMU sample) as a receiver would, paced at SPEED."""

    from ..datasets.registry import load_dataset, parse_loader_options
    from ..replay import outage_windows, parse_outage, run_end_ns
    from .simulate import send_fixes, write_all

    if sum(x is not None and x is not False for x in (use_pty or None, tcp_port, file_path)) != 1:
        raise click.UsageError("give exactly one of --pty, --tcp PORT, --file PATH")
    try:
        ds = load_dataset(dataset, **parse_loader_options(options))
        t0, t_end = int(ds.initial.t_ns), run_end_ns(ds)
        few = outage_windows(t0, t_end, [parse_outage(x) for x in few_sats])
        nofix = outage_windows(t0, t_end, [parse_outage(x) for x in no_fix])
    except ValueError as e:
        raise click.ClickException(str(e)) from None
    fixes = [ds.gnss.fix_at(i) for i in range(len(ds.gnss.t_ns)) if t0 < ds.gnss.t_ns[i] <= t_end]
    half = fixes[len(fixes) // 2].t_ns if fixes else 0
    form = (lambda f: "nmea" if f.t_ns < half else "ubx") if fmt == "alternate" else fmt
    if use_pty:
        from .simulate import open_pty

        fd, _slave, path = open_pty()
        click.echo(path, err=False)
        sys.stdout.flush()
        write = write_all(fd)
    elif tcp_port is not None:
        srv = socket.create_server(("127.0.0.1", tcp_port))
        click.echo(f"waiting for a client on tcp:127.0.0.1:{tcp_port}", err=True)
        conn, _ = srv.accept()
        write = conn.sendall
    else:
        f = open(file_path, "wb")
        write = f.write
    n = send_fixes(write, fixes, form, t0, speed, few, nofix)
    click.echo(f"sent {n} epochs of {ds.name} ({fmt})", err=True)
