"""Controller configurations the tests build on (core only).

* :func:`exact_feedforward`: the paper's feed-forward, which cancels the model's endpoint
  friction exactly (``feedforward.margin`` 0 and ``dahl_stiffness_share`` 1, so
  ``allow_non_passive``). Tests that reproduce
  the paper's figures on a simulated plant equal to the model use it; everything a user runs
  keeps the margin (docs/safety-and-layouts.md).
* :func:`unlimited`: a joint range of +-100 rad and a runaway monitor that never trips, for
  tests of the controller's linear behaviour that drive the finger far (eq. 25 sweeps): the
  walls and the monitor are tested in test/core/test_safety.py.
"""

import dataclasses

from seaforce_ros.core.params import ControllerConfig, LimitParams, MonitorParams


def exact_feedforward(config=None, **changes):
    """``config`` (default ``ControllerConfig(**changes)``) without the feed-forward's margin."""
    config = ControllerConfig(**changes) if config is None else config.replace(**changes)
    return config.replace(feedforward=dataclasses.replace(config.feedforward, margin=0.0,
                                                          dahl_stiffness_share=1.0,
                                                          damping_reserve=0.0),
                          allow_non_passive=True)


def unlimited(config=None, **changes):
    """``config`` with a +-100 rad joint range and a monitor at 1000 rad/s."""
    config = ControllerConfig(**changes) if config is None else config.replace(**changes)
    return config.replace(limits=LimitParams(position_min=-100.0, position_max=100.0),
                          monitor=MonitorParams(max_speed=1000.0))
