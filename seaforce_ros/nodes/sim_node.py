"""sim_node (node ``sim``): the simulated gripper, a drop-in substitute for hardware_node.

A :class:`~seaforce_ros.nodes.plant_node.PlantNode` composing a
:class:`~seaforce_ros.core.sim_backend.SimBackend` built from the parameters. Like
hardware_node it is a managed (lifecycle) node; its ``autostart`` defaults to ``active``
(there is nothing to check and no drive to enable), and while it is not active the
simulated fingers rest.

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
The simulated plant's nonlinear effects (``<channel>.sim.nonlinear.*``: the hose's flow- and
pressure-dependent terms, the stroke-dependent diaphragm force, the four-bar finger ratio,
cogging; :mod:`~seaforce_ros.core.nonlinear_effects`) are set at start; with every one 0 (the
default) the channel is the linear simulator.
"""
from __future__ import annotations

import sys
from typing import Any, Dict, List, Optional, Tuple

from rcl_interfaces.msg import SetParametersResult

from . import param_specs as ps
from ..core.environment import Environment, environment_from_dict
from ..core.errors import SeaforceError
from ..core.params import DahlParams, PlantParams
from ..core.schema import SIM, Spec
from ..core.sensors import SensorParams
from ..core.settings import SIM_PREFIX, SimulatorParams
from ..core.nonlinear_effects import NonlinearEffects
from ..core.nonlinear_simulator import make_simulator
from ..core.sim_backend import SimBackend
from ..core.simulator import ChannelSimulator
from .plant_node import PlantNode, plant_specs, prepare_process
from .ros_common import StartupError, check_undeclared, declare, run


def node_specs() -> List[Spec]:
    """sim_node's own parameters (the plant's common ones among them)."""
    return plant_specs(SIM)


class SimNode(PlantNode):
    """The simulated gripper (see module docstring): the plant node with a SimBackend, and
    the sim's per-channel parameters (environment, true plant) that change at run time.

    Parameters
    ----------
    direct : controller_node.DirectPort, optional
        The direct layout (bringup ``loop:=direct``): the cycle thread calls the controller.
    """

    def __init__(self, direct: Any = None, **kwargs: Any) -> None:
        super().__init__('sim', node_specs(), direct=direct, **kwargs)
        values = self.values
        self._specs: Dict[str, Spec] = {}
        for channel in self.channels:
            specs = ps.sim_channel_specs(channel)
            values.update(declare(self, specs))
            true_plant = ps.sim_plant_specs(channel, values)     # defaults: the model
            values.update(declare(self, true_plant))
            self._specs.update({s.name: s for s in specs + true_plant})
        check_undeclared(self)          # every name declared; nothing simulated yet
        lockstep = values['clock_mode'] == 'lockstep'
        if lockstep and values['control_qos'] != 'reliable':
            raise StartupError('clock_mode lockstep needs control_qos reliable: a lost command '
                               'would stall the simulation')
        if lockstep and direct is not None:
            raise StartupError('loop direct needs clock_mode realtime (the controller is '
                               'called every cycle; there is nothing to wait for)')
        sims = []
        for index, channel in enumerate(self.channels):
            try:
                sims.append(self._make_sim(values, channel, values['seed'] + index))
            except (SeaforceError, ValueError) as exc:
                raise StartupError(ps.channel_error(exc, channel)) from None
        self.sim = SimBackend(self.channels, sims, values['clock_mode'])
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_sim_parameters)
        self.attach(self.sim, lockstep=lockstep, description=(
            f'simulating channels {self.channels} at {values["rate"]:.0f} Hz, '
            f'clock_mode={values["clock_mode"]}'))

    @staticmethod
    def _true_plant(values: Dict[str, Any],
                    channel: str) -> Tuple[PlantParams, Optional[DahlParams]]:
        """(PlantParams, DahlParams or None) of ``<channel>.sim.plant.*`` / ``sim.dahl.*``."""
        plant, dahl = (group.from_values({
            spec.name: values[f'{channel}.{SIM_PREFIX}{spec.name}'] for spec in group.SPECS})
            for group in (PlantParams, DahlParams))
        return plant, (dahl if dahl.sigma > 0 else None)

    def _make_sim(self, values: Dict[str, Any], channel: str, seed: int) -> ChannelSimulator:
        """The channel's simulator: the linear one, or the nonlinear one when an effect of
        ``<channel>.sim.nonlinear.*`` is on."""
        plant, dahl = self._true_plant(values, channel)
        sensors, physics, effects = (group.from_values({
            spec.name: values[f'{channel}.{spec.name}'] for spec in group.SPECS
            if f'{channel}.{spec.name}' in values})
            for group in (SensorParams, SimulatorParams, NonlinearEffects))
        env = environment_from_dict(ps.channel_values(values, channel, 'environment.'))
        if effects.any:
            self.get_logger().info(f'{channel}: nonlinear plant: {effects.describe()}')
        return make_simulator(
            plant, dahl, effects, dt=self.dt, seed=seed, environment=env, sensors=sensors,
            **{spec.attribute: getattr(physics, spec.attribute) for spec in physics.SPECS})

    # --- parameters ----------------------------------------------------------------------
    def _validate_parameters(self, params) -> SetParametersResult:
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

    def _plant_with(self, channel: str,
                    changed: Dict[str, Any]) -> Tuple[PlantParams, Optional[DahlParams]]:
        current = {}
        for key in ps.MODEL_KEYS:
            name = f'{channel}.{SIM_PREFIX}{key}'
            current[name] = changed.get(name, self.get_parameter(name).value)
        return self._true_plant(current, channel)

    def _environment_with(self, channel: str, changed: Dict[str, Any]) -> Environment:
        current = {}
        for spec in Environment.SPECS:
            name = f'{channel}.{spec.name}'
            current[spec.name] = changed.get(name, self.get_parameter(name).value)
        return environment_from_dict(current)

    def _apply_sim_parameters(self, params) -> None:
        """A new environment or true plant, handed to the backend for its next step."""
        changed = {p.name: p.value for p in params}
        for index, channel in enumerate(self.channels):
            if any(k.startswith(f'{channel}.environment.') for k in changed):
                env = self._environment_with(channel, changed)
                self.sim.set_environment(index, env)
                self.get_logger().info(f'{channel}: environment -> {env.mode}')
            if any(k.startswith(f'{channel}.sim.plant.') or k.startswith(f'{channel}.sim.dahl.')
                   for k in changed):
                self.sim.set_plant(index, *self._plant_with(channel, changed))
                self.get_logger().info(f'{channel}: simulated plant changed')


def main(args: Optional[List[str]] = None) -> None:
    prepare_process()
    sys.exit(run(SimNode, args=args, name='sim_node'))


if __name__ == '__main__':
    main()
