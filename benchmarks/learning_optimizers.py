"""Learning benchmark: ANFIS trainers side by side on the rtklibexplorer drive's training set (issue 6).

Prints one table: the same training set fitted, in one run, by
  hybrid_cg   zennav: consequents by least squares (LSE), premises by Fletcher-Reeves CG (strong Wolfe);
              by default the LSE is re-solved at every CG evaluation (variable projection, cg_projected)
  hybrid_gd   zennav: LSE + plain gradient descent on the premises (Jang's normalised step)
  adam        zennav: Adam on all parameters (premises and consequents), mini-batches of 256
  pso         zennav: particle swarm on the premises, LSE consequents for every particle
  toolbox     the HybridTrainer of the anfis-toolbox package (PyPI `anfis-toolbox`, LSE + gradient descent)
with, for each, the wall time and epochs to reach the target training RMSE, whether it reached it, and the
final training and validation RMSE (normalised, and per output in physical units). Medians over --seeds seeds.

Data. `zennav.learn.loop.training_set(load_dataset("rtklibexplorer"), --target)`: the learning samples the
navigation engine emits over the whole drive with full GNSS (the target variant's features and outputs: N and
E, or x, y, z for body_velocity; any variant in zennav.nav.learning.TARGETS). Split in time
order: the first 70 % of the samples train, the last 30 % validate (no shuffling: validation is the future
part of the drive, as in an outage). Inputs and targets are normalised with the training part's mean and
standard deviation only; all methods see the same normalised arrays.

Model. First-order Takagi-Sugeno ANFIS with generalised bell MFs; rule base by k-means on the normalised
training inputs (`cluster_rulebase`, --rules rules, one bell per rule on every input, seeded with the run's
seed). Every method, the toolbox included, starts from that same rule base (same a, b, c) and from zero
consequents.

Fairness. torch.set_num_threads(1) and single-threaded BLAS (OMP/OPENBLAS/MKL_NUM_THREADS=1 set before numpy
loads); all fits run one after another in this process. The clock counts only the training work (including
set-up such as PSO's initial swarm evaluation), not the per-epoch RMSE evaluation made for the table. Each
fit stops after --max-epochs epochs or once its clock passes --budget-s seconds, whichever comes first (the
default cap is high enough that the budget binds for every method): an "epoch" costs very different amounts
of time per method (20 CG iterations, each evaluation with its own LSE; one LSE + one gradient step; one pass
of mini-batches; one swarm iteration of 20 LSE solves), so a common time budget, not a common epoch count, is
what makes the final RMSEs comparable. No early stopping on tolerance. The zennav trainers
run with TrainConfig's defaults (--train-option overrides a field, e.g. cg_projected=false for Jang's
alternation), stepped through anfis_torch.epoch_stepper, the per-epoch function that train() runs.

Target. Per seed, target RMSE = --target-factor (1.02) x the lowest final training RMSE reached by any
method with that seed (normalised units, mean over both outputs). It belongs to no single method: it is
"within 2 % of the best fit anyone reached in the same budget", so the method with the lowest final RMSE
always reaches it and the question is who gets there first and how fast. It is set per seed because the
seed changes the rule base and with it the attainable minimum. --target-rmse fixes it instead (normalised).
"Time / epochs to target" = the first epoch whose training RMSE is <= the target; medians are over seeds,
with "not reached" counted as infinite (so the median is "-" when most seeds miss).

anfis-toolbox (0.2.2) differences, configured as closely as it allows: the same bell MFs (a, b, c), the same
rule list (rule r uses MF r of every input) and the same normalised data; its HybridTrainer is single-output,
so each of the two outputs gets its own model (own premises), and one toolbox epoch = one hybrid step of
each (times added). Its premise step is raw gradient descent with a fixed learning rate (--toolbox-lr, its
default 0.01), not a normalised step; its LSE ridge is 1e-6 absolute (zennav: 1e-8 per sample); its rule
firing is a linear-domain product normalised with sum + 1e-8 (zennav: log domain); pure numpy, full batch.

    .venv/bin/python benchmarks/learning_optimizers.py [--target position] [--rules 8] [--seeds 3]
        [--max-epochs 1500] [--budget-s 8] [--clock wall|cpu] [--per-seed] [--train-option cg_iters=20]

About 3 minutes on an idle 2-core machine with the defaults (15 fits of <= 8 s, plus the replay that builds
the training set). On a loaded machine wall times inflate and fits get fewer epochs: --clock cpu measures
this process's CPU time instead (the same thing on an idle machine, as everything is single-threaded).
"""
from __future__ import annotations

# ruff: noqa: E402  (the thread variables below must be set before numpy and torch load their BLAS)
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import math
import statistics
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from zennav.datasets.registry import load_dataset
from zennav.learn import anfis_numpy, anfis_torch
from zennav.learn.anfis_torch import TorchAnfis, TrainConfig
from zennav.learn.loop import training_set
from zennav.nav.learning import OUTPUTS, TARGETS

ZENNAV_METHODS = ("hybrid_cg", "hybrid_gd", "adam", "pso")
ALL_METHODS = ZENNAV_METHODS + ("toolbox",)
LABELS = {
    "hybrid_cg": "LSE + FR-CG (zennav)",
    "hybrid_gd": "LSE + plain GD (zennav)",
    "adam": "Adam, all params (zennav)",
    "pso": "PSO premises + LSE (zennav)",
    "toolbox": "anfis-toolbox hybrid",
}
UNITS = {"position": "m/s", "velocity": "m/s^2", "drift": "m", "body_velocity": "m/s"}  # nav/learning.py
TRAIN_FRACTION = 0.7


@dataclass
class Run:
    """One fit: per-epoch training clock and RMSEs (epoch 0 = the initial model)."""

    method: str
    seed: int
    epochs: list[int] = field(default_factory=list)
    clock_s: list[float] = field(default_factory=list)
    rmse: list[float] = field(default_factory=list)  # training, normalised
    val_rmse: list[float] = field(default_factory=list)  # validation, normalised
    val_rmse_out: list[np.ndarray] = field(default_factory=list)  # validation per output, normalised
    error: str | None = None

    def record(self, epoch, clock, pred_tr, y_tr, pred_va, y_va):
        per_out = np.sqrt(np.mean((pred_va - y_va) ** 2, axis=0))
        self.epochs.append(epoch)
        self.clock_s.append(clock)
        self.rmse.append(float(np.sqrt(np.mean((pred_tr - y_tr) ** 2))))
        self.val_rmse.append(float(np.sqrt(np.mean((pred_va - y_va) ** 2))))
        self.val_rmse_out.append(per_out)

    def first_reaching(self, target: float) -> tuple[float, float]:
        """(clock, epoch) of the first epoch with training RMSE <= target; (inf, inf) if none."""
        for e, c, r in zip(self.epochs, self.clock_s, self.rmse):
            if r <= target:
                return c, e
        return math.inf, math.inf


def _finite(v) -> bool:
    return bool(np.all(np.isfinite(v)))


CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
_clock = time.perf_counter


def run_zennav(method, rb, x_tr, y_tr, x_va, y_va, seed, max_epochs, budget_s, options=None) -> Run:
    """anfis_torch.epoch_stepper (the epoch train() runs), stepped here so the budget can stop it."""
    run = Run(method, seed)
    model = TorchAnfis(rb, n_out=y_tr.shape[1], device="cpu")
    x, y, xv = model.tensor(x_tr), model.tensor(y_tr), model.tensor(x_va)
    cfg = TrainConfig(method=method, max_epochs=max_epochs, seed=seed, **(options or {}))

    def evaluate(epoch, clock):
        with torch.no_grad():
            pt, pv = model.forward(x).numpy(), model.forward(xv).numpy()
        run.record(epoch, clock, pt, y_tr, pv, y_va)
        return _finite(pt)

    evaluate(0, 0.0)
    t0 = _clock()
    step = anfis_torch.epoch_stepper(model, x, y, cfg)  # PSO evaluates its initial swarm here
    clock = _clock() - t0
    for epoch in range(1, max_epochs + 1):
        t0 = _clock()
        step()
        clock += _clock() - t0
        if not evaluate(epoch, clock):
            run.error = "non-finite output"
            break
        if clock >= budget_s:
            break
    return run


def run_toolbox(rb, x_tr, y_tr, x_va, y_va, seed, max_epochs, budget_s, lr) -> Run:
    """anfis-toolbox HybridTrainer, one single-output TSKANFIS per output, from the same rule base."""
    from anfis_toolbox.membership import BellMF, MembershipFunction
    from anfis_toolbox.model import TSKANFIS
    from anfis_toolbox.optim import HybridTrainer

    run = Run("toolbox", seed)
    n_in, n_mf = rb["a"].shape
    rules = [tuple(int(i) for i in r) for r in rb["rules"]]
    models = []
    for _ in range(y_tr.shape[1]):
        mfs: dict[str, list[MembershipFunction]] = {
            f"x{j}": [BellMF(rb["a"][j, m], rb["b"][j, m], rb["c"][j, m]) for m in range(n_mf)] for j in range(n_in)}
        m = TSKANFIS(mfs, rules=rules)
        m.consequent_layer.parameters = np.zeros_like(m.consequent_layer.parameters)  # it starts random
        models.append(m)
    trainer = HybridTrainer(learning_rate=lr, epochs=1)

    def evaluate(epoch, clock):
        with np.errstate(all="ignore"):
            pt = np.hstack([m.predict(x_tr) for m in models])
            pv = np.hstack([m.predict(x_va) for m in models])
        run.record(epoch, clock, pt, y_tr, pv, y_va)
        return _finite(pt)

    evaluate(0, 0.0)
    clock = 0.0
    for epoch in range(1, max_epochs + 1):
        t0 = _clock()
        try:
            with np.errstate(all="ignore"):
                for o, m in enumerate(models):
                    trainer.train_step(m, x_tr, y_tr[:, o:o + 1], None)
        except (ValueError, np.linalg.LinAlgError) as e:  # e.g. a bell width driven to <= 0
            run.error = f"{type(e).__name__}: {e}"
            break
        clock += _clock() - t0
        if not evaluate(epoch, clock):
            run.error = "non-finite output"
            break
        if clock >= budget_s:
            break
    return run


def _med(values) -> float:
    return statistics.median(values) if values else math.nan


def _fmt(v: float, spec: str) -> str:
    return "-" if not math.isfinite(v) else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", default=TARGETS[0], choices=TARGETS, help="learning target variant")
    ap.add_argument("--rules", type=int, default=8, help="rule count (k-means clusters)")
    ap.add_argument("--seeds", type=int, default=3, help="number of seeds (0, 1, ...)")
    ap.add_argument("--max-epochs", type=int, default=1500,
                    help="epoch cap per fit (set so that the time budget binds first)")
    ap.add_argument("--budget-s", type=float, default=8.0, help="training-time budget per fit [s]")
    ap.add_argument("--target-factor", type=float, default=1.02,
                    help="target = factor x best final training RMSE of the seed")
    ap.add_argument("--target-rmse", type=float, default=None, help="fixed target (normalised) instead")
    ap.add_argument("--toolbox-lr", type=float, default=0.01, help="anfis-toolbox premise learning rate")
    ap.add_argument("--train-option", action="append", default=[], metavar="KEY=VALUE",
                    help="override a zennav TrainConfig field for all zennav methods, e.g. cg_iters=20 "
                         "(repeatable; each method reads only its own fields); default: TrainConfig's defaults")
    ap.add_argument("--clock", choices=tuple(CLOCKS), default="wall",
                    help="wall: elapsed time; cpu: this process's CPU time (robust on a loaded machine)")
    ap.add_argument("--per-seed", action="store_true", help="also print every seed's result")
    ap.add_argument("--methods", default=",".join(ALL_METHODS), help=f"subset of {','.join(ALL_METHODS)}")
    args = ap.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    unknown = set(methods) - set(ALL_METHODS)
    if unknown:
        ap.error(f"unknown methods {sorted(unknown)}")
    if "toolbox" in methods:
        try:
            import anfis_toolbox  # noqa: F401
        except ImportError:
            print("anfis-toolbox is not installed (pip install -e '.[bench]'); skipping it", file=sys.stderr)
            methods.remove("toolbox")
    options: dict[str, Any] = {}  # TrainConfig fields of several types
    for kv in args.train_option:
        key, _, value = kv.partition("=")
        if key not in TrainConfig.__dataclass_fields__ or key in ("method", "max_epochs", "seed", "pso"):
            ap.error(f"--train-option: {key!r} is not a settable TrainConfig field")
        default = getattr(TrainConfig(), key)
        try:
            if value == "None":
                options[key] = None
            elif isinstance(default, bool):
                options[key] = {"true": True, "false": False}[value.lower()]
            elif isinstance(default, tuple):
                options[key] = tuple(float(v) for v in value.split(","))
            else:
                options[key] = type(default)(value) if default is not None else int(value)
        except (ValueError, KeyError):
            ap.error(f"--train-option {kv}: cannot convert {value!r} to {type(default).__name__}")
    global _clock
    _clock = CLOCKS[args.clock]
    torch.set_num_threads(1)
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()

    x, y, t_ns = training_set(load_dataset("rtklibexplorer"), args.target)
    order = np.argsort(t_ns, kind="stable")
    x, y, t_ns = x[order], y[order], t_ns[order]
    n_tr = round(TRAIN_FRACTION * len(x))
    norm = anfis_numpy.fit_normalization(x[:n_tr], y[:n_tr])
    xn = (x - norm["x_mean"]) / norm["x_std"]
    yn = (y - norm["y_mean"]) / norm["y_std"]
    x_tr, y_tr, x_va, y_va = xn[:n_tr], yn[:n_tr], xn[n_tr:], yn[n_tr:]
    unit = UNITS[args.target]
    names = "/".join(OUTPUTS[args.target]).upper()
    w = 11 * len(OUTPUTS[args.target])  # width of the per-output column

    def per_output(v) -> str:
        return " / ".join(f"{a:.4g}" for a in v)
    y_std = norm["y_std"]
    span = (t_ns[-1] - t_ns[0]) / 1e9
    t_split = (t_ns[n_tr] - t_ns[0]) / 1e9

    runs: dict[str, list[Run]] = {m: [] for m in methods}
    for seed in range(args.seeds):
        rb = anfis_numpy.cluster_rulebase(x_tr, args.rules, seed=seed)
        for m in methods:
            if m == "toolbox":
                r = run_toolbox(rb, x_tr, y_tr, x_va, y_va, seed, args.max_epochs, args.budget_s, args.toolbox_lr)
            else:
                r = run_zennav(m, rb, x_tr, y_tr, x_va, y_va, seed, args.max_epochs, args.budget_s, options)
            runs[m].append(r)

    targets = {}
    for seed in range(args.seeds):
        if args.target_rmse is not None:
            targets[seed] = args.target_rmse
        else:
            best = min(runs[m][seed].rmse[-1] for m in methods if math.isfinite(runs[m][seed].rmse[-1]))
            targets[seed] = args.target_factor * best

    # --- report ---
    print(f"ANFIS trainers on the rtklibexplorer drive, target '{args.target}' ({names} in {unit}); "
          f"{len(x)} samples over {span:.0f} s")
    print(f"split in time order: first {TRAIN_FRACTION:.0%} train ({n_tr} samples, 0-{t_split:.0f} s), "
          f"last {1 - TRAIN_FRACTION:.0%} validation ({len(x) - n_tr} samples); normalised with the training "
          f"mean/std (y std {names} = {per_output(y_std)} {unit})")
    print(f"{args.rules} rules (k-means, bell MFs) x {x.shape[1]} inputs; seeds {list(range(args.seeds))}; "
          f"per fit: <= {args.max_epochs} epochs and <= {args.budget_s:g} s ({args.clock} clock) of training; "
          f"1 thread; anfis-toolbox lr {args.toolbox_lr:g}; zennav TrainConfig "
          + (", ".join(f"{k}={v}" for k, v in options.items()) or "defaults"))
    if args.target_rmse is not None:
        print(f"target training RMSE (normalised): fixed {args.target_rmse:.4f}")
    else:
        print(f"target training RMSE (normalised) = {args.target_factor:g} x best final training RMSE of the "
              f"seed over all methods: " + ", ".join(f"seed {s}: {v:.4f}" for s, v in targets.items()))
    print("medians over seeds; RMSE normalised (1.0 = the target's training std) unless a unit is given\n")

    hdr = (f"{'method':<28}{'reached':>8}{'time to':>9}{'epochs to':>10}{'epochs':>8}{'train':>8}"
           f"{'final':>8}{'final':>8}{'final val RMSE':>{w}}")
    hdr2 = (f"{'':<28}{'target':>8}{'target s':>9}{'target':>10}{'run':>8}{'time s':>8}"
            f"{'train':>8}{'val':>8}{names + ' ' + unit:>{w}}")
    print(hdr)
    print(hdr2)
    print("-" * len(hdr))
    ranking = []
    for m in methods:
        rs = runs[m]
        hits = [r.first_reaching(targets[r.seed]) for r in rs]
        n_hit = sum(math.isfinite(c) for c, _ in hits)
        t_med = _med([c for c, _ in hits])
        e_med = _med([e for _, e in hits])
        phys = np.median(np.array([r.val_rmse_out[-1] * y_std for r in rs]), axis=0)
        print(f"{LABELS[m]:<28}{f'{n_hit}/{len(rs)}':>8}{_fmt(t_med, '.2f'):>9}{_fmt(e_med, '.0f'):>10}"
              f"{_med([r.epochs[-1] for r in rs]):>8.0f}{_med([r.clock_s[-1] for r in rs]):>8.2f}"
              f"{_med([r.rmse[-1] for r in rs]):>8.4f}{_med([r.val_rmse[-1] for r in rs]):>8.3f}"
              f"{per_output(phys):>{w}}")
        ranking.append((t_med, m))
        for r, (c, e) in zip(rs, hits):
            if args.per_seed:
                print(f"{'  seed ' + str(r.seed):<28}{'yes' if math.isfinite(c) else 'no':>8}{_fmt(c, '.2f'):>9}"
                      f"{_fmt(e, '.0f'):>10}{r.epochs[-1]:>8}{r.clock_s[-1]:>8.2f}{r.rmse[-1]:>8.4f}"
                      f"{r.val_rmse[-1]:>8.3f}{per_output(r.val_rmse_out[-1] * y_std):>{w}}")
            if r.error:
                print(f"{'':<4}seed {r.seed}: stopped at epoch {r.epochs[-1]}: {r.error}")
    # reference: the training mean as the prediction (zero in normalised units)
    base_out = np.sqrt(np.mean(y_va**2, axis=0))
    print(f"{'(predict the training mean)':<28}{'':>8}{'':>9}{'':>10}{'':>8}{'':>8}"
          f"{float(np.sqrt(np.mean(y_tr**2))):>8.4f}{float(np.sqrt(np.mean(y_va**2))):>8.3f}"
          f"{per_output(base_out * y_std):>{w}}")

    ranking.sort()
    reached = [(t, m) for t, m in ranking if math.isfinite(t)]
    if reached:
        order_txt = " < ".join(f"{LABELS[m]} ({t:.2f} s)" for t, m in reached)
        print(f"\nfirst to the target (median time): {order_txt}")
        missed = [LABELS[m] for t, m in ranking if not math.isfinite(t)]
        if missed:
            print("not reached (median over seeds): " + ", ".join(missed))
    ncpu = os.cpu_count() or 1
    load1 = os.getloadavg()[0]
    print(f"total run time {time.perf_counter() - t_start:.0f} s; 1-min load average {load0:.1f} at the start, "
          f"{load1:.1f} at the end, on {ncpu} CPUs"
          + ("  (loaded machine: wall times are inflated and noisy; --clock cpu is steadier)"
             if max(load0, load1) > ncpu and args.clock == "wall" else ""))


if __name__ == "__main__":
    main()
