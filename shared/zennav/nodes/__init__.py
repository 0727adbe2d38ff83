"""The cores of the service processes, transport-free: each takes validated messages and hands its outputs to a
``publish`` callable, so that it runs the same in its service (services/zennav/services/, the wiring) and in
tests without a network. ``ins`` (the navigation engine over the sensor stream), ``attitude`` (the
complementary filter), ``monitor`` (what the monitor knows of the key space), ``trainer`` (learners over the
ins's samples) and ``predictor`` (validated hot swap and answers, numpy only), the last two over the cores in
zennav.learn."""
