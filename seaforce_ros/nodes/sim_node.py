"""sim_node (node ``sim``): the simulated gripper, a drop-in substitute for hardware_node.

Every cycle it publishes ``actuator_state`` (one synchronous sample of every channel) and
applies the torques :class:`~seaforce_ros.core.plant_cycle.PlantCycle` allows from the newest
``actuator_command`` — the same safety rules as hardware_node (per-channel command watchdog,
fresh commands only, one command source, torque clamp, velocity trip, fault latch and
``~/reset``; see :mod:`seaforce_ros.nodes.plant_node`). ``joint_states`` at ``joint_state_rate``
and ``/diagnostics`` once per ``diagnostics_period``. The physics is
:class:`seaforce_ros.core.simulator.ChannelSimulator` per channel (lumped hydraulic model,
Dahl hysteresis, friction, sensors, endpoint environment).

``clock_mode``:
  * ``realtime`` - an own thread paces the cycle with absolute deadlines at ``rate``.
  * ``lockstep`` - the model advances one sample per command answering the current cycle,
    so a closed loop over ROS reproduces :func:`~seaforce_ros.core.simulator.run_closed_loop`
    sample for sample (no command watchdog: the sim waits). Until the first command arrives
    the current state is re-published every 100 ms.

The environment of each channel (``<channel>.environment.*``: free, torque sine or chirp,
position drive, or an ``object`` to grasp) and the simulated plant (``<channel>.sim.plant.*``,
``<channel>.sim.dahl.*``; by default the model ``<channel>.plant.*`` / ``dahl.*`` the
controller uses) can change at run time; a change takes effect at the start of the next cycle.
"""
from __future__ import annotations

import sys
import time

from rcl_interfaces.msg import SetParametersResult

from . import param_specs as ps
from ..core.environment import Environment, environment_from_dict
from ..core.errors import SeaforceError
from ..core.params import DahlParams, PlantParams
from ..core.plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_LIMIT
from ..core.schema import SIM
from ..core.sensors import SensorParams
from ..core.settings import SIM_PREFIX, SimulatorParams
from ..core.simulator import ChannelSimulator
from .plant_node import PlantNode, plant_specs, prepare_process
from .ros_common import StartupError, declare, log_events, run, shutdown_safe

LOCKSTEP_REPUBLISH = 0.1     # s without progress after which lockstep re-publishes its state


def node_specs():
    """sim_node's own parameters (the plant's common ones among them)."""
    return plant_specs(SIM)


class SimNode(PlantNode):
    """The simulated gripper (see module docstring).

    Parameters
    ----------
    direct : controller_node.DirectPort, optional
        The direct layout (bringup ``loop:=direct``): the cycle thread calls the controller.
    """

    def __init__(self, direct=None, **kwargs):
        super().__init__('sim', node_specs(), direct=direct, **kwargs)
        values = self.values
        self._specs = {}
        for channel in self.channels:
            specs = ps.sim_channel_specs(channel)
            values.update(declare(self, specs))
            true_plant = ps.sim_plant_specs(channel, values)     # defaults: the model
            values.update(declare(self, true_plant))
            self._specs.update({s.name: s for s in specs + true_plant})
        self.lockstep = values['clock_mode'] == 'lockstep'
        if self.lockstep and values['control_qos'] != 'reliable':
            raise StartupError('clock_mode lockstep needs control_qos reliable: a lost command '
                               'would stall the simulation')
        if self.lockstep and direct is not None:
            raise StartupError('loop direct needs clock_mode realtime (the controller is '
                               'called every cycle; there is nothing to wait for)')
        self.sims = []
        for index, channel in enumerate(self.channels):
            try:
                self.sims.append(self._make_sim(values, channel, values['seed'] + index))
            except (SeaforceError, ValueError) as exc:
                raise StartupError(ps.channel_error(exc, channel)) from None
        self._make_plant_cycle()
        self._pending_env = {}           # channel index -> Environment, applied next cycle
        self._pending_plant = {}         # channel index -> (PlantParams, DahlParams or None)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self._start_plant()
        self._last_progress = time.monotonic()
        if self.lockstep:
            self._republish()
            self.create_timer(LOCKSTEP_REPUBLISH, self._lockstep_kick)
        else:
            self._start_cycle_thread()
        self.get_logger().info(
            f'simulating channels {self.channels} at {values["rate"]:.0f} Hz, '
            f'clock_mode={values["clock_mode"]}, loop={"direct" if direct else "topics"}')

    @staticmethod
    def _true_plant(values, channel):
        """(PlantParams, DahlParams or None) of ``<channel>.sim.plant.*`` / ``sim.dahl.*``."""
        plant, dahl = (group.from_values({
            spec.name: values[f'{channel}.{SIM_PREFIX}{spec.name}'] for spec in group.SPECS})
            for group in (PlantParams, DahlParams))
        return plant, (dahl if dahl.sigma > 0 else None)

    def _make_sim(self, values, channel, seed):
        plant, dahl = self._true_plant(values, channel)
        sensors, physics = (group.from_values({
            spec.name: values[f'{channel}.{spec.name}'] for spec in group.SPECS
            if f'{channel}.{spec.name}' in values}) for group in (SensorParams, SimulatorParams))
        env = environment_from_dict(ps.channel_values(values, channel, 'environment.'))
        return ChannelSimulator(
            plant, dahl=dahl, dt=self.dt, seed=seed, environment=env, sensors=sensors,
            **{spec.attribute: getattr(physics, spec.attribute) for spec in physics.SPECS})

    # --- parameters ----------------------------------------------------------------------
    def _validate_parameters(self, params):
        changed = {p.name: p.value for p in params}
        for name, value in changed.items():
            spec = self._specs.get(name)
            if spec is not None:
                reason = spec.reason(value)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
        for channel in self.channels:
            try:
                if any(k.startswith(f'{channel}.environment.') for k in changed):
                    self._environment_with(channel, changed)
                if any(k.startswith(f'{channel}.sim.') for k in changed):
                    self._plant_with(channel, changed)
            except (SeaforceError, ValueError) as exc:
                return SetParametersResult(successful=False,
                                           reason=ps.channel_error(exc, channel))
        return SetParametersResult(successful=True)

    def _plant_with(self, channel, changed):
        current = {}
        for key in ps.MODEL_KEYS:
            name = f'{channel}.{SIM_PREFIX}{key}'
            current[name] = changed.get(name, self.get_parameter(name).value)
        return self._true_plant(current, channel)

    def _environment_with(self, channel, changed):
        current = {}
        for spec in Environment.SPECS:
            name = f'{channel}.{spec.name}'
            current[spec.name] = changed.get(name, self.get_parameter(name).value)
        return environment_from_dict(current)

    def _apply_parameters(self, params):
        super()._apply_parameters(params)
        changed = {p.name: p.value for p in params}
        for index, channel in enumerate(self.channels):
            if any(k.startswith(f'{channel}.environment.') for k in changed):
                env = self._environment_with(channel, changed)
                self._pending_env[index] = env
                self.get_logger().info(f'{channel}: environment -> {env.mode}')
            if any(k.startswith(f'{channel}.sim.plant.') or k.startswith(f'{channel}.sim.dahl.')
                   for k in changed):
                self._pending_plant[index] = self._plant_with(channel, changed)
                self.get_logger().info(f'{channel}: simulated plant changed')

    # --- the cycle (PlantNode hooks) -----------------------------------------------------
    @shutdown_safe
    def _on_command(self, msg):
        super()._on_command(msg)
        if self.lockstep and msg.cycle == self.plant.cycle:
            # one sample per answer: apply it, then publish the state it leads to
            now = self._last_progress = time.monotonic()
            self.stats.tick(now)
            self._decide_and_write(now, answered=self.plant.cycle)
            self._read_sample(now)
            if self.plant.events:
                log_events(self.get_logger(), self.plant.events.drain())

    def _write(self, out):
        pending = self._pending_env
        if pending:
            for index in list(pending):
                self.sims[index].set_environment(pending.pop(index))
        plants = self._pending_plant
        if plants:
            for index in list(plants):
                self.sims[index].set_plant(*plants.pop(index))
        for sim, torque in zip(self.sims, out.torque):
            sim.step(torque)

    def _sample(self, out, sample):
        x, v, fp, fa, xe, fe, status = sample
        for i, sim in enumerate(self.sims):
            m = sim.measurement()
            x[i], v[i], fp[i], fa[i], xe[i], fe[i] = m.x, m.v, m.f_p, m.f_a, m.x_e, m.f_e
            status[i] = out.status[i] | (STATUS_LIMIT if sim.limited else 0)

    def _ve(self, i):
        return self.sims[i].state[3]     # the simulator knows the true endpoint velocity

    def _republish(self):
        """(lockstep) Publish the current state again, e.g. state 0 before the first command."""
        sample = self._new_sample()
        self._sample(self.plant.out, sample)
        if self.plant.cycle == 0:
            sample[6][:] = [STATUS_COMMAND_TIMEOUT] * len(self.channels)
        self._publish(self.plant.cycle, time.time_ns(), sample, None)

    @shutdown_safe
    def _lockstep_kick(self):
        if time.monotonic() - self._last_progress > LOCKSTEP_REPUBLISH:
            self._republish()

    # --- monitoring ----------------------------------------------------------------------
    def _diagnostics(self):
        mode = 'lockstep' if self.lockstep else 'realtime'
        waiting = [c for c, s in zip(self.channels, self.plant.out.status)
                   if s & STATUS_COMMAND_TIMEOUT]
        warning = None
        if waiting and not self.lockstep:
            warning = 'command timeout: zero torque on ' + ', '.join(waiting)
        status = self._common_diagnostics('sim: cycle', 'seaforce_sim', f'running ({mode})',
                                          warning, {'clock_mode': mode})
        return [status] + self._channel_diagnostics(
            'sim', [f'seaforce_sim/{c}' for c in self.channels],
            lambda i: {'environment': self.sims[i].environment.mode})

    def shutdown(self):
        """Stop the cycle thread (called by :func:`~seaforce_ros.nodes.ros_common.run`)."""
        self._stop_threads()


def main(args=None):
    prepare_process()
    sys.exit(run(SimNode, args=args, name='sim_node'))


if __name__ == '__main__':
    main()
