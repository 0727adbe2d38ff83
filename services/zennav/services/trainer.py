"""trainer service (issue 6, DESIGN.md sections 5 and 6): collects the ins's training samples per target variant,
learns the INS error and publishes versioned parameter sets. --model anfis (default): retrains ANFIS by the
hybrid learner (least squares for the consequents + Fletcher-Reeves CG for the premises,
zennav.learn.anfis_torch.fit_anfis_sigma) on the newest samples. --model elman (seed 002): an Elman network learns
online from every sample, in arrival order, on its sliding window (zennav.compensation.ElmanCompensator, the
same object the in-process replay uses); on the schedule below its weights and context are published, once its
training error is under its threshold (before that nothing is published, as the seed's network does not
predict). The only zennav process that imports torch; ANFIS trains on the GPU when torch sees one.

Wiring table
    subscribes <base>/learn/samples        learn_sample from the ins (variants outside --targets are counted, ignored)
    publishes  <base>/learn/model/<name>   model_params, the wire form of a zennav.learn.paramset set (name
                                           <prefix>-<target>, e.g. anfis-drift; the latest is served to late
                                           joiners by the publisher's queryable)
               <base>/svc/trainer/status   samples per target, trainings, versions, link losses, device

ANFIS rule count: --n-rules, reduced while samples are few (anfis_torch.fit_anfis_sigma).

Schedule: per target, the newest --window samples are kept; a training starts when at least --min-samples are
held and either --retrain-samples new ones arrived or --retrain-every seconds passed since the last training
with new samples. Training runs on its own thread, so samples keep arriving meanwhile. The set's metrics carry
the target, the sample count and time span, the device, epochs, wall time, the training RMSE per output and
sigma, the predictor's 1-sigma per output (zennav.compensation: out-of-sample residuals inflated for their
correlation; ANFIS on the newest quarter of the samples of a fit on the rest, Elman running free).

Versions: one integer per model name, +1 per training. At start the trainer asks for the latest set of each of
its names on the bus and continues above it (else from --first-version), so a restarted trainer's sets are
newer than those a predictor may still hold, as long as some process still serves them.

Remote deployment: run it as a zenoh client of the edge router (``--mode client --connect tcp/<edge>:7447``,
deploy/zenoh-client.json5: waits for the router, reconnects for ever). When the link drops the trainer keeps
running and keeps its samples (none arrive meanwhile); the edge keeps predicting with the last set. On
reconnection (seen as the router reappearing in the session's info) it re-publishes its latest set of each
model, so a set trained during the cut is not lost; the next training then follows the schedule.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import Counter, deque

import numpy as np

from zennav import messages as M
from zennav.compensation import ElmanCompensator
from zennav.learn import paramset
from zennav.nav.learning import ANSWER_PERIOD_S, FEATURES, OUTPUTS, TARGETS, LearnSample

MODELS = ("anfis", "elman")
from zennav.service import ServiceRunner, add_bus_args


class TrainerNode:
    """The transport-free part of the trainer: ``on_sample(msg)`` from the bus thread, ``train_due()`` /
    ``train(target)`` from the training thread; ``publish(name, msg)`` sends a model_params message."""

    def __init__(self, publish, log, targets=("body_velocity",), *, model: str = "anfis", prefix: str | None = None,
                 window: int = 5000, min_samples: int = 200, retrain_samples: int = 500,
                 retrain_every_s: float = 60.0, n_rules: int = 8, max_epochs: int = 30, seed: int = 0, device=None,
                 first_version: int = 1):
        if model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}")
        self.publish = publish
        self.log = log
        self.model = model
        self.targets = tuple(targets)
        prefix = prefix or model
        self.names = {t: M.check_chunk(f"{prefix}-{t}", "model name") for t in self.targets}
        self.window, self.min_samples = int(window), int(min_samples)
        self.retrain_samples, self.retrain_every_s = int(retrain_samples), float(retrain_every_s)
        self.n_rules, self.max_epochs, self.seed = int(n_rules), int(max_epochs), int(seed)
        self.device = device
        self.cv = threading.Condition()
        self.data = {t: deque(maxlen=self.window) for t in self.targets}  # (t_ns, features, value)
        self.unlearned = {t: [] for t in self.targets}  # elman: samples not yet learned, in arrival order
        self.elman = {t: ElmanCompensator(t, seed=seed) for t in self.targets} if model == "elman" else {}
        self.new = {t: 0 for t in self.targets}
        self.last_train = {t: time.monotonic() for t in self.targets}
        self.version = {t: int(first_version) - 1 for t in self.targets}
        self.counts: Counter[str] = Counter()
        self.last = {}  # target -> metrics of the last training
        self.busy = ""

    # ------------------------------------------------------------------ samples
    def on_sample(self, msg: dict) -> None:
        t = msg["variant"]
        if t not in self.data:
            self.counts["ignored_variant"] += 1
            return
        if len(msg["features"]) != len(FEATURES[t]) or len(msg["target"]) != len(OUTPUTS[t]):
            self.counts["ignored_shape"] += 1
            return
        with self.cv:
            self.data[t].append((msg["t_ns"], msg["features"], msg["target"]))
            if self.elman:
                self.unlearned[t].append(LearnSample(msg["t_ns"], t, np.asarray(msg["features"], dtype=float),
                                                     np.asarray(msg["target"], dtype=float)))
            self.new[t] += 1
            self.counts[f"samples_{t}"] += 1
            if self.new[t] >= self.retrain_samples:
                self.cv.notify()

    def seen_version(self, target: str, version: int) -> None:
        """A set of this model already exists on the bus with this version: continue above it."""
        with self.cv:
            self.version[target] = max(self.version[target], int(version))

    # ------------------------------------------------------------------ schedule
    def due(self, now: float | None = None) -> list[str]:
        now = time.monotonic() if now is None else now
        out = []
        for t in self.targets:
            n, held = self.new[t], len(self.data[t])
            if n > 0 and held >= self.min_samples and (
                    n >= self.retrain_samples or (self.retrain_every_s > 0 and now - self.last_train[t] >= self.retrain_every_s)):
                out.append(t)
        return out

    def wait_due(self, tick: float = 0.5) -> list[str]:
        """The targets due for training, after waiting up to tick seconds for one (the caller loops)."""
        with self.cv:
            due = self.due()
            if not due:
                self.cv.wait(tick)
                due = self.due()
        return due

    def train(self, target: str) -> dict | None:
        """Train the target's model on what arrived and publish its set; returns the published message (None
        when nothing was published)."""
        return self._learn_elman(target) if self.elman else self._fit_anfis(target)

    def _next_version(self, target: str) -> int:
        with self.cv:
            self.version[target] += 1
            return self.version[target]

    def _learn_elman(self, target: str) -> dict | None:
        """Online learning of the new samples, then the network's weights and context as a set when it is ready."""
        with self.cv:
            rows, self.unlearned[target] = self.unlearned[target], []
            self.new[target] = 0
            self.last_train[target] = time.monotonic()
        comp = self.elman[target]
        self.busy = f"learning {target} online from {len(rows)} samples"
        try:
            comp.add(rows)
        finally:
            self.busy = ""
        if not comp.ready:
            self.counts[f"not_ready_{target}"] += 1
            return None
        std = comp.std()
        version = self._next_version(target)
        net = comp.net
        metrics = {"target": target, "method": "elman_online", "sigma": std.tolist(), "samples": comp.learned,
                   "window": net.window, "n_hidden": net.n_hidden, "context_gain": float(net.context_gain),
                   "window_rmse_normalised": float(net.train_rmse), "t_last_ns": int(rows[-1].t_ns) if rows else 0}
        arrays = {k: v.copy() for k, v in net.arrays().items()}
        name = self.names[target]
        msg = M.model_params_msg(paramset.build(name, version, arrays, comp.norm(), metrics, kind="elman"))
        self.publish(name, msg)
        self.counts[f"trainings_{target}"] += 1
        self.last[target] = {"version": version, "samples": comp.learned, "sigma": [round(v, 4) for v in std]}
        self.log.info("published %s v%d: learned %d samples online, 1-sigma %s", name, version,
                      comp.learned, self.last[target]["sigma"])
        return msg

    def _fit_anfis(self, target: str) -> dict | None:
        """Fit ANFIS on a snapshot of the target's window and publish the set."""
        from zennav.learn.anfis_torch import TrainConfig, fit_anfis_sigma

        with self.cv:
            rows = list(self.data[target])
            self.new[target] = 0
            self.last_train[target] = time.monotonic()
        t_ns = np.array([r[0] for r in rows], dtype=np.int64)
        x = np.array([r[1] for r in rows], dtype=float)
        y = np.array([r[2] for r in rows], dtype=float)
        self.busy = f"training {target} on {len(rows)} samples"
        try:
            fit = fit_anfis_sigma(x, y, max_rules=self.n_rules, device=self.device, t_ns=t_ns,
                                  answer_period_s=ANSWER_PERIOD_S[target], config=TrainConfig(
                                      method="hybrid_cg", max_epochs=self.max_epochs, seed=self.seed))
        except Exception:
            self.counts["train_errors"] += 1
            self.log.exception("training %s on %d samples failed; the last set stays published", target, len(x))
            return None
        finally:
            self.busy = ""
        version = self._next_version(target)
        metrics = {**fit.metrics, "target": target, "samples": int(len(x)), "t_first_ns": int(t_ns.min()),
                   "t_last_ns": int(t_ns.max()), "device": str(self.device or "cpu"), "n_rules": int(len(fit.arrays["rules"]))}
        name = self.names[target]
        msg = M.model_params_msg(paramset.build(name, version, fit.arrays, fit.norm, metrics))
        self.publish(name, msg)
        self.counts[f"trainings_{target}"] += 1
        self.last[target] = {"version": version, "samples": len(x), "epochs": fit.metrics["epochs"],
                             "wall_s": round(fit.metrics["wall_s"], 3),
                             "sigma": [round(v, 4) for v in fit.metrics["sigma"]]}
        self.log.info("published %s v%d: %d samples, %d epochs (%s) in %.2f s on %s, 1-sigma %s", name, version,
                      len(x), fit.metrics["epochs"], fit.metrics["stop_reason"], fit.metrics["wall_s"],
                      self.device or "cpu", self.last[target]["sigma"])
        return msg

    # ------------------------------------------------------------------ status
    def counters(self) -> dict:
        with self.cv:
            c = dict(self.counts)
            c.update({f"held_{t}": len(d) for t, d in self.data.items()})
            c.update({f"version_{t}": v for t, v in self.version.items()})
        return c

    def detail(self) -> str:
        last = dict(self.last)
        s = "; ".join(f"{self.names[t]} v{m['version']} ({m['samples']} samples, 1-sigma {m['sigma']})"
                      for t, m in sorted(last.items())) or "no set published yet"
        return f"{s}; device {self.device or 'cpu'}" + (f"; {self.busy}" if self.busy else "")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-trainer", description="zennav trainer service: ANFIS (hybrid "
                                "LSE + Fletcher-Reeves CG) or online Elman on the ins's samples, versioned parameter sets")
    p.add_argument("--model", default="anfis", choices=MODELS, help="anfis: retrained on the newest samples; "
                   "elman: learns online from every sample (seed 002)")
    p.add_argument("--targets", default="body_velocity", help=f"comma-separated target variants to learn ({', '.join(TARGETS)})")
    p.add_argument("--prefix", default=None, help="model name prefix (default: --model): sets are published as "
                   "<prefix>-<target>")
    p.add_argument("--window", type=int, default=5000, help="newest samples kept per target")
    p.add_argument("--min-samples", type=int, default=200, help="no training below this many samples")
    p.add_argument("--retrain-samples", type=int, default=500, help="retrain after this many new samples")
    p.add_argument("--retrain-every", type=float, default=60.0,
                   help="... or after this many seconds if any new sample arrived (0: sample count only)")
    p.add_argument("--n-rules", type=int, default=8, help="ANFIS rules (k-means rule base)")
    p.add_argument("--max-epochs", type=int, default=30, help="hybrid epochs (LSE + FR-CG) per training")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None, help="torch device (default: cuda when torch sees one, else cpu)")
    p.add_argument("--torch-threads", type=int, default=0,
                   help="torch CPU threads (0: torch's default); 1 beside the real-time services on one host")
    p.add_argument("--first-version", type=int, default=1, help="version of the first set if none is found on the bus")
    p.add_argument("--link-poll", type=float, default=0.5, help="period [s] of the link (router/peer) check")
    p.add_argument("--close-timeout", type=float, default=3.0, help="longest wait [s] for the session to close")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    if not targets or not set(targets) <= set(TARGETS):
        raise SystemExit(f"--targets: choose from {TARGETS}")
    run = ServiceRunner("trainer", args, serial=False)
    from zennav.learn.anfis_torch import default_device  # torch: this process only

    if args.torch_threads > 0:
        import torch

        torch.set_num_threads(args.torch_threads)
    device = args.device or str(default_device())
    k = run.keys
    bus = run.bus
    pubs: dict[str, object] = {}
    pub_lock = threading.Lock()

    def publish(name: str, msg: dict) -> None:
        with pub_lock:
            p = pubs.get(name)
            if p is None:
                p = pubs[name] = bus.publisher(k.learn_model(name))
            p.put(msg)

    node = TrainerNode(publish, run.log, targets, model=args.model, prefix=args.prefix, window=args.window,
                       min_samples=args.min_samples, retrain_samples=args.retrain_samples,
                       retrain_every_s=args.retrain_every, n_rules=args.n_rules, max_epochs=args.max_epochs,
                       seed=args.seed, device=device, first_version=args.first_version)
    for t, name in node.names.items():  # continue the version numbering of a set already on the bus
        for _key, msg in bus.get_latest(k.learn_model(name), timeout=2.0):
            if msg["name"] == name:
                node.seen_version(t, msg["version"])
    link = {"up": True, "losses": 0, "republished": 0}
    run.counters = lambda: {**node.counters(), "link_losses": link["losses"], "republished": link["republished"]}
    bus.subscribe(k.learn_samples(), lambda key, msg, recv_ns: node.on_sample(msg), channel="fifo", capacity=8192,
                  name="samples")

    def connected() -> bool:
        return bool(bus.routers() or bus.peers())

    def watch_link() -> None:  # a client's session reconnects by itself; re-publish the latest sets when it does
        while not run.wait(args.link_poll):
            up = connected()
            if up == link["up"]:
                continue
            link["up"] = up
            if not up:
                link["losses"] += 1
                run.log.warning("link to the router lost; training goes on with the %s samples held",
                                sum(len(d) for d in node.data.values()))
                continue
            with pub_lock:
                for p in pubs.values():
                    if p.latest is not None:
                        p.put_raw(p.latest)
                        link["republished"] += 1
            run.log.info("link to the router restored; latest sets re-published (%s)", ", ".join(pubs) or "none yet")

    def train_loop() -> None:
        while not run.stopping:
            for t in node.wait_due():
                node.train(t)
                run.detail = node.detail()

    link["up"] = connected()
    threads = [threading.Thread(target=f, name=f"zennav-{f.__name__}", daemon=True) for f in (watch_link, train_loop)]
    for th in threads:
        th.start()
    run.ready("running", node.detail())
    try:
        run.wait()
    finally:
        run.stop()
        with node.cv:
            node.cv.notify_all()
        # a client whose router is unreachable can block in the zenoh session's close (it is reconnecting): bound it
        closer = threading.Thread(target=run.close, name="zennav-close", daemon=True)
        closer.start()
        closer.join(args.close_timeout)
        if closer.is_alive():
            run.log.warning("zenoh session close still blocked after %.0f s (link down?); exiting anyway",
                            args.close_timeout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
