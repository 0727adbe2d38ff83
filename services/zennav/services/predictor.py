"""predictor service (issue 6): holds the live parameter set (numpy only), swaps in a validated newer one
between two samples, and during GNSS outages publishes the predicted INS error on learn/correction.

Wiring table (planned)
    subscribes <base>/learn/model/*     model_params (validated: schema, shapes, finite, checksum, newer)
               <base>/nav/status        GNSS state (outage -> predict)
    publishes  <base>/learn/correction  correction (predicted error and its 1-sigma)

NOT IMPLEMENTED yet: the prediction loop and the ins pseudo-measurement are issue 6's work. The service
starts, announces liveliness, reports state 'not_implemented' and counts what it ignores.
"""
from __future__ import annotations

import sys

from zennav.service import not_implemented_main

REASON = "predictor not implemented yet (issue 6): no live model, no corrections published"


def main(argv=None) -> int:
    return not_implemented_main("predictor", REASON, argv, ["{base}/learn/model/*", "{base}/nav/status"])


if __name__ == "__main__":
    sys.exit(main())
