"""Seeded DVL beam anomalies for the evaluation of DVL fusion (seed 003, issue 14): inject them into any DvlData
with beams (a recording's derived beams or the simulator's) and keep a record of every event to score against.

Kinds (magnitudes in units of the DVL's beam 1-sigma ``sigma_mps``, default 0.02 m/s, the A-KIT README's
Workhorse figure):
- ``outlier``: a single-sample spike on one beam, +-magnitude sigma (default 20 sigma = 0.4 m/s), random sign.
- ``bias``: a step of +-magnitude sigma (default 5 sigma = 0.1 m/s) on one beam for duration_s (default 30 s).
- ``noise``: white noise of magnitude x sigma (default 10, i.e. 0.2 m/s 1-sigma) added to one beam for duration_s
  (default 30 s), a burst of noise (turbulence, bubbles, a weak bottom return).
- ``lost1``: one beam invalid for duration_s (default 30 s), e.g. a beam shadowed or without bottom lock.
- ``lost2p``: two parallel (opposite) beams invalid, ``lost2o``: two orthogonal (adjacent) beams invalid,
  ``lostall``: all four invalid (bottom loss), each for duration_s (default 30 s).
"Parallel" and "orthogonal" are in the Janus sense (zennav.nav.beams): beams i and i+2 point in opposite horizontal
directions (they lie in one vertical plane), beams i and i+1 in perpendicular ones.

Events at given times (``apply_events``: the simulator's bottom loss, noise bursts and bias jump) go through the same
code; an event may touch several beams (a noise burst on all four).

Spec (the loader option ``-o anomalies=...``): comma-separated ``kind[:count[:magnitude[:duration_s]]]``, e.g.
``outlier:10,bias:2:5:30,lost2o:1``; ``all`` is one event of every kind with the defaults. Events come in random
order at random times inside [t_from_ns, end] (the spare samples split at random between them), never overlapping
(at least one clean sample between two events), and touch random beams. Where an event changed the beams,
``velocity_d`` is recomputed from the valid beams as a DVL does (least squares, zennav.nav.beams; invalid with fewer
than three valid beams), so a loose body-velocity filter sees the same anomaly.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from zennav.nav.beams import velocity_from_beams
from zennav.nav.types import NS, DvlData

SIGMA_MPS = 0.02  # DVL beam 1-sigma [m/s] the default magnitudes are relative to (A-KIT README: Workhorse 0.02 m/s)
KINDS = {  # kind: (default magnitude [sigma, or noise std factor; 0 for lost beams], default duration [s])
    "outlier": (20.0, 0.0),
    "bias": (5.0, 30.0),
    "noise": (10.0, 30.0),
    "lost1": (0.0, 30.0),
    "lost2p": (0.0, 30.0),
    "lost2o": (0.0, 30.0),
    "lostall": (0.0, 30.0),
}
_LOST_BEAMS = {"lost1": 1, "lost2p": 2, "lost2o": 2, "lostall": 4}


@dataclass(frozen=True)
class AnomalySpec:
    """One line of the spec: count events of kind, magnitude (sigma units, or noise std factor), duration_s [s]."""

    kind: str
    count: int
    magnitude: float
    duration_s: float


@dataclass(frozen=True)
class AnomalyEvent:
    """One injected event: kind, the beams touched (0-based), [start_ns, end_ns] the first and last DVL sample
    times affected, magnitude in m/s (outlier: the signed spike, bias: the signed step, noise: the added 1-sigma;
    0 for lost beams) and the number of DVL samples affected."""

    kind: str
    beams: tuple[int, ...]
    start_ns: int
    end_ns: int
    magnitude_mps: float
    samples: int

    def as_dict(self) -> dict:
        return {**asdict(self), "beams": list(self.beams)}


def parse_spec(text: str) -> list[AnomalySpec]:
    """``kind[:count[:magnitude[:duration_s]]],...`` (module doc) -> specs; ValueError with the reason."""
    out = []
    for item in (x.strip() for x in str(text).split(",")):
        if not item:
            continue
        if item == "all":
            out += [AnomalySpec(kind, 1, *KINDS[kind]) for kind in KINDS]
            continue
        kind, *fields = item.split(":")
        if kind not in KINDS or len(fields) > 3:
            raise ValueError(f"DVL anomaly {item!r}: expected kind[:count[:magnitude[:duration_s]]] with kind one "
                             f"of {', '.join(KINDS)} or 'all'")
        try:
            values = [float(x) for x in fields]
        except ValueError:
            raise ValueError(f"DVL anomaly {item!r}: count, magnitude and duration must be numbers") from None
        count = values[0] if values else 1.0
        magnitude = values[1] if len(values) > 1 else KINDS[kind][0]
        duration = values[2] if len(values) > 2 else KINDS[kind][1]
        if count != int(count) or count < 0 or not np.isfinite(magnitude) or magnitude < 0 \
                or not np.isfinite(duration) or duration < 0:
            raise ValueError(f"DVL anomaly {item!r}: count a whole number >= 0, magnitude and duration finite >= 0")
        out.append(AnomalySpec(kind, int(count), magnitude, 0.0 if kind == "outlier" else duration))
    return out


def _beams_of(kind: str, rng: np.random.Generator) -> tuple[int, ...]:
    first = int(rng.integers(4))
    if kind == "lost2p":
        return tuple(sorted((first, (first + 2) % 4)))
    if kind == "lost2o":
        return tuple(sorted((first, (first + 1) % 4)))
    if kind == "lostall":
        return (0, 1, 2, 3)
    return (first,)


def inject(dvl: DvlData, spec, B: np.ndarray, seed: int = 0, t_from_ns: int | None = None,
           sigma_mps: float = SIGMA_MPS) -> tuple[DvlData, list[AnomalyEvent]]:
    """A copy of dvl (which must carry beams) with the anomalies of ``spec`` (a spec string or AnomalySpec list)
    injected, seeded, at samples at or after t_from_ns; B (4, 3) the beam directions (for velocity_d). Returns
    (the new DvlData, the events in time order). ValueError when the spec is malformed or the events do not
    fit."""
    if dvl.beams is None or dvl.beam_valid is None:
        raise ValueError("DVL anomalies are injected into beams; this DVL gives only a velocity")
    specs = parse_spec(spec) if isinstance(spec, str) else list(spec)
    rng = np.random.default_rng(seed)
    beams = dvl.beams.copy()
    valid = dvl.beam_valid.copy()
    t_ns = dvl.t_ns
    dt_s = float(np.median(np.diff(t_ns))) / NS if len(t_ns) > 1 else 1.0
    todo = [(s, 1 if s.kind == "outlier" else max(1, int(round(s.duration_s / dt_s)))) for s in specs
            for _ in range(s.count)]
    todo = [todo[i] for i in rng.permutation(len(todo))]
    first = 0 if t_from_ns is None else int(np.searchsorted(t_ns, t_from_ns, side="left"))
    slack = len(t_ns) - first - sum(length + 1 for _, length in todo) + 1  # one clean sample between events
    if slack < 0:
        raise ValueError(f"DVL anomalies: no room for {len(todo)} events of {sum(n for _, n in todo)} samples in "
                         f"{len(t_ns) - first} samples; ask for fewer or shorter events")
    gaps = np.diff(np.concatenate([[0], np.sort(rng.integers(0, slack + 1, size=len(todo)))]))
    touched = np.zeros(len(t_ns), dtype=bool)
    events: list[AnomalyEvent] = []
    k = first
    for (s, length), gap in zip(todo, gaps, strict=True):
        k += int(gap)
        cols = _beams_of(s.kind, rng)
        magnitude = 0.0
        if s.kind in ("outlier", "bias"):
            magnitude = float(rng.choice((-1.0, 1.0))) * s.magnitude * sigma_mps
        elif s.kind == "noise":
            magnitude = s.magnitude * sigma_mps
        event = AnomalyEvent(s.kind, cols, int(t_ns[k]), int(t_ns[k + length - 1]), magnitude, length)
        _apply(beams, valid, touched, slice(k, k + length), event, rng)
        events.append(event)
        k += length + 1
    return _with_velocity(dvl, beams, valid, touched, B), events


def apply_events(dvl: DvlData, events, B: np.ndarray, rng: np.random.Generator) -> DvlData:
    """A copy of dvl (with beams) with the given AnomalyEvents applied to its samples in [start_ns, end_ns] (the
    event's samples field is not used), noise drawn from rng; B (4, 3) the beam directions (for velocity_d)."""
    if dvl.beams is None or dvl.beam_valid is None:
        raise ValueError("DVL anomalies are applied to beams; this DVL gives only a velocity")
    beams, valid = dvl.beams.copy(), dvl.beam_valid.copy()
    touched = np.zeros(len(dvl.t_ns), dtype=bool)
    for event in events:
        a = int(np.searchsorted(dvl.t_ns, event.start_ns, side="left"))
        b = int(np.searchsorted(dvl.t_ns, event.end_ns, side="right"))
        _apply(beams, valid, touched, slice(a, b), event, rng)
    return _with_velocity(dvl, beams, valid, touched, B)


def _apply(beams: np.ndarray, valid: np.ndarray, touched: np.ndarray, rows: slice, event: AnomalyEvent,
           rng: np.random.Generator) -> None:
    """Apply one event to the rows of beams / valid in place (outlier, bias: + magnitude; noise: + magnitude x
    standard normal per sample and beam; lost kinds: invalid) and mark them touched."""
    cols = list(event.beams)
    touched[rows] = True
    if event.kind in ("outlier", "bias"):
        beams[rows, cols] += event.magnitude_mps
    elif event.kind == "noise":
        n = len(range(*rows.indices(len(beams))))
        beams[rows, cols] += event.magnitude_mps * rng.standard_normal((n, len(cols)))
    else:
        valid[rows, cols] = False


def _with_velocity(dvl: DvlData, beams: np.ndarray, valid: np.ndarray, touched: np.ndarray, B: np.ndarray) -> DvlData:
    """The new DvlData; where samples were touched, velocity_d recomputed from the valid beams (module doc)."""
    velocity_d = None if dvl.velocity_d is None else dvl.velocity_d.copy()
    velocity_valid = None if dvl.velocity_valid is None else dvl.velocity_valid.copy()
    if velocity_d is not None and velocity_valid is not None:
        for k in np.flatnonzero(touched).tolist():  # a DVL's own solution needs three beams
            ok = bool(valid[k].sum() >= 3)
            velocity_d[k] = velocity_from_beams(beams[k], valid[k], B) if ok else np.nan
            velocity_valid[k] = ok
    return DvlData(dvl.t_ns.copy(), beams, valid, velocity_d, velocity_valid)
