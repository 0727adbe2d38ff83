"""`zennav demo --vehicle auv`: the simulated AUV through the services on loopback, scored against the truth.

1. Launches deploy/auv.yaml on a free loopback port (zennav.launch, as `zennav demo` does with demo.yaml):
   router, ins (the "auv" vehicle profile of deploy/ins.yaml: no land-vehicle constraints; the DVL source and the
   depth source run because the stream has their sensors), predictor, trainer, monitor, record and ingest, each a
   process. ingest streams the simulated AUV (sim:auv: GNSS at the surface only, then a dive with DVL beams and
   depth) as fast as the pipeline drains without loss.
2. Meanwhile a thread runs the same data in process (zennav.replay.run_replay, the same parameter file and
   profile).
3. Checks that no IMU, GNSS, DVL or depth sample was lost or duplicated, compares the distributed solution with
   the in-process one (the largest differences), and prints the AUV's figures: for each stretch under water the
   distance travelled, the horizontal error at its end and as a percentage of that distance
   (zennav.metrics.dives); the DVL and depth updates of the ins (its nav/aid/dvl, nav/aid/depth records in the
   recording: fused, rejected by reason) and the engine's counters of the partial-beam cases (dvl_beams_<case>:
   4, 3, 2 orthogonal, 2 parallel, 1, 0 valid beams) and rejections. Writes nav.txt, nav.csv, metrics.json, the
   plots and the services' log.

The learning loop runs over the bus with the target dvl_beam (seed 003): the ins sends each beam's features and
error at the surface, the trainer fits the ANFIS (--compensation, default anfis-ipso: the improved PSO), the
predictor answers each beam's predicted error under water and the ins's anomaly discrimination decides which
beams it compensates (zennav.nav.aid.dvl_learned), in lockstep. The in-process twin (2.) runs the same loop
(zennav.learn.loop.InProcessLoop) and must agree bit for bit; a third, in-process run without the learned
compensation gives the comparison row. Prints what the loop did (sets, answers, the ins's decisions per beam).
"""
from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import click

from .demo import (
    DemoSpec,
    _background,
    _learning_lines,
    _verdict,
    compare,
    learning_over_the_bus,
    pipeline_result,
    recording_stats,
    run_set,
    write_plots,
)
from .metrics import dives, evaluate, format_table, write_outputs
from .nav.types import NS
from .replay import run_end_ns, run_replay

AUV_LAUNCH = Path(__file__).resolve().parents[2] / "deploy" / "auv.yaml"
PROFILE = "auv"  # the vehicle profile of deploy/ins.yaml the set's ins runs (zennav-ins --profile auv)
UNDERWATER_SOURCES = ("dvl", "dvl_loose", "depth")  # the ins's aid sources of an AUV (nav/aid/<source>)
TARGET = "dvl_beam"  # the target variant the AUV's learning loop learns (zennav.nav.learning)


def aid_records(recording: Path) -> dict[str, dict]:
    """The ins's DVL and depth status records in the recording, per source: records, fused, rejected by reason,
    fault flags (the partial-beam case of each DVL sample is one)."""
    from .recording import read_mcap

    out: dict[str, dict] = {}
    pattern = r"/nav/aid/(" + "|".join(UNDERWATER_SOURCES) + r")$"
    for _key, msg, _payload, _t in read_mcap(recording, [pattern]):
        if msg is None:
            continue
        a = out.setdefault(msg["source"], {"records": 0, "fused": 0, "rejected": Counter(), "faults": Counter()})
        a["records"] += 1
        a["fused"] += bool(msg["fused"])
        if not msg["fused"]:
            a["rejected"][msg["reason"].split(":", 1)[0] or "-"] += 1
        a["faults"].update(msg.get("faults") or [])
    return {s: {**a, "rejected": dict(a["rejected"]), "faults": dict(a["faults"])} for s, a in out.items()}


def _dive_lines(rows: list[dict]) -> list[str]:
    if not rows:
        return ["  no stretch under water in this run (the truth never deeper than the surface threshold)"]
    return [f"  dive {i}: {d['start_s']:.0f}..{d['end_s']:.0f} s under water, {d['distance_m']:.0f} m travelled: "
            f"horizontal error at its end {d['end_horizontal_m']:.2f} m = {d['drift_pct']:.3f} % of the distance "
            f"(largest {d['max_horizontal_m']:.2f} m)" for i, d in enumerate(rows, 1)]


def _counter_lines(status: dict, records: dict[str, dict]) -> list[str]:
    counters = {k: v for k, v in status["counters"].items() if k.startswith(("dvl", "depth"))}
    beams = {k[len("dvl_beams_"):]: v for k, v in counters.items() if k.startswith("dvl_beams_")}
    consumed = ", ".join(f"{n} {a}" for a, n in (status.get("aid_counts") or {}).items())
    lines = [f"  samples consumed by the ins: {consumed}"]
    for src, a in records.items():
        lines.append(f"  {src:<6} updates {a['records']}: fused {a['fused']}, rejected {a['rejected'] or 0}")
    lines.append(f"  partial-beam cases (valid beams per DVL sample): {beams or 'none counted'}")
    rest = {k: v for k, v in counters.items() if not k.startswith("dvl_beams_")}
    if rest:
        lines.append(f"  other DVL/depth counters of the engine: {rest}")
    return lines


def run_auv_demo(out: Path, spec: DemoSpec, launch_file: Path = AUV_LAUNCH) -> None:
    """Everything `zennav demo --vehicle auv` does (see the module docstring); raises click.ClickException on
    failure."""
    from .datasets.registry import load_dataset
    from .learn.loop import InProcessLoop
    from .learn.settings import compensation_settings
    from .params import nav_config
    from .replay_cli import filter_settings

    wall0 = time.monotonic()
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    ds = load_dataset(spec.dataset, **spec.options)
    if ds.dvl is None:
        raise click.ClickException(f"{spec.dataset} has no DVL: the AUV demo needs a dataset with one (sim:auv)")
    ds.config = nav_config(ds.config, filter_settings(spec.dataset, None, PROFILE, None))  # the set's ins
    duration_s = (run_end_ns(ds) - int(ds.initial.t_ns)) / NS
    click.echo(f"zennav demo --vehicle auv: {ds.name} ({duration_s:.0f} s: GNSS at the surface only, DVL "
               f"{ds.config.dvl_mode}, depth {'on' if ds.config.depth and ds.depth is not None else 'off'}), "
               f"profile {PROFILE}\n")
    settings = compensation_settings(spec.compensation, spec.seed)
    in_process = _background(lambda: (run_replay(ds, compensator=InProcessLoop(TARGET, settings)), run_replay(ds)))
    recording, got = run_set(launch_file, out, spec, settings, limit_s=2.0 * duration_s + 300.0, prefixes=("",),
                             target=TARGET)
    recorded, n_recorded = recording_stats(recording)
    pipe = pipeline_result(got, "", recorded, label=PROFILE)
    start, st = got.start, pipe.status
    assert start is not None  # pipeline_result raised without one
    ref, plain = in_process()
    diff = compare(pipe.result, ref)
    records = aid_records(recording)
    n_got = {"imu": st["imu_count"], "gnss": st["gnss_count"], **(st.get("aid_counts") or {})}
    consumed = ", ".join(f"{n_got.get(a, 0)}/{n} {a}" for a, n in start["counts"].items())
    click.echo(f"ins consumed {consumed} samples over Zenoh in {pipe.result.wall_s:.1f} s: none lost or duplicated")
    click.echo(f"distributed vs in-process replay, {len(pipe.result.t_ns)} epochs: {_verdict(diff)}")
    rows = dives(ds, pipe.result)
    click.echo("\nunder water (over the bus, against the truth):")
    click.echo("\n".join(_dive_lines(rows)))
    click.echo("\nDVL and depth:")
    click.echo("\n".join(_counter_lines(st, records)))
    lo = learning_over_the_bus(recording, st)
    decisions = {k[len("dvl_learned_"):]: v for k, v in st["counters"].items() if k.startswith("dvl_learned_")}
    click.echo(f"\nlearned DVL beam errors over the bus ({spec.compensation}, seed {spec.seed}):")
    click.echo("\n".join(_learning_lines(lo)))
    click.echo(f"  ins's decisions per beam (anomaly discrimination): {decisions or 'none'}")
    plain_rows = dives(ds, plain)
    click.echo("without the learned compensation (in process, same data):")
    click.echo("\n".join(_dive_lines(plain_rows)))
    m = evaluate(ds, pipe.result)
    m["dives"] = rows
    m["dives_without_learning"] = plain_rows
    m["learning"] = {**lo, "decisions": decisions}
    m["pipeline"] = {"launch_file": str(launch_file), "recording": str(recording), "recorded_messages": n_recorded,
                     "ins_status": st, "vs_in_process": diff, "aid_records": records}
    write_outputs(out, ds, pipe.result, m)
    plots = write_plots(out, ds, {"learned compensation, over the bus": pipe.result,
                                  "without it, in process": plain},
                        windows=[(r["start_s"], r["end_s"]) for r in rows], window_name="dive")
    click.echo("\nAccuracy against the truth, over the bus:")
    click.echo(format_table(m))
    click.echo(f"\nrecording  {recording} ({n_recorded} messages on {len(recorded)} keys; opens in Foxglove)"
               f"\nsolution   {out / 'nav.txt'}, nav.csv, metrics.json"
               f"\nplots      {plots[0]}, {plots[1].name}"
               f"\nlog        {out / 'launch.log'}"
               f"\ndone in {time.monotonic() - wall0:.0f} s")
    if not diff["identical"]:
        raise click.ClickException("the distributed solution differs from the in-process replay")
