"""The trainer drops the learn samples a resumed ins sends again (zennav.nodes.trainer): same stream, not after
the last sample accepted of the variant; counted as duplicate_samples."""
from __future__ import annotations

import logging

import numpy as np

from zennav import messages as M
from zennav.learn.settings import LearnSettings
from zennav.nav.learning import FEATURES, OUTPUTS, LearnSample
from zennav.nodes.trainer import TrainerNode

LOG = logging.getLogger("test")


def _sample(t_ns: int, index: int | None, stream: str | None = "ingest.a") -> dict:
    rng = np.random.default_rng(t_ns + (index or 0))
    s = LearnSample(t_ns, "drift", rng.normal(size=len(FEATURES["drift"])), rng.normal(size=len(OUTPUTS["drift"])))
    return M.learn_sample_msg(s, stream, index)


def test_samples_sent_again_after_a_resume_are_dropped_and_counted():
    node = TrainerNode(lambda name, msg: None, LOG, ("drift",), LearnSettings(min_samples=100, max_epochs=1))
    lr = node.learners["drift"]
    # two shadows' samples at each fix time (the same t_ns, consecutive indices)
    first = [_sample(10**9 * (1 + i // 2), i) for i in range(10)]
    for m in first[:7]:  # the ins dies after publishing the first of the 4th fix's pair
        node.on_sample(m)
    assert lr.received == 7 and node.counts["duplicate_samples"] == 0
    for m in first[4:]:  # resumed from its checkpoint after the 2nd fix: 4..6 again, then 7..9 new
        node.on_sample(m)
    assert lr.received == 10 and node.counts["duplicate_samples"] == 3
    held = [t for t, _x, _y in lr._pending]
    assert held == [m["t_ns"] for m in first]  # each sample once, in order
    # a new stream that starts earlier in time (another recording) is not a repeat
    node.on_sample(_sample(10**9, 0, stream="ingest.b"))
    # an ins restarted without a checkpoint on the first stream: its count starts again, its times go on
    node.on_sample(_sample(10**9, 0))  # back on stream a, earlier than its last: a repeat
    node.on_sample(_sample(6 * 10**9, 0))
    assert lr.received == 12 and node.counts["duplicate_samples"] == 4
    # senders without stream and index (older ones): only a time going back is a repeat
    node.on_sample(_sample(7 * 10**9, None, stream=None))
    node.on_sample(_sample(7 * 10**9, None, stream=None))
    node.on_sample(_sample(6 * 10**9, None, stream=None))
    assert lr.received == 14 and node.counts["duplicate_samples"] == 5
    assert node.counters()["duplicate_samples"] == 5
