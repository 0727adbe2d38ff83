"""`zennav demo` on the command line (zennav.demo does the work; imported only when the command runs)."""
from __future__ import annotations

from pathlib import Path

import click

COMPENSATIONS = ("anfis", "anfis-pso", "anfis-ipso", "elman")  # zennav.learn.settings.COMPENSATIONS (checked by a test)


@click.command()
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("out/demo"), show_default=True,
              help="Where the recording, nav.txt, nav.csv, metrics.json, the plots and the services' log go.")
@click.option("--dataset", default="sim:car", show_default=True,
              help="What ingest streams: any `zennav replay` DATASET (the simulated drives need no external data).")
@click.option("--duration", type=click.FloatRange(min=30.0), default=None,
              help="Length of a simulated drive [s] (sim:* only)  [default: 600]")
@click.option("--outage", "outages", multiple=True, metavar="START:DURATION",
              help="GNSS outage [s from the start] (repeatable)  [default: 300:60 unless --outage-every]")
@click.option("--outage-every", "every", default=None, metavar="PERIOD:DURATION[:FIRST]",
              help="Periodic GNSS outages [s] (first at 60 s unless FIRST).")
@click.option("--compensation", type=click.Choice(COMPENSATIONS), default="anfis", show_default=True,
              help="The learning loop's model: ANFIS with FR-CG (seed 000) or PSO (seed 003) premises, or Elman "
                   "(seed 002).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the learned model.")
@click.option("--launch-file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The process set to run [deploy/demo.yaml]; it needs 'record', 'ingest' and 'trainer' services.")
def demo(out, dataset, duration, outages, every, compensation, seed, launch_file):
    """Run the whole process set on loopback (deploy/demo.yaml: router, two ins, attitude, trainer, predictor,
    monitor, record, ingest) over a dataset with GNSS outages (default: the built-in simulated car drive, 200 Hz
    MEMS IMU and 1 Hz GNSS, GNSS withheld 300..360 s), as fast as it drains without loss. The learning loop runs
    over the bus (ins -> trainer -> predictor -> ins, in lockstep); a second ins without learning navigates the
    same stream. Prints the accuracy of both against the truth, what the learning loop did, and the largest
    difference from the same run in one process (`zennav replay DATASET --compensation ...`)."""
    from .datasets.errors import DataError
    from .demo import DEMO_LAUNCH, DemoSpec, run_demo
    from .replay import parse_outage, parse_outage_every
    from .replay_cli import _setup_logging

    _setup_logging(0)
    sim = dataset.startswith("sim:")
    if duration is not None and not sim:
        raise click.BadParameter("only a simulated drive (sim:*) has a duration", param_hint="--duration")
    try:
        windows = [parse_outage(o) for o in (outages or (() if every else ("300:60",)))]
        periodic = parse_outage_every(every) if every else None
    except ValueError as e:
        raise click.BadParameter(str(e)) from None
    options = {"duration_s": float(duration or 600.0)} if sim else {}
    if sim and any(s + d > options["duration_s"] for s, d in windows):
        raise click.BadParameter(f"an outage ends after the {options['duration_s']:g} s drive", param_hint="--outage")
    try:
        run_demo(out, DemoSpec(dataset, options, windows, periodic, compensation, seed), launch_file or DEMO_LAUNCH)
    except DataError as e:
        raise click.ClickException(str(e)) from None
