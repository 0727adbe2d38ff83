"""trainer service (issue 6): collects learn/samples while GNSS is good, retrains ANFIS / Elman and publishes
versioned parameter sets on learn/model/<name> (the only process that imports torch).

Wiring table (planned)
    subscribes <base>/learn/samples        training pairs from the ins service
    publishes  <base>/learn/model/<name>   model_params (latest served to late joiners)

NOT IMPLEMENTED yet: the ins service does not emit training samples and the training schedule is issue 6's
work. The service starts, announces liveliness, reports state 'not_implemented' and counts what it ignores.
"""
from __future__ import annotations

import sys

from zennav.service import not_implemented_main

REASON = "trainer not implemented yet (issue 6): no training loop; learn/samples are counted and ignored"


def main(argv=None) -> int:
    return not_implemented_main("trainer", REASON, argv, ["{base}/learn/samples"])


if __name__ == "__main__":
    sys.exit(main())
