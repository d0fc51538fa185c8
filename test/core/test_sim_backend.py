"""SimBackend: the simulator behind the plant node's backend protocol (no ROS)."""
import math

import pytest

from seaforce_ros.core.backend import LINK_COMPLETE, PlantBackend, PlantSample
from seaforce_ros.core.environment import torque_sine
from seaforce_ros.core.errors import SimulationDivergedError
from seaforce_ros.core.params import PlantParams
from seaforce_ros.core.plant_cycle import (STATUS_COMMAND_TIMEOUT, STATUS_FAULT, STATUS_LIMIT,
                                           PlantCycle, PlantLimits)
from seaforce_ros.core.sim_backend import SimBackend
from seaforce_ros.core.simulator import ChannelSimulator

DT = 5e-4
CHANNELS = ('wrist', 'pinch')


def make(clock_mode='realtime', saturation=10.0):
    sims = [ChannelSimulator(PlantParams(), dt=DT, seed=i, torque_saturation=saturation)
            for i in range(len(CHANNELS))]
    return SimBackend(CHANNELS, sims, clock_mode), sims


def cycle(backend, plant, effort):
    """One cycle as the plant node runs it: read, PlantCycle, write."""
    sample = PlantSample(len(CHANNELS))
    link = backend.read(sample)
    assert plant.exchange(link.counter, link.expected)
    plant.command(list(CHANNELS), list(effort), plant.state_published())
    backend.write(plant.step(0.0, sample.velocity, backend.drives()))
    return sample


def test_the_protocol_is_abstract():
    with pytest.raises(TypeError):
        PlantBackend()


def test_read_write_steps_the_physics_under_the_allowed_torque():
    backend, sims = make(saturation=0.5)
    for step in ('open', 'configure', 'activate'):
        assert getattr(backend, step)()
    plant = PlantCycle(CHANNELS, DT, PlantLimits(torque_limit=5.0))
    sample = PlantSample(2)
    assert backend.read(sample) is LINK_COMPLETE
    assert sample.position == [0.0, 0.0] and sample.flags == [0, 0]
    assert backend.drives() is None
    for _ in range(200):
        sample = cycle(backend, plant, (0.0, 1.0))
    assert sample.position[1] > 0.0 and sample.position[0] == pytest.approx(0.0, abs=1e-6)
    assert sample.effort[1] == pytest.approx(0.5)            # the simulated drive saturates
    assert sample.flags == [0, STATUS_LIMIT]
    now = PlantSample(2)
    backend.read(now)                 # read again: the true V_e after the last step
    assert now.endpoint_velocity[1] == sims[1].state[3] != sample.endpoint_velocity[1]
    assert math.isfinite(sample.endpoint_position[1])
    assert backend.deactivate() and backend.close() == ''


def test_environment_change_takes_effect_at_the_next_step():
    backend, sims = make()
    backend.set_environment(1, torque_sine(0.3, 10.0))
    assert sims[1].environment.mode == 'free'
    plant = PlantCycle(CHANNELS, DT)
    cycle(backend, plant, (0.0, 0.0))
    assert sims[1].environment.mode == 'torque_sine' and sims[0].environment.mode == 'free'


def test_diagnostics_warn_of_command_timeouts_only_in_realtime():
    for mode, warns in (('realtime', True), ('lockstep', False)):
        backend, _ = make(mode)
        plant = PlantCycle(CHANNELS, DT)
        backend.write(plant.step(0.0))            # no command yet: both channels time out
        assert plant.out.status == [STATUS_COMMAND_TIMEOUT] * 2
        report = backend.diagnostics()
        assert report.running == f'running ({mode})'
        assert bool(report.warning) is warns, report.warning
        assert [c.values['environment'] for c in report.channels] == ['free', 'free']


class DivergingSimulator(ChannelSimulator):
    """A simulator whose physics leaves the finite numbers at its ``at``-th step and at every
    step after it (until reset): what NonlinearChannelSimulator raises on effects too stiff
    for the step (they are not reached within the parameters' ranges: the failure is
    stood in for, the backend's answer to it is what is tested)."""

    def __init__(self, at, *args, **kwargs):
        self.at = at
        super().__init__(*args, **kwargs)

    def step(self, torque):
        if self.step_count + 1 >= self.at:
            raise SimulationDivergedError(self.t, tuple(self.state))
        return super().step(torque)


def test_a_diverged_channel_is_a_faulted_drive_until_reset():
    """The channel whose simulation diverges latches its fault with the reason (zero torque,
    STATUS_FAULT), stays where it was without stepping, the other channel runs on; the
    cycle's reset restarts it at rest and it takes torque again. Nothing raises out of
    write() (it stopped the sim node's cycle thread before)."""
    sims = [ChannelSimulator(PlantParams(), dt=DT, seed=0),
            DivergingSimulator(99, PlantParams(), dt=DT, seed=1)]
    backend = SimBackend(CHANNELS, sims)
    plant = PlantCycle(CHANNELS, DT, PlantLimits(torque_limit=5.0))
    for _ in range(98):
        cycle(backend, plant, (0.2, 0.2))
    assert backend.drives() is None and not plant.latched_faults()
    cycle(backend, plant, (0.2, 0.2))                  # the 99th step diverges
    frozen = sims[1].state
    assert backend.diverged[1] and not backend.diverged[0]
    assert backend.drives()[0] == (True, False, '')
    wrist_before = sims[0].state
    for _ in range(20):
        cycle(backend, plant, (0.2, 0.2))
        assert plant.out.torque[1] == 0.0 and plant.out.status[1] & STATUS_FAULT
        assert plant.out.torque[0] == 0.2 and not plant.out.status[0] & STATUS_FAULT
    assert sims[1].state == frozen and sims[0].state != wrist_before
    latched = plant.latched_faults()
    assert len(latched) == 1 and latched[0].startswith('pinch: the simulated plant diverged')
    assert 'until ~/reset' in latched[0]
    sims[1].at = math.inf                              # the physics is fine after the restart
    plant.request_reset()
    cycle(backend, plant, (0.2, 0.2))                  # the reset's cycle: still no torque
    assert plant.out.torque[1] == 0.0
    assert sims[1].state == (0.0, 0.0, 0.0, 0.0) and backend.drives() is None
    for _ in range(50):
        cycle(backend, plant, (0.2, 0.2))
    assert plant.out.torque[1] == 0.2 and not plant.latched_faults()
    assert sims[1].state[0] > 0.0
