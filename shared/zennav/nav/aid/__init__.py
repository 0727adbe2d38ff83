"""Aiding sources of the navigation engine (see base.py): GNSS position and velocity (gnss.py), learned
pseudo-measurements (learned.py), vehicle-motion constraints (constraints.py: non-holonomic; zupt.py: zero velocity
and angular rate at standstill; odometer.py: wheel speed with a scale-factor state; vehicle.py: their vehicle
frame), the AUV's Doppler velocity log (dvl.py: tight per beam or loose; dvl_learned.py: tight with learned beam-error
compensation) and pressure depth (depth.py).
``build_sources`` is the one place that says which sources an engine runs."""
from __future__ import annotations

from ..learning import TARGETS
from ..types import NavConfig
from .base import AidReport, AidSource, Measurement
from .constraints import NonHolonomic
from .depth import Depth, depth_source
from .dvl import BeamFeatures, DvlLoose, DvlTight, dvl_source
from .dvl_learned import DvlAnswers, LearnedDvl
from .gnss import MAX_FIX_AGE_S, FixContext, GnssPosition, GnssVelocity
from .learned import LearnedSource
from .odometer import Odometer, OdometerSample
from .zupt import ZeroVelocity

__all__ = ["AidReport", "AidSource", "BeamFeatures", "Depth", "DvlAnswers", "DvlLoose", "DvlTight", "FixContext",
           "GnssPosition", "GnssVelocity", "LearnedDvl", "LearnedSource", "MAX_FIX_AGE_S", "Measurement",
           "NonHolonomic", "Odometer", "OdometerSample", "ZeroVelocity", "build_sources"]


def build_sources(config: NavConfig, t0_ns: int) -> list[AidSource]:
    """The engine's sources in the order they take a shared input (a GNSS fix: position, then velocity); the
    learned ones only with config.learning, the vehicle constraints only with config.nhc, config.zupt and
    config.odometer, the DVL and depth sources only where the data has them (config.has_dvl, has_depth) and they are
    on (config.dvl_mode, config.depth); the tight DVL with learned compensation (and learned_dvl_beam taking its
    answers) with config.learning and config.dvl_learned."""
    sources: list[AidSource] = [GnssPosition(config, t0_ns), GnssVelocity(config, t0_ns)]
    if config.nhc:
        sources.append(NonHolonomic(config, t0_ns))
    if config.zupt:
        sources.append(ZeroVelocity(config, t0_ns))
    if config.odometer:
        sources.append(Odometer(config))
    dvl = dvl_source(config)
    if isinstance(dvl, DvlTight) and config.learning and config.dvl_learned:
        dvl = LearnedDvl(config)  # learned beam-error compensation (dvl_learned.py)
    sources += [s for s in (dvl, depth_source(config)) if s is not None]
    if config.learning:  # dvl_beam answers go to the learned DVL (none without it: counted correction_malformed)
        sources += [LearnedSource(config, target) for target in TARGETS if target != "dvl_beam"]
        if isinstance(dvl, LearnedDvl):
            sources.append(DvlAnswers(dvl))
    return sources
