"""Service heartbeat messages: ``svc/<service>/status``."""
from __future__ import annotations

import time

from .codec import make, pyval
from .schema import MAP, STR, define

SERVICE_STATES = ("starting", "running", "not_implemented", "done", "stopping", "error")

define("service_status", 1, "Per-service heartbeat: state (starting|running|not_implemented|done|stopping|error), "
       "detail, counters, rejections per reason; t_ns is wall clock here.",
       service=STR, state=STR, detail=STR, counters=MAP, rejected=MAP)


def service_status_msg(service: str, state: str, detail: str = "", counters=None, rejected=None, t_ns=None) -> dict:
    return make("service_status", time.time_ns() if t_ns is None else t_ns, service=service, state=state,
                detail=detail, counters=pyval(dict(counters or {})), rejected=pyval(dict(rejected or {})))
