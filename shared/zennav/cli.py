"""The `zennav` console command.

Units at this edge: degrees for angles, metres, m/s, seconds; inside everything is SI/radians.
Frames: navigation frame NED, body frame forward-right-down (FRD).
"""
from __future__ import annotations

import click


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="zennav")
def main():
    """zennav: GNSS/INS navigation that keeps position, velocity and attitude through GNSS outages.

    Frames: navigation frame n is NED (north-east-down), body frame b is forward-right-down.
    Units on the command line and in reports: degrees, metres, m/s, seconds (SI and radians inside).
    """


# Subcommands register below (one import per command module).
from .demo_cli import demo  # noqa: E402
from .replay_cli import replay, report  # noqa: E402

main.add_command(replay)
main.add_command(report)
main.add_command(demo)
from .bus_cli import bus_replay_cmd, certs_cmd, launch_cmd, monitor_cmd, record_cmd, router_cmd  # noqa: E402

main.add_command(router_cmd)
main.add_command(launch_cmd)
main.add_command(monitor_cmd)
main.add_command(record_cmd)
main.add_command(bus_replay_cmd)
main.add_command(certs_cmd)
from .receivers.cli import gnss_sim  # noqa: E402

main.add_command(gnss_sim)
from .keys_cli import keys_cmd  # noqa: E402

main.add_command(keys_cmd)
