"""`zennav demo` on the command line (zennav.demo does the work; imported only when the command runs)."""
from __future__ import annotations

from pathlib import Path

import click

COMPENSATIONS = ("anfis", "anfis-pso", "anfis-ipso", "elman")  # zennav.learn.settings.COMPENSATIONS (checked by a test)
# --vehicle: default dataset, duration [s] and its other loader options (the AUV's DVL loses the bottom for 10 s
# of its dive, so that the no-beam case shows too)
VEHICLES = {"car": ("sim:car", 600.0, {}), "auv": ("sim:auv", 300.0, {"dvl_bottom_loss": "220:10"})}
# --vehicle: the default learned compensation (the car: ANFIS with FR-CG, seed 000; the AUV's DVL beams: ANFIS with
# the improved PSO, seed 003)
DEFAULT_COMPENSATION = {"car": "anfis", "auv": "anfis-ipso"}


@click.command()
@click.option("--vehicle", type=click.Choice(tuple(VEHICLES)), default="car", show_default=True,
              help="car: the GNSS/INS learning loop (deploy/demo.yaml); auv: the AUV with DVL and depth "
                   "(deploy/auv.yaml, zennav.demo_auv; sim:auv, 300 s: 120 s at the surface, then a dive, the "
                   "bottom lost 220..230 s).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where the recording, nav.txt, nav.csv, metrics.json, the plots and the services' log go  "
                   "[default: out/demo, out/demo-auv]")
@click.option("--dataset", default=None,
              help="What ingest streams: any `zennav replay` DATASET (the simulated drives need no external data; "
                   "--vehicle auv: one with a DVL)  [default: sim:car, sim:auv]")
@click.option("--duration", type=click.FloatRange(min=30.0), default=None,
              help="Length of a simulated drive [s] (sim:* only)  [default: 600, auv 300]")
@click.option("--outage", "outages", multiple=True, metavar="START:DURATION",
              help="GNSS outage [s from the start] (repeatable)  [default: 300:60 unless --outage-every]")
@click.option("--outage-every", "every", default=None, metavar="PERIOD:DURATION[:FIRST]",
              help="Periodic GNSS outages [s] (first at 60 s unless FIRST).")
@click.option("--compensation", type=click.Choice(COMPENSATIONS), default=None,
              help="The learning loop's model: ANFIS with FR-CG (seed 000), PSO or improved PSO (seed 003) "
                   "premises, or Elman (seed 002)  [default: anfis, auv anfis-ipso]")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the learned model.")
@click.option("--launch-file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The process set to run [deploy/demo.yaml, deploy/auv.yaml]; it needs 'record', 'ingest' and "
                   "'trainer' services.")
def demo(vehicle, out, dataset, duration, outages, every, compensation, seed, launch_file):
    """Run the whole process set on loopback (deploy/demo.yaml: router, two ins, attitude, trainer, predictor,
    monitor, record, ingest) over a dataset with GNSS outages (default: the built-in simulated car drive, 200 Hz
    MEMS IMU and 1 Hz GNSS, GNSS withheld 300..360 s), as fast as it drains without loss. The learning loop runs
    over the bus (ins -> trainer -> predictor -> ins, in lockstep); a second ins without learning navigates the
    same stream. Prints the accuracy of both against the truth, what the learning loop did, and the largest
    difference from the same run in one process (`zennav replay DATASET --compensation ...`).

    --vehicle auv: the simulated AUV through deploy/auv.yaml (ins with the auv profile fusing DVL beams and
    depth, trainer, predictor, monitor, record, ingest); prints, for each stretch under water, the horizontal
    error at its end and the drift as a percentage of the distance travelled, the DVL and depth updates and the
    partial-beam counters, and the largest difference from the in-process replay. No GNSS outages to choose:
    GNSS is absent under water."""
    from .datasets.errors import DataError
    from .demo import DEMO_LAUNCH, DemoSpec, run_demo
    from .replay import parse_outage, parse_outage_every
    from .replay_cli import _setup_logging

    _setup_logging(0)
    compensation = compensation or DEFAULT_COMPENSATION[vehicle]
    dataset = dataset or VEHICLES[vehicle][0]
    out = out or Path("out/demo" if vehicle == "car" else f"out/demo-{vehicle}")
    sim = dataset.startswith("sim:")
    if duration is not None and not sim:
        raise click.BadParameter("only a simulated drive (sim:*) has a duration", param_hint="--duration")
    options = {"duration_s": float(duration or VEHICLES[vehicle][1]),
               **(VEHICLES[vehicle][2] if dataset == VEHICLES[vehicle][0] else {})} if sim else {}
    if vehicle == "auv":
        from .demo_auv import AUV_LAUNCH, run_auv_demo

        if outages or every:
            raise click.BadParameter("the AUV has no GNSS under water: no outages to choose", param_hint="--outage")
        try:
            run_auv_demo(out, DemoSpec(dataset, options, [], None, compensation, seed), launch_file or AUV_LAUNCH)
        except DataError as e:
            raise click.ClickException(str(e)) from None
        return
    try:
        windows = [parse_outage(o) for o in (outages or (() if every else ("300:60",)))]
        periodic = parse_outage_every(every) if every else None
    except ValueError as e:
        raise click.BadParameter(str(e)) from None
    if sim and any(s + d > options["duration_s"] for s, d in windows):
        raise click.BadParameter(f"an outage ends after the {options['duration_s']:g} s drive", param_hint="--outage")
    try:
        run_demo(out, DemoSpec(dataset, options, windows, periodic, compensation, seed), launch_file or DEMO_LAUNCH)
    except DataError as e:
        raise click.ClickException(str(e)) from None
