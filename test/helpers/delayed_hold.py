"""The simulated hold with extra loop delay: the oracle the predictor's hold delay limit is
checked against (its test and bench/zwidth_prediction.py)."""
import numpy as np

from seaforce_ros.core import ChannelController, ChannelSimulator

__all__ = ['DelayedController', 'hold_grows']


class DelayedController:
    """A controller whose commands wait ``extra`` more samples (on top of the simulator's
    own one-sample delay)."""

    def __init__(self, controller, extra):
        self.controller = controller
        self.queue = [0.0] * extra

    def update(self, x, v, f_p):
        self.queue.append(self.controller.update(x, v, f_p))
        return self.queue.pop(0)


def hold_grows(plant, dahl, config, delay, seconds=1.5, dt=5e-4, seed=3):
    """The simulated hold with a loop delay of ``delay`` >= 1 samples, endpoint free, from a
    0.01 rad offset: True when the late command envelope (last fifth) exceeds the early one
    (10-30 % of the run), or the command diverges."""
    sim = ChannelSimulator(plant, dahl, dt=dt, seed=seed)
    sim.reset(state=(0.01, 0.0, 0.01, 0.0))
    ctl = DelayedController(ChannelController(config.replace(mode="hold"), dt), delay - 1)
    n = int(seconds / dt)
    m = sim.measurement()
    u = np.zeros(n)
    for i in range(n):
        u[i] = ctl.update(m.x, m.v, m.f_p)
        if not abs(u[i]) < 1e3:
            return True
        m = sim.step(u[i])
    return bool(np.max(np.abs(u[4 * n // 5:])) > np.max(np.abs(u[n // 10: 3 * n // 10])))
