"""The trainer service's core: one zennav.learn.learner.Learner per target variant fed with the ins's
learn_sample messages and the sample counts of its learn_query messages (TrainerNode, transport-free); the fits
run on the training thread (``train_loop``) and each set goes to ``publish(name, model_params message)``, the
bus's model publishers (ModelPublishers, which also re-publish the latest sets when a lost link to the router
comes back); see zennav.services.trainer for the wiring, ARCHITECTURE.md section 3 for the loop.

Versions survive a restart: with a state directory, the last version of each model name is written there (atomically,
before the set is published) and a restarted trainer continues above it; the trainer also continues above a set it
finds on the bus (zennav.services.trainer). The held samples are not persisted: a restarted trainer learns again
from the samples that arrive (its first set after min_samples of them).

Samples sent twice: an ins resumed from its checkpoint publishes again the samples it had published since (same
stream, same times, same indices). Per variant and stream, a sample that is not after the last one accepted (an
earlier time, or the same time and an index not above its index) is dropped and counted (duplicate_samples): the
learner holds each sample once, as in a run without the crash."""
from __future__ import annotations

import json
import os
import threading
from collections import Counter
from pathlib import Path

from .. import messages as M
from ..learn.learner import Learner
from ..learn.settings import LearnSettings
from ..learn.signing import Signer
from ..nav.learning import FEATURES, OUTPUTS

DEFAULTS = LearnSettings()


class VersionFile:
    """The last published version per model name, in <state dir>/versions.json (written atomically)."""

    def __init__(self, directory) -> None:
        self.path = Path(directory) / "versions.json"
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.versions: dict[str, int] = {}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
                self.versions = {str(k): int(v) for k, v in data.items()}
            except (ValueError, TypeError, AttributeError) as e:
                raise ValueError(f"{self.path}: not a version map ({e})") from None

    def save(self, name: str, version: int) -> None:
        self.versions[name] = int(version)
        tmp = self.path.with_suffix(".tmp")
        with open(tmp, "w") as f:
            json.dump(self.versions, f, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)


class TrainerNode:
    """The transport-free part of the trainer: ``on_sample(msg)`` and ``on_query(msg)`` from the bus threads,
    ``wait_due()`` / ``train(target)`` from the training thread; ``publish(name, msg)`` sends a model_params
    message."""

    def __init__(self, publish, log, targets=("body_velocity",), settings: LearnSettings = DEFAULTS, *,
                 prefix: str | None = None, device=None, first_version: int = 1, signer: Signer | None = None,
                 versions: VersionFile | None = None, fitter=None):
        self.publish = publish
        self.log = log
        self.settings = settings
        self.targets = tuple(targets)
        prefix = prefix or settings.model
        self.learners = {t: Learner(t, settings, name=M.check_chunk(f"{prefix}-{t}", "model name"), device=device,
                                    fitter=fitter) for t in self.targets}
        self.names = {t: lr.name for t, lr in self.learners.items()}
        self.device = device
        self.cv = threading.Condition()
        self.signer, self.versions = signer, versions
        kept = versions.versions if versions else {}
        self.version = {t: max(int(first_version) - 1, kept.get(self.names[t], 0)) for t in self.targets}
        self.counts: Counter[str] = Counter()
        self.busy = ""
        self._last: dict[tuple, tuple] = {}  # (variant, stream) -> (t_ns, index) of the last sample accepted

    # ------------------------------------------------------------------ input
    def on_sample(self, msg: dict) -> None:
        t = msg["variant"]
        if t not in self.learners:
            self.counts["ignored_variant"] += 1
            return
        if len(msg["features"]) != len(FEATURES[t]) or len(msg["target"]) != len(OUTPUTS[t]):
            self.counts["ignored_shape"] += 1
            return
        if self._sent_again(t, msg):
            self.counts["duplicate_samples"] += 1
            n = self.counts["duplicate_samples"]
            if n <= 3 or n % 1000 == 0:
                self.log.warning("%s sample at t=%d ns from %s sent again: dropped (#%d duplicate_samples)", t,
                                 msg["t_ns"], msg.get("src"), n)
            return
        self.learners[t].add(msg["t_ns"], msg["features"], msg["target"])
        with self.cv:
            self.cv.notify()

    def _sent_again(self, target: str, msg: dict) -> bool:
        """Whether msg repeats a sample of target already accepted (module docstring); else it is the last."""
        key, this = (target, msg.get("stream")), (msg["t_ns"], msg.get("index"))
        last = self._last.get(key)
        if last is not None and (this[0] < last[0] or (this[0] == last[0] and this[1] is not None
                                                       and last[1] is not None and this[1] <= last[1])):
            return True
        self._last[key] = this
        return False

    def on_query(self, msg: dict) -> None:
        """A learn_query: its n_samples asks for a set through exactly that many samples of its variant."""
        t, n = msg["target"], msg.get("n_samples")
        if t not in self.learners:
            return
        if n is None:
            self.counts["queries_without_count"] += 1
            return
        self.learners[t].request(int(n))
        with self.cv:
            self.cv.notify()

    def seen_version(self, target: str, version: int) -> None:
        """A set of this model already exists on the bus with this version: continue above it."""
        with self.cv:
            self.version[target] = max(self.version[target], int(version))

    # ------------------------------------------------------------------ schedule
    def due(self) -> list[str]:
        return [t for t, lr in self.learners.items() if lr.due() is not None]

    def wait_due(self, tick: float = 0.5) -> list[str]:
        """The targets with a fit due, after waiting up to tick seconds for one (the caller loops)."""
        with self.cv:
            due = self.due()
            if not due:
                self.cv.wait(tick)
                due = self.due()
        return due

    def train(self, target: str) -> dict | None:
        """Fit the target's next due point and publish its set; returns the model_params message published
        (None: nothing due, or no set at that point, counted by the learner)."""
        lr = self.learners[target]
        n = lr.due()
        if n is None:
            return None
        with self.cv:
            version = self.version[target] + 1
        self.busy = f"fitting {target} through {n} samples"
        try:
            ps = lr.fit(n, version)
        finally:
            self.busy = ""
        if ps is None:
            self.log.warning("no %s set through %d samples (%s)", lr.name, n, lr.last_error or "model not ready")
            return None
        with self.cv:
            self.version[target] = max(self.version[target], version)
        if self.versions is not None:  # before it is published: a restart never reuses a version
            self.versions.save(lr.name, version)
        msg = M.model_params_msg(ps, None if self.signer is None else self.signer.sign(ps["checksum"]))
        self.publish(lr.name, msg)
        m = ps["metrics"]
        self.log.info("published %s v%d through %d samples (%d used, %s), 1-sigma %s", lr.name, version, n,
                      m["samples"], m["method"], lr.last["sigma"])
        return msg

    # ------------------------------------------------------------------ status
    def received(self) -> int:
        """Samples received, all targets."""
        return sum(lr.received for lr in self.learners.values())

    def counters(self) -> dict:
        c = dict(self.counts)
        for t, lr in self.learners.items():
            c.update(lr.counters())
            c[f"version_{t}"] = self.version[t]
        return c

    def detail(self) -> str:
        s = "; ".join(f"{lr.name} v{lr.last['version']} (through {lr.last['samples_seen']} samples, 1-sigma "
                      f"{lr.last['sigma']})" for lr in self.learners.values() if lr.last) or "no set published yet"
        return f"{s}; {self.settings.label}, device {self.device or 'cpu'}" + (f"; {self.busy}" if self.busy else "")


class ModelPublishers:
    """The trainer's publishers on <base>/learn/model/<name>, one per model name, made on first use. ``watch``
    follows the link to the router (a client's session reconnects by itself) and re-publishes the latest set of
    each model when it comes back, so a set trained during a cut is not lost."""

    def __init__(self, bus, log) -> None:
        self.bus, self.log = bus, log
        self.pubs: dict = {}
        self.lock = threading.Lock()
        self.up = self.connected()
        self.losses = self.republished = 0

    def publish(self, name: str, msg: dict) -> None:
        with self.lock:
            p = self.pubs.get(name)
            if p is None:
                p = self.pubs[name] = self.bus.publisher(self.bus.keys.learn_model(name))
            p.put(msg)

    def connected(self) -> bool:
        return bool(self.bus.routers() or self.bus.peers())

    def watch(self, run, poll_s: float, held) -> None:
        """Until the service stops: check the link every poll_s [s]; held() is the number of samples received."""
        while not run.wait(poll_s):
            up = self.connected()
            if up == self.up:
                continue
            self.up = up
            if not up:
                self.losses += 1
                self.log.warning("link to the router lost; training goes on with the %s samples received", held())
                continue
            with self.lock:
                for p in self.pubs.values():
                    if p.latest is not None:
                        p.put_raw(p.latest)
                        self.republished += 1
            self.log.info("link to the router restored; latest sets re-published (%s)",
                          ", ".join(self.pubs) or "none yet")

    def counters(self) -> dict:
        return {"link_losses": self.losses, "republished": self.republished}


def train_loop(run, node: TrainerNode) -> None:
    """The training thread: fit and publish every due point until the service stops; each fit is a heartbeat (a
    lockstep predictor waits on the trainer's progress, zennav.services.predictor)."""
    while not run.stopping:
        for t in node.wait_due():
            if run.stopping:
                break
            node.train(t)
            run.heartbeat()
