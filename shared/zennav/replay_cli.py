"""`zennav replay`: the core in one process over a dataset, with its accuracy."""
from __future__ import annotations

import json
import logging
import math
import shutil
from dataclasses import replace
from pathlib import Path

import click

# zennav.nav.learning.TARGETS, written out so that the command line starts without the core (a test ties them)
TARGETS = ("position", "velocity", "drift", "body_velocity", "dvl_beam")
KF_GINS_NAV = "KF_GINS_Navresult.nav"  # KF-GINS's solution file, written beside nav.txt for a KF-GINS configuration


def _click_parser(name: str):
    """zennav.replay's outage parser `name` as a click value parser (ValueError -> BadParameter), imported when a
    value is parsed."""
    def conv(text: str):
        from . import replay

        try:
            return getattr(replay, name)(text)
        except ValueError as e:
            raise click.BadParameter(str(e)) from None
    return conv


_parse_outage = _click_parser("parse_outage")
_parse_every = _click_parser("parse_outage_every")


def replay_dataset(spec: str, outages, every, out: Path | None, as_json: bool, compensation: str = "none",
                   target: str = "body_velocity", heading_unknown: bool = False, adaptive_r: bool | None = None,
                   seed: int = 0, params: Path | None = None, nhc: bool | None = None, mcap: Path | None = None,
                   quiet: bool = False, smooth: bool = False, profile: str | None = None,
                   constraints: list[str] | None = None, odometer: Path | None = None,
                   options: dict | None = None, dvl: str | None = None, vb: list[str] | None = None) -> dict:
    """Load, replay, evaluate, write and print; returns the metrics. heading_unknown: start from the dataset's
    initial state without its yaw (alignment); adaptive_r: override the parameter file's adaptive_r (None: keep);
    seed: of the learned model; params: the ins's filter parameter file (None: deploy/ins.yaml, as the ins);
    profile: a vehicle profile of the parameter file ("dataset": the dataset's vehicle) that sets the constraints;
    constraints: the constraint names to run instead (wins over the profile); nhc: override the non-holonomic
    constraint after both (None: keep); odometer: a KF-GINS-Matlab ODO file of wheel speeds for the dataset;
    mcap: also write the run as a Foxglove-ready MCAP; quiet: no progress line (there is none either when stderr is
    not a terminal); smooth: also the forward-backward smoothed solution (metrics under "smoothed", files under
    smoothed/); options: the dataset loader's options (e.g. duration_s, seed of a simulated drive); dvl: the DVL mode
    (off, loose, tight; None: the parameter file's); vb: the sources with variational-Bayes R ("dvl", "gnss"; None:
    the parameter file's)."""
    from .datasets.errors import DataError
    from .datasets.odometer import load_kfgins_odometer
    from .datasets.registry import load_dataset
    from .gpstime import WEEK_NS
    from .metrics import evaluate, format_table, write_outputs, write_solution
    from .params import ParamError, nav_config
    from .progress import Progress
    from .replay import run_replay, sensor_events
    from .run_outputs import RunRecorder

    try:
        # the truth read after the run, a long IMU file while it starts (zennav.datasets.streamed): start-up time
        ds = load_dataset(spec, defer_truth=True, stream_imu=True, **(options or {}))
        if odometer is not None:
            ds.odometer = load_kfgins_odometer(odometer)
        # the ins's filter on the dataset's sensors
        ds.config = nav_config(ds.config, filter_settings(spec, params, profile, constraints))
    except (DataError, ParamError) as e:
        raise click.ClickException(str(e)) from None
    shown = len(ds.notes.get("remarks") or [])
    for remark in ds.notes.get("remarks") or []:  # what a loader changed or left out (KF-GINS configurations)
        click.echo(f"note: {remark}", err=True)
    kf_gins = ds.notes.get("format") == "KF-GINS"
    if out is None and kf_gins:  # as KF-GINS: into the configuration's outputpath
        out = Path(ds.notes["outputpath"])
    if heading_unknown:
        ds.initial = replace(ds.initial, heading_known=False)
    if adaptive_r is not None:
        ds.config = ds.config.with_(adaptive_r=adaptive_r)
    if nhc is not None:
        ds.config = ds.config.with_(nhc=nhc)
    if dvl is not None:
        ds.config = ds.config.with_(dvl_mode=dvl)
    if vb is not None:
        ds.config = ds.config.with_(vb_dvl="dvl" in vb, vb_gnss="gnss" in vb)
    progress = Progress.of_replay(ds, f"replay {ds.name}", quiet)
    recorder = RunRecorder(int(ds.initial.t_ns), mcap)

    def on_epoch(nav) -> None:
        recorder.on_epoch(nav)
        progress.on_epoch(nav)

    compensator = None
    if compensation != "none":  # the learning loop (its modules) only when asked for: start-up time
        from .learn.loop import make_compensator

        compensator = make_compensator(compensation, target, seed, fit_worker=True)
    try:  # a long IMU file is read while the run starts (zennav.datasets.streamed): its defects show here
        res = run_replay(ds, outages=list(outages), outage_every=every, compensator=compensator, on_epoch=on_epoch,
                         smoothing=smooth, epoch_due=recorder.due_ns)
    except DataError as e:
        raise click.ClickException(str(e)) from None
    finally:
        progress.close()
    for remark in (ds.notes.get("remarks") or [])[shown:]:  # on the part read while the run started
        click.echo(f"note: {remark}", err=True)
    run_s = (int(ds.imu.t_ns[-1]) - int(ds.imu.t_ns[0])) / 1e9  # outage times count from the first IMU sample
    for start, duration in outages:
        if start >= run_s:
            click.echo(f"note: outage {start:g}:{duration:g} starts after the run's {run_s:.1f} s: none", err=True)
    if "truth_file" in ds.notes:  # a KF-GINS truth file, read after the run
        from .datasets.kfgins import load_deferred_truth

        try:
            load_deferred_truth(ds)
        except DataError as e:
            raise click.ClickException(str(e)) from None
    recorder.finish(ds, sensor_events(ds, list(outages), every)[1] if mcap is not None else [], res.reports)
    metrics = evaluate(ds, res)
    learned = compensation != "none"
    metrics["compensation"] = {"model": compensation, "target": target if learned else None,
                               "seed": seed if learned else None}
    if compensator is not None:
        metrics["compensation"]["counters"] = compensator.status()  # (the last fits, if any are due)
        compensator.close()
    if res.smoothed is not None:
        metrics["smoothed"] = evaluate(ds, res.smoothed)
        metrics["smoothed"].pop("engine")
        metrics["smoothed"]["smoother"] = res.smoothed.status["smoother"]
    if out is not None:
        write_outputs(out, ds, res, metrics)
        recorder.write(out, res.reports, spec, options)
        if res.smoothed is not None:
            write_solution(out / "smoothed", res.smoothed)
        if kf_gins:  # the names KF-GINS gives its solution and its IMU errors, for the scripts that read them
            shutil.copyfile(out / "nav.txt", out / KF_GINS_NAV)
            recorder.write_kf_gins(out, int(res.t_ns[0] // WEEK_NS))
    click.echo(json.dumps(metrics, indent=2) if as_json else format_table(metrics))
    if res.smoothed is not None and not as_json:
        click.echo("smoothed (forward-backward):\n" + format_table(metrics["smoothed"]))
    if not as_json:
        click.echo(_gnss_summary(res.status["counters"]))
    if compensator is not None and not as_json:
        click.echo(_learning_summary(metrics["compensation"], res.status["counters"]))
    if not as_json and (heading_unknown or adaptive_r is not None or res.status["alignment"]["method"] != "given"):
        click.echo(_alignment_summary(res.status, int(ds.initial.t_ns)))
    if out is not None and not as_json:
        smoothed = f", {out / 'smoothed' / 'nav.txt'}, {out / 'smoothed' / 'nav.csv'}" if smooth else ""
        kf_nav = f", {KF_GINS_NAV}, KF_GINS_IMU_ERR.txt, KF_GINS_STD.txt" if kf_gins else ""
        click.echo(f"wrote {out / 'nav.txt'}{kf_nav}, {out / 'nav.csv'}, {out / 'metrics.json'}, aid.csv, biases.csv, "
                   f"run.json{smoothed}")
    if mcap is not None and not as_json:
        click.echo(f"wrote {mcap} (opens in Foxglove: map, 3-D pose, every message)")
    return metrics


def _gnss_summary(counters: dict) -> str:
    """One line on the GNSS fixes: fused, refused per reason (zennav.nav.aid.gnss's counters), gate resets and
    outages, and a configured initial state the first fixes rejected, so that a run whose fixes were refused says so
    beside its table."""
    fused = {k[5:-6]: n for k, n in counters.items() if k.startswith("gnss_") and k.endswith("_fused")}
    skip = ("_fused", "_inflated")
    refused = {k[5:]: n for k, n in counters.items()
               if k.startswith("gnss_") and not k.endswith(skip) and k != "gnss_align_coarse"}
    text = "GNSS fused: " + (", ".join(f"{k} {n}" for k, n in fused.items()) or "none")
    text += "; refused: " + (", ".join(f"{k} {n}" for k, n in sorted(refused.items())) or "none")
    resets, outages = counters.get("gate_reset", 0), counters.get("outage_declared", 0)
    text += f"; gate resets {resets}, outages declared {outages}"
    if counters.get("init_state_rejected"):  # zennav.nav.alignment: the first fixes contradicted it
        text += "; the configured initial state was rejected by the first fixes (aligned from the fixes instead)"
    elif counters.get("init_state_reset_pos_vel"):
        text += "; the configured initial position and velocity were reset from the first fixes (attitude kept)"
    return text


def _learning_summary(compensation: dict, engine_counters: dict) -> str:
    """One line on what the learning loop did: training samples, sets made, queries and their fate; says so when no
    model was made (the run then equals the plain one)."""
    target, trainer = compensation["target"], compensation["counters"]["trainer"]
    received, version = trainer.get(f"received_{target}", 0), trainer.get(f"version_{target}", 0)
    predictor = compensation["counters"]["predictor"]
    fused = sum(n for k, n in engine_counters.items() if k.startswith("learned_") and k.endswith("_fused"))
    answers = ", ".join(f"{k} {n}" for k, n in sorted(predictor.items())) or "none"
    made = f"{version} model sets" if version else \
        f"no model made (it needs {trainer.get(f'min_samples_{target}', '?')} samples): the run equals a plain one"
    return (f"learning ({compensation['model']}, {target}): {received} training samples, {made}; "
            f"queries {compensation['counters']['link']['queries']} ({answers}); answers fused {fused}")


def filter_settings(spec: str, params: Path | None, profile: str | None, constraints: list[str] | None) -> dict:
    """The parameter file's filter settings ({NavConfig field: SI value}) with a vehicle profile's constraints and
    settings (a name of the file's profiles, "dataset": the dataset's vehicle, "none": none; None: the file's own
    constraints.profile) and then an explicit list of constraint names, which wins. ParamError for an unknown
    profile or constraint."""
    from .datasets.registry import vehicle_of
    from .params import constraint_flags, load_filter_params

    settings = load_filter_params(params, vehicle_of(spec) if profile == "dataset" else profile)
    if constraints is not None:
        settings.update(constraint_flags(constraints))
    return settings


def _alignment_summary(status: dict, t0_ns: int) -> str:
    """Alignment and measurement-noise lines of the engine's final status (times in s from the run start)."""
    import numpy as np

    al = status["alignment"]
    times = ", ".join(f"{k} at {(v - t0_ns) / 1e9:.2f} s" for k, v in al["times_ns"].items())
    lines = [(f"alignment: {al['state']} ({al['method'] or 'not yet'}; {times}), heading 1-sigma "
              f"{math.degrees(al['heading_std_rad']):.3f} deg, roll/pitch from {al['tilt_source']}")]
    if al.get("waiting"):
        lines.append(f"alignment waits for: {al['waiting']}")
    for src, r in status["measurement_noise"].items():
        ratio = "" if "scale_diag" not in r else f", R / reported {[round(x, 2) for x in r['scale_diag']]}"
        unit = {"gnss_pos": " [m^2, NED]", "gnss_vel": " [(m/s)^2, NED]"}.get(src, " [SI units squared]")
        lines.append(f"{src} R diag{unit}: {[float(f'{x:.3g}') for x in np.diag(r['R'])]}{ratio}")
    return "\n".join(lines)


_outage_opts = [
    click.option("--outage", "outages", multiple=True, callback=lambda c, p, v: [_parse_outage(x) for x in v],
                 metavar="START:DURATION", help="Withhold GNSS from START for DURATION seconds (from the first IMU "
                 "sample of the run). Repeatable."),
    click.option("--outage-every", "every", default=None, metavar="PERIOD:DURATION[:FIRST]",
                 callback=lambda c, p, v: _parse_every(v) if v else None,
                 help="Withhold GNSS for DURATION seconds every PERIOD seconds, the first at FIRST "
                 "(default PERIOD-DURATION)."),
    click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
                 help="Write nav.txt (KF-GINS .nav: week, sow, lat/lon deg, h m, v NED m/s, roll/pitch/yaw deg), "
                 "nav.csv and metrics.json here [a KF-GINS configuration's outputpath, with KF_GINS_Navresult.nav; "
                 "else nothing]."),
    click.option("--json", "as_json", is_flag=True, help="Print metrics.json instead of the table."),
    click.option("--compensation", type=click.Choice(["none", "anfis", "anfis-pso", "anfis-ipso", "elman"]),
                 default="none", show_default=True, help="Learned INS-error compensation during outages, the "
                 "trainer's and predictor's learning loop in this process (zennav.learn.loop, default "
                 "LearnSettings): anfis (premises by hybrid LSE + Fletcher-Reeves CG, seed 000), anfis-pso "
                 "(premises by particle swarm, seed 003), anfis-ipso (seed 003's improved swarm: inertia 0.9 -> 0.4, "
                 "c1 2.5 -> 0.5, c2 0.5 -> 2.5), elman (online Elman network, seed 002)."),
    click.option("--target", type=click.Choice(TARGETS), default="body_velocity", show_default=True,
                 help="What the model learns (zennav.nav.learning): the filter's position corrections (seed 000), its "
                 "velocity corrections, i.e. increments of INS minus filter (seed 002), the drift of a free INS "
                 "since a fix, or the vehicle's body-frame velocity (a learned motion model), or each DVL beam's error "
                 "(seed 003: learned at the surface, compensated under water by the anomaly discrimination)."),
    click.option("--seed", type=int, default=0, show_default=True,
                 help="Seed of the learned model (ANFIS: k-means rule base and premises; Elman: initial weights)."),
    click.option("-v", "--verbose", count=True, help="Log engine events (-v: warnings, -vv: debug)."),
    click.option("--mcap", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="Also write the run as an MCAP recording that Foxglove shows without configuration "
                 "(foxglove.LocationFix, PoseInFrame, FrameTransform, the zennav messages; log time = sample time)."),
    click.option("-q", "--quiet", is_flag=True, help="No progress line on stderr (none either when not a terminal)."),
]


def _vb_sources(text: str) -> list[str]:
    """--vb's comma-separated source list (dvl, gnss, none) -> the names; click.BadParameter for another name."""
    names = [x for x in text.split(",") if x and x != "none"]
    if any(n not in ("dvl", "gnss") for n in names):
        raise click.BadParameter(f"{text!r}: a comma-separated list of dvl, gnss, or none")
    return names


def _with_outage_opts(f):
    for opt in reversed(_outage_opts):
        f = opt(f)
    return f


def _setup_logging(verbose: int) -> None:
    level = {0: logging.ERROR, 1: logging.WARNING}.get(verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


@click.command()
@click.argument("dataset", required=False)
@click.option("--kf-gins-config", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="A KF-GINS YAML configuration; its IMU/GNSS files, time window, initial state, IMU noise "
              "and lever arm are used unchanged.")
@click.option("--heading-unknown", is_flag=True,
              help="Ignore the dataset's initial yaw: align at rest (gyrocompassing where the gyro allows it) or in "
              "motion from the GNSS velocity (align_in_motion: yaw = course above align_min_speed_mps, 3 m/s; the "
              "multirotor profile: from the velocity changes against the IMU's; the auv profile: from the DVL's "
              "velocity against the GNSS's, from 1 m/s).")
@click.option("--params", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The ins's filter parameter file (human units) [deploy/ins.yaml]: the same filter as zennav-ins.")
@click.option("--adaptive-r/--no-adaptive-r", "adaptive_r", default=None,
              help="Innovation-based adaptive GNSS measurement noise (seed 001); default: the parameter file's (off).")
@click.option("--nhc/--no-nhc", "nhc", default=None,
              help="Non-holonomic constraint of a land vehicle (no sideslip, no jump), after --profile and "
                   "--constraints; default: the parameter file's (off).")
@click.option("--profile", default=None, metavar="NAME",
              help="Vehicle profile of the parameter file (car: nhc, zupt, odo; multirotor: zupt; fixed-wing: none; "
                   "pedestrian: zupt; auv: none, alignment by the DVL from 1 m/s; multirotor: alignment by velocity "
                   "changes), 'dataset' for the dataset's "
                   "vehicle, or none; sets the constraints and the settings it lists. Default: the parameter file's "
                   "constraints.profile (none).")
@click.option("--constraints", "constraints", default=None, metavar="LIST",
              callback=lambda c, p, v: None if v is None else [x for x in v.split(",") if x and x != "none"],
              help="The vehicle constraints to run, comma-separated from nhc, zupt, odo, or none; wins over "
                   "--profile.")
@click.option("--odometer", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Wheel speeds for the dataset, a KF-GINS-Matlab ODO file (time of week [s], forward speed [m/s]); "
                   "used with the odo constraint.")
@click.option("--smooth", is_flag=True,
              help="Also smooth the run forward-backward (Rauch-Tung-Striebel over the error-state filter, all "
                   "states): metrics of both, the smoothed nav.txt/nav.csv under OUT/smoothed/.")
@click.option("-o", "--option", "options", multiple=True, metavar="KEY=VALUE",
              help="A dataset loader option, as zennav-ingest's (repeatable): e.g. -o duration_s=120 -o seed=3 for a "
                   "simulated drive.")
@click.option("--dvl", "dvl", type=click.Choice(["off", "loose", "tight"]), default=None,
              help="DVL aiding where the dataset has a DVL (sim:auv): tight (per beam, with beam-bias and scale-factor "
                   "states), loose (its 3-D velocity) or off; default: the parameter file's (tight).")
@click.option("--vb", "vb", default=None, metavar="LIST",
              callback=lambda c, p, v: None if v is None else _vb_sources(v),
              help="Variational-Bayes adaptive measurement noise on these sources, comma-separated from dvl, gnss, "
                   "or none; default: the parameter file's (none).")
@_with_outage_opts
def replay(dataset, kf_gins_config, heading_unknown, params, adaptive_r, nhc, profile, constraints, odometer, smooth,
           options, dvl, vb, outages, every, out, as_json, compensation, target, seed, verbose, mcap, quiet):
    """Run the navigation core in one process over DATASET and print its accuracy against the truth.

    DATASET: rtklibexplorer, comma2k19, ansfl:Horizontal/path_N (also Vertical/, StraightLine/), akit:TrajectoryN,
    sim:car, sim:multirotor, sim:static, sim:auv, a dataset folder, or a KF-GINS YAML file (same as
    --kf-gins-config). Position errors are horizontal/vertical in metres,
    velocity in m/s, attitude in degrees; errors are computed only where truth exists.
    """
    from .datasets.registry import parse_loader_options

    _setup_logging(verbose)
    if (dataset is None) == (kf_gins_config is None):
        raise click.UsageError("give exactly one of DATASET or --kf-gins-config")
    replay_dataset(str(kf_gins_config or dataset), outages, every, out, as_json, compensation, target,
                   heading_unknown, adaptive_r, seed, params, nhc, mcap, quiet, smooth, profile, constraints,
                   odometer, parse_loader_options(options), dvl, vb)


@click.command("report")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the plots and index.html [RUN_DIR/report].")
@click.option("--dataset", default=None, help="The run's dataset spec, for its truth [RUN_DIR/run.json's, else the "
              "name in metrics.json] (a demo folder: sim:car, with -o duration_s=... for a shorter drive).")
@click.option("-o", "--option", "options", multiple=True, help="Loader option key=value of --dataset (repeatable).")
def report(run_dir, out, dataset, options):
    """Plots and one self-contained HTML page of a run folder (zennav replay --out, zennav demo): track with the
    GNSS outages, position errors against time, innovation test ratios per aid source, estimated biases with
    their 1-sigma, learned answers against the truth, and the accuracy table (forward and smoothed/ side by side)."""
    from .datasets.registry import parse_loader_options
    from .report import write_report

    page = write_report(run_dir, out, dataset, parse_loader_options(options))
    click.echo(f"wrote {page} and {', '.join(p.name for p in sorted(page.parent.glob('*.png')))}")
