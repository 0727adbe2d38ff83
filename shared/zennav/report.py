"""`zennav report RUN_DIR`: the plots a navigation engineer looks at first, and one self-contained HTML page.

RUN_DIR is a `zennav replay --out` folder (nav.csv, metrics.json; aid.csv and biases.csv) or a demo folder
(its demo.mcap gives the aid reports). A ``smoothed/`` subfolder (`zennav replay --smooth`: the same nav.csv
columns, and a "smoothed" entry in metrics.json) is drawn beside the forward solution. The truth comes from the
dataset named in metrics.json, loaded again; without it the error plots are left out and the page says so.

Writes into ``RUN_DIR/report`` (or --out): track.png (north/east, GNSS outages in red), errors.png (horizontal
and vertical error against time, outages shaded), test_ratios.png (each aid source's innovation test ratio, the
gate at 1), biases.png (estimated gyro and accelerometer biases with their 1-sigma band), learned.png (the learned
answers against the truth, body-velocity target), and index.html (every plot inlined, the accuracy table).
"""
from __future__ import annotations

import base64
import csv
import html
import json
import math
from pathlib import Path

import numpy as np

from .nav.types import NS

PLOTS = ("track", "errors", "test_ratios", "biases", "learned")


def load_nav_csv(path: Path) -> dict[str, np.ndarray]:
    """nav.csv (zennav.metrics.write_outputs) -> column name -> array."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {n: np.asarray(data[n], dtype=float) for n in data.dtype.names or ()}


def _aid_rows(run: Path, t0_ns: int) -> list[dict]:
    """The aid reports: aid.csv, else the nav/aid keys of an MCAP recording in the folder."""
    if (run / "aid.csv").exists():
        with open(run / "aid.csv") as f:
            return [{"t_s": float(r["t_s"]), "source": r["source"], "fused": r["fused"] == "1",
                     "test_ratio": float(r["test_ratio"]) if r["test_ratio"] else None,
                     "obs": [float(r[f"obs_{i}"]) for i in range(3) if r[f"obs_{i}"] != ""]}
                    for r in csv.DictReader(f)]
    rows = []
    from .recording import read_mcap

    for mc in sorted(run.glob("*.mcap")):
        for _key, msg, _p, _t in read_mcap(mc, [r"/nav/aid/[^/]+$"]):
            if msg is not None:
                rows.append({"t_s": (msg["t_ns"] - t0_ns) / NS, "source": msg["source"], "fused": msg["fused"],
                             "test_ratio": msg["test_ratio"], "obs": list(msg["observation"])})
    return rows


def _truth(run: Path, metrics: dict, spec: str | None, options: dict):
    """The run's dataset (spec with its loader options, else run.json's, else the name in metrics.json), or why
    there is no truth."""
    from .datasets.registry import load_dataset

    if spec is None and (run / "run.json").exists():
        recorded = json.loads((run / "run.json").read_text())
        spec, options = recorded.get("dataset_spec"), {**recorded.get("loader_options", {}), **options}
    spec = spec or metrics["dataset"]
    try:
        return load_dataset(spec, **options)
    except Exception as e:  # any loader error: the report goes on without truth
        return f"truth not available ({spec}: {e})"


def _solution_errors(ds, nav: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truth times [ns], horizontal error [m], vertical error [m]) of a nav.csv solution, as
    zennav.metrics.evaluate measures them (the same point as the truth)."""
    from .metrics import _interp, antenna_llh, ned_errors
    from .nav.rotation import euler_to_quat

    t_ns = np.round(nav["t_s"] * NS).astype(np.int64)
    llh = np.column_stack([np.radians(nav["lat_deg"]), np.radians(nav["lon_deg"]), nav["h_m"]])
    truth = ds.truth
    if truth.at_antenna:
        euler = np.radians(np.column_stack([nav["roll_deg"], nav["pitch_deg"], nav["yaw_deg"]]))
        llh = antenna_llh(llh, np.array([euler_to_quat(e) for e in euler]), ds.config.lever_arm_b)
    sel = (truth.t_ns >= t_ns[0]) & (truth.t_ns <= t_ns[-1])
    e = ned_errors(_interp(truth.t_ns[sel], t_ns, llh), truth.llh[sel])
    return truth.t_ns[sel], np.hypot(e[:, 0], e[:, 1]), e[:, 2]


def _shade(ax, windows) -> None:
    for i, (a, b) in enumerate(windows):
        ax.axvspan(a, b, color="tab:red", alpha=0.15, lw=0, label="GNSS outage" if i == 0 else None)


def write_report(run: Path, out: Path | None = None, spec: str | None = None, options: dict | None = None) -> Path:
    """Every plot that the folder's data allows and index.html; returns the page's path. spec, options: the run's
    dataset and its loader options (default: run.json's, else the name in metrics.json)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = Path(run)
    out = Path(out) if out is not None else run / "report"
    out.mkdir(parents=True, exist_ok=True)
    metrics = json.loads((run / "metrics.json").read_text())
    sols = {"forward": load_nav_csv(run / "nav.csv")}
    if (run / "smoothed" / "nav.csv").exists():
        sols["smoothed"] = load_nav_csv(run / "smoothed" / "nav.csv")
    ds = _truth(run, metrics, spec, options or {})
    notes = [ds] if isinstance(ds, str) else []
    ds = None if isinstance(ds, str) else ds
    fwd = sols["forward"]
    t0_ns = int(ds.initial.t_ns) if ds is not None else int(round(fwd["t_s"][0] * NS))
    windows = [(o["start_s"], o["start_s"] + o["duration_s"]) for o in metrics.get("outages", [])]
    made: dict[str, Path] = {}

    def save(fig, name: str) -> None:
        fig.tight_layout()
        made[name] = out / f"{name}.png"
        fig.savefig(made[name], dpi=100)
        plt.close(fig)

    # track
    lat0, lon0 = math.radians(fwd["lat_deg"][0]), math.radians(fwd["lon_deg"][0])
    r_e = 6378137.0

    def ne(lat_deg, lon_deg):
        return ((np.radians(lat_deg) - lat0) * r_e, (np.radians(lon_deg) - lon0) * r_e * math.cos(lat0))

    fig, ax = plt.subplots(figsize=(8, 7))
    if ds is not None and ds.truth is not None:
        n, e = ne(np.degrees(ds.truth.llh[:, 0]), np.degrees(ds.truth.llh[:, 1]))
        ax.plot(e, n, "k-", lw=2.5, alpha=0.3, label="truth")
    for label, s in sols.items():
        n, e = ne(s["lat_deg"], s["lon_deg"])
        ax.plot(e, n, lw=1, label=label)
        t_rel = s["t_s"] - t0_ns / NS
        for i, (a, b) in enumerate(windows):
            m = (t_rel >= a) & (t_rel < b)
            ax.plot(e[m], n[m], color="tab:red", lw=3, alpha=0.6,
                    label="in GNSS outage" if (i == 0 and label == "forward") else None)
    ax.set(xlabel="east [m]", ylabel="north [m]", title=f"{metrics['dataset']}: track")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend()
    save(fig, "track")

    # errors against time
    if ds is not None and ds.truth is not None:
        fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
        for label, s in sols.items():
            t_ref, h, v = _solution_errors(ds, s)
            x = (t_ref - t0_ns) / NS
            axes[0].plot(x, h, lw=1, label=label)
            axes[1].plot(x, v, lw=1, label=label)
        for ax, what in zip(axes, ("horizontal error [m]", "vertical error (down) [m]")):
            _shade(ax, windows)
            ax.set_ylabel(what)
            ax.grid(alpha=0.3)
        axes[0].legend()
        axes[1].set_xlabel("time from start [s]")
        axes[0].set_title(f"{metrics['dataset']}: position error against the truth")
        save(fig, "errors")
    else:
        notes.append("errors.png: no truth for this run")

    # per-source innovation test ratios
    aid = _aid_rows(run, t0_ns)
    sources = sorted({r["source"] for r in aid if r["test_ratio"] is not None})
    if sources:
        fig, axes = plt.subplots(len(sources), 1, figsize=(11, 2.3 * len(sources) + 0.6), sharex=True, squeeze=False)
        for ax, src in zip(axes[:, 0], sources):
            rows = [r for r in aid if r["source"] == src and r["test_ratio"] is not None]
            for fused, color, lab in ((True, "tab:blue", "fused"), (False, "tab:red", "rejected")):
                pts = [(r["t_s"], max(r["test_ratio"], 1e-4)) for r in rows if r["fused"] == fused]
                if pts:
                    ax.plot(*zip(*pts), ".", ms=2, color=color, label=lab)
            ax.axhline(1.0, color="k", lw=0.8, ls="--")
            _shade(ax, windows)
            ax.set_yscale("log")
            ax.set_ylabel(f"{src}\ntest ratio")
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("time from start [s]")
        axes[0, 0].set_title("innovation test ratio d^2 / gate (> 1 fails the gate)")
        save(fig, "test_ratios")
    else:
        notes.append("test_ratios.png: no aid reports in this folder (aid.csv or an MCAP recording)")

    # biases with 1-sigma
    if (run / "biases.csv").exists():
        b = np.atleast_2d(np.genfromtxt(run / "biases.csv", delimiter=",", skip_header=1))
        fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
        for ax, col, unit, what in ((axes[0], 1, "deg/h", "gyro bias"), (axes[1], 7, "mg", "accelerometer bias")):
            for i, axis in enumerate("xyz"):
                line, = ax.plot(b[:, 0], b[:, col + i], lw=1, label=f"{axis} (FRD)")
                ax.fill_between(b[:, 0], b[:, col + i] - b[:, col + 3 + i], b[:, col + i] + b[:, col + 3 + i],
                                color=line.get_color(), alpha=0.15, lw=0)
            _shade(ax, windows)
            ax.set_ylabel(f"{what} [{unit}]")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        axes[0].set_title("estimated sensor biases with their 1-sigma band")
        axes[1].set_xlabel("time from start [s]")
        save(fig, "biases")
    else:
        notes.append("biases.png: no biases.csv in this folder (written by zennav replay --out)")

    # learned answers against the truth
    learned = [r for r in aid if r["source"].startswith("learned") and len(r["obs"]) == 3]
    target = (metrics.get("compensation") or {}).get("target")
    if learned and target == "body_velocity" and ds is not None and ds.truth is not None \
            and ds.truth.v_n is not None:
        from .nav.rotation import euler_to_dcm

        t_l = np.array([r["t_s"] for r in learned])
        t_sol = fwd["t_s"] - t0_ns / NS
        k = np.clip(np.searchsorted(t_sol, t_l), 0, len(t_sol) - 1)
        euler = np.radians(np.column_stack([fwd["roll_deg"], fwd["pitch_deg"], fwd["yaw_deg"]]))[k]
        t_tr = (ds.truth.t_ns - t0_ns) / NS
        v_n = np.column_stack([np.interp(t_l, t_tr, ds.truth.v_n[:, i]) for i in range(3)])
        v_b = np.array([euler_to_dcm(e).T @ v for e, v in zip(euler, v_n)])
        obs = np.array([r["obs"] for r in learned])
        fig, axes = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
        for i, ax in enumerate(axes):
            ax.plot(t_l, v_b[:, i], "k.", ms=2, label="truth")
            ax.plot(t_l, obs[:, i], ".", ms=2, color="tab:green", label="learned answer")
            _shade(ax, windows)
            ax.set_ylabel(f"v_b {'xyz'[i]} (FRD) [m/s]")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        axes[0].set_title("learned body velocity against the truth")
        axes[-1].set_xlabel("time from start [s]")
        save(fig, "learned")
    else:
        notes.append("learned.png: no learned answers with a body-velocity target and truth in this run")

    page = out / "index.html"
    page.write_text(_html(metrics, made, notes))
    return page


def accuracy_rows(metrics: dict) -> list[tuple[str, list[str]]]:
    """The accuracy table: (row name, [forward, smoothed when present])."""
    from .metrics import dive_text

    runs = [metrics] + ([metrics["smoothed"]] if isinstance(metrics.get("smoothed"), dict) else [])

    def f(x, unit):
        return "n/a" if x is None else f"{x:.3f} {unit}"

    rows = [("horizontal RMS", [f(m.get("horizontal_rms_m"), "m") for m in runs]),
            ("vertical RMS", [f(m.get("vertical_rms_m"), "m") for m in runs]),
            ("velocity RMS", [f(m.get("velocity_rms_mps"), "m/s") for m in runs])]
    att = [m.get("attitude_rms_deg") for m in runs]
    rows.append(("attitude RMS roll/pitch/yaw", ["n/a" if a is None else " / ".join(
        "n/a" if a[k] is None else f"{a[k]:.3f}" for k in ("roll", "pitch", "yaw")) + " deg" for a in att]))
    for i, o in enumerate(metrics.get("outages", [])):
        vals = []
        for m in runs:
            oo = m.get("outages", [])
            vals.append(f"max {oo[i]['max_horizontal_m']:.2f} m, final {oo[i]['final_horizontal_m']:.2f} m"
                        if i < len(oo) else "n/a")
        rows.append((f"outage {o['start_s']:.0f} s + {o['duration_s']:.0f} s", vals))
    if metrics.get("outages"):
        rows.append(("outage max drift RMS", [f(m.get("outage_max_horizontal_rms_m"), "m") for m in runs]))
        rows.append(("outage max drift max", [f(m.get("outage_max_horizontal_max_m"), "m") for m in runs]))
    for i, d in enumerate(metrics.get("dives", [])):
        vals = [dive_text(m["dives"][i]) if i < len(m.get("dives", [])) else "n/a" for m in runs]
        rows.append((f"under water {d['start_s']:.0f} s .. {d['end_s']:.0f} s, {d['distance_m']:.0f} m", vals))
    return rows


def _html(metrics: dict, made: dict[str, Path], notes: list[str]) -> str:
    cols = ["forward"] + (["smoothed"] if isinstance(metrics.get("smoothed"), dict) else [])
    head = "".join(f"<th>{c}</th>" for c in cols)
    body = "".join(f"<tr><td>{html.escape(name)}</td>" + "".join(f"<td>{html.escape(v)}</td>" for v in vals)
                   + "</tr>" for name, vals in accuracy_rows(metrics))
    imgs = "".join(f'<h2>{name.replace("_", " ")}</h2><img alt="{name}" src="data:image/png;base64,'
                   f'{base64.b64encode(made[name].read_bytes()).decode()}">' for name in PLOTS if name in made)
    comp = metrics.get("compensation") or {}
    info = (f"dataset {html.escape(str(metrics['dataset']))}, {metrics.get('duration_s', 0):.0f} s, truth: "
            f"{html.escape(str(metrics.get('truth_source') or 'none'))}, learned compensation: "
            f"{html.escape(str(comp.get('model', 'none')))}")
    note = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>zennav report: "
            f"{html.escape(str(metrics['dataset']))}</title><style>body{{font-family:sans-serif;margin:2em;"
            "max-width:1200px}table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:4px 10px;"
            "text-align:right}td:first-child{text-align:left}img{max-width:100%}</style></head><body>"
            f"<h1>zennav report</h1><p>{info}</p><h2>accuracy</h2><table id='accuracy'><tr><th></th>{head}</tr>"
            f"{body}</table>{imgs}" + (f"<h2>not shown</h2><ul>{note}</ul>" if note else "") + "</body></html>\n")
