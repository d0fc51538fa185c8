"""Grasping demo: three simulated objects felt, squeezed, probed and measured over ROS 2.

Starts the simulated gripper and the controller (``bringup`` with ``loop:=direct``, the
layout for a 2 kHz loop; ``--lockstep``: separate ``sim_node`` / ``controller_node`` processes
in the deterministic lockstep mode) with the simulated plant 10-20 % off the controller's model
(every Table I and Dahl parameter, signs at random from ``--seed``), and sends the ``pinch``
finger a ``seaforce_msgs/action/Grasp`` goal for each of three objects placed in its way by the
sim's ``object`` environment (soft, medium, stiff). First, with no object in reach, the
finger's endpoint friction is recalibrated (``~/calibrate_friction``, ``--calibration-time`` s
in free air; ``--no-calibration`` grasps with the model as it is): the model's b_e and Dahl
F_c, 10-20 % off, turn into object damping error (docs/grasping.md). Per object it holds until
the grip has settled, cancels (the release), and prints the true vs. estimated stiffness and
damping with their 1-sigma, the contact detection delay, the peak contact force before the
squeeze, and the held grip vs. ``grip_force``; it writes a force-position plot per object. The controller sees
motor position and hose pressure only: the object's true force comes from the simulator.

Usage: python -m seaforce_ros.demos grasp [--out DIR] [--seed N] [--lockstep]
       [--speed RAD_S] [--grip N_M] [--calibration-time S] [--no-calibration]
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

import numpy as np
import yaml

from .common import (CHANNEL, DT, PLANT_KEYS, SERVICE_TIMEOUT, get_parameter, prepare,
                     print_calibration, run_friction_calibration, run_guarded, set_parameters,
                     true_plant, wait_until)

#: name, stiffness k_o [N m/rad], damping b_o [N m s/rad]
OBJECTS = (('soft', 0.5, 0.05), ('medium', 3.0, 0.06), ('stiff', 12.0, 0.08))
GAP = 0.2                 # rad between the finger and the next object's surface


class Observer:
    """In-process ROS node: records actuator_state and controller_status per cycle, sets the
    sim's parameters, sends grasp goals."""

    def __init__(self):
        from rclpy.action import ActionClient
        from seaforce_msgs.action import Grasp
        from seaforce_msgs.msg import ActuatorState, ControllerStatus

        from ..nodes.ros_common import RECORD_QOS, BackgroundNode

        self.background = BackgroundNode('seaforce_grasp_demo')
        self.node = self.background.node
        self.lock = threading.Lock()
        self.states = {}         # cycle -> (X_e, F_e, F_a)
        self.status = {}         # cycle -> (contact, k, k_sigma, b, b_sigma, phase)
        self.node.create_subscription(ActuatorState, 'actuator_state', self._on_state,
                                      RECORD_QOS)
        self.node.create_subscription(ControllerStatus, 'controller_status', self._on_status,
                                      RECORD_QOS)
        self.action = ActionClient(self.node, Grasp, '/controller/grasp')
        self.Goal = Grasp.Goal

    def _on_state(self, msg):
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.states[msg.cycle] = (msg.endpoint_position[i], msg.external_force[i],
                                      msg.motor_effort[i])

    def _on_status(self, msg):
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.status[msg.cycle] = (msg.contact[i], msg.object_stiffness[i],
                                      msg.object_stiffness_sigma[i], msg.object_damping[i],
                                      msg.object_damping_sigma[i], msg.grasp_phase[i])

    def latest(self):
        with self.lock:
            cycle = max(self.states) if self.states else None
            return cycle, (self.states[cycle] if cycle is not None else None)

    def wait_cycle(self, cycle, children, timeout=120.0):
        wait_until(children, lambda: (self.latest()[0] or 0) >= cycle, timeout,
                   f'the simulation did not reach cycle {cycle}')

    def set_sim(self, values, timeout=SERVICE_TIMEOUT):
        """The sim's parameters ``values``, all at once (an object moves with its spring)."""
        set_parameters(self.node, '/sim', values, timeout, atomically=True)

    def wait(self, future, what, children, timeout=120.0):
        wait_until(children, future.done, timeout, f'no {what}', poll=0.02)
        return future.result()

    def close(self):
        self.background.close()


def grasp_one(obs, children, name, k, b, speed, grip):
    """Place the object, grasp it, hold until settled, cancel; return what was measured."""
    cycle, (x_e, _, _) = obs.latest()
    surface = x_e + GAP
    obs.set_sim({f'{CHANNEL}.environment.mode': 'object',
                 f'{CHANNEL}.environment.position': surface,
                 f'{CHANNEL}.environment.stiffness': k, f'{CHANNEL}.environment.damping': b})
    max_force = 2.0 * grip
    goal = obs.Goal(channel=CHANNEL, closing_velocity=speed, grip_force=grip,
                    max_force=max_force, probe=True)
    feedback = []
    start = obs.latest()[0]
    # (requests from the spin thread: from this one rclpy can drop the answer)
    call = obs.background.call
    handle = obs.wait(call(lambda: obs.action.send_goal_async(
        goal, feedback_callback=lambda m: feedback.append(m.feedback.phase))), 'goal answer',
        children)
    ended = call(handle.get_result_async)
    deadline = time.monotonic() + 120.0
    while not feedback or feedback[-1] != 'hold':
        children.check()
        if ended.done():
            raise RuntimeError(f'{name}: the grasp ended: {ended.result().result.message}')
        if time.monotonic() > deadline:
            raise RuntimeError(f'{name}: the grasp never reached hold')
        time.sleep(0.02)
    settle = max(0.5, 6.0 * (b + 0.08) / k)                     # the soft object's creep
    obs.wait_cycle(obs.latest()[0] + int(settle / DT), children)
    canceled = obs.latest()[0]
    obs.wait(call(handle.cancel_goal_async), 'cancel answer', children)
    answer = obs.wait(ended, 'result', children)
    obs.wait_cycle(obs.latest()[0] + 200, children)
    with obs.lock:
        states = {c: v for c, v in obs.states.items() if c > start}
        status = {c: v for c, v in obs.status.items() if c > start}
    cycles = np.array(sorted(states))
    xe = np.array([states[c][0] for c in cycles])
    force = -np.array([states[c][1] for c in cycles])           # contact force, > 0
    # the touch: the cycle after the last state without contact force before the first with
    # it -- the earliest it can have been where the demo lost the states around it (a busy
    # host: the first state it had with a force came 51 ms after the controller's detection,
    # which the table then showed as a negative delay)
    first = int(np.argmax(force > 0.0))
    touched = int(cycles[first - 1]) + 1 if first > 0 else int(cycles[0])
    detected = min(c for c, v in status.items()
                   if v[5] in ('contact', 'squeeze', 'probe', 'hold'))
    squeeze = min(c for c, v in status.items() if v[5] in ('squeeze', 'probe', 'hold'))
    half = status[min(c for c in status if c >= touched + int(0.5 / DT))]
    held = force[(cycles > canceled - int(0.1 / DT)) & (cycles <= canceled)]
    r = answer.result
    return {'name': name, 'k': k, 'b': b, 'surface': surface, 'grip': grip,
            'max_force': max_force, 'k_half': half[1], 'k_sigma_half': half[2],
            'b_half': half[3], 'b_sigma_half': half[4], 'result': r,
            'delay_ms': (detected - touched) * DT * 1e3,
            # (from the touch to the squeeze: at least the touch's own sample -- the squeeze can
            # be reported at a cycle whose states the demo did not receive, before the first
            # positive force it has)
            'peak_approach': float(force[(cycles >= touched)
                                         & (cycles < max(squeeze, cycles[first] + 1))].max()),
            'peak': float(force.max()), 'held': float(held.mean()),
            'xe': xe, 'force': force, 'cycles': cycles, 'touched': touched,
            'canceled': canceled}


def plot(m, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    r = m['result']
    keep = m['cycles'] <= m['canceled']
    fig, ax = plt.subplots(figsize=(7, 5))
    ax.plot(m['xe'][keep], m['force'][keep], lw=1.0, color='#1f77b4',
            label='true contact force (simulator) vs endpoint position')
    x = np.linspace(r.contact_position, m['xe'][keep].max(), 50)
    ax.plot(x, r.object_stiffness * (x - r.contact_position), ls='--', color='#d62728',
            label=f'estimate: k = {r.object_stiffness:.3g} +- {r.object_stiffness_sigma:.2g} '
                  f'N m/rad from x_c = {r.contact_position:.3f} rad')
    ax.plot(x, m['k'] * (x - m['surface']), ls=':', color='0.3',
            label=f'true: k = {m["k"]:.3g} N m/rad from {m["surface"]:.3f} rad')
    ax.axhline(m['grip'], color='0.6', lw=0.8)
    ax.axhline(m['max_force'], color='#ff7f0e', lw=0.8, label='max_force')
    ax.set_xlabel('endpoint position X_e [rad]')
    ax.set_ylabel('contact force [N m]')
    ax.plot([], [], ' ', label=f'damping: true {m["b"]:.3g}, estimated {r.object_damping:.3g} '
                               f'+- {r.object_damping_sigma:.2g} N m s/rad')
    ax.set_title(f'{m["name"]} object: approach, squeeze, probe, hold')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc='upper left')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(results, factors, args):
    symbols = dict(zip(PLANT_KEYS + ('sigma', 'coulomb_force'),
                       ('m', 'b', 'k', 'm_e', 'b_e', 'k_e', 'b_s', 'k_s', 'sigma', 'F_c')))
    print(f'\npinch finger closing at {args.speed} rad/s, grip_force {args.grip} N m, '
          f'max_force {2 * args.grip} N m')
    print('the simulated plant vs the controller\'s model: '
          + ', '.join(f'{symbols[k]} {100 * (f - 1):+.0f}%' for k, f in factors.items()))
    print('\nobject   k true  k at 0.5 s  +-1 sigma  b true  b at 0.5 s  +-1 sigma  detect  '
          'peak before  grip held')
    print('        [N m/rad]   [N m/rad]             [N m s/rad]               [ms]  '
          'squeeze [N m]  [N m]')
    for m in results:
        print(f'{m["name"]:8s}{m["k"]:7.2f}{m["k_half"]:12.3f}{m["k_sigma_half"]:11.3f}'
              f'{m["b"]:8.3f}{m["b_half"]:12.4f}{m["b_sigma_half"]:11.4f}'
              f'{m["delay_ms"]:8.1f}{m["peak_approach"]:13.4f}{m["held"]:11.4f}')
    worst = max(m['peak'] / m['max_force'] for m in results)
    print(f'\nlargest contact force: {worst:.2f} of max_force; grip held within '
          + f'{max(abs(m["held"] - m["grip"]) / m["grip"] for m in results) * 100:.1f} % of '
          'grip_force')


def calibrate(observer, children, args, truth):
    """~/calibrate_friction with no object in reach; the controller's state_timeout and the
    channel's mode as they were; prints what it recovered."""
    node = observer.node
    before = {name: get_parameter(node, '/controller', name)
              for name in ('state_timeout', f'{CHANNEL}.mode')}
    result = run_friction_calibration(observer, children, args)
    set_parameters(node, '/controller', before)
    observer.set_sim({f'{CHANNEL}.environment.mode': 'object'})
    print_calibration(result, truth, args.calibration_time)
    if not result.applied:
        print('(not applied: the grasps use the model as it is)')


def main(argv=None):
    parser = argparse.ArgumentParser(prog='demo grasp', description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', default='out/demo', help='output directory (PNGs, logs)')
    parser.add_argument('--seed', type=int, default=3, help='seed of the plant error')
    parser.add_argument('--speed', type=float, default=0.2, help='closing velocity [rad/s]')
    parser.add_argument('--grip', type=float, default=0.3, help='grip_force [N m]')
    parser.add_argument('--lockstep', action='store_true',
                        help='separate sim_node/controller_node in deterministic lockstep')
    parser.add_argument('--calibration-time', type=float, default=10.0,
                        help='friction calibration length before the grasps [s]')
    parser.add_argument('--no-calibration', action='store_true',
                        help='grasp with the model as it is (no friction calibration first)')
    args = parser.parse_args(argv)

    out, lib, config = prepare(args.out)
    plant, factors = true_plant(args.seed)
    sim = {'clock_mode': 'lockstep' if args.lockstep else 'realtime',
           f'{CHANNEL}.environment.mode': 'object', f'{CHANNEL}.environment.position': 10.0,
           **plant}
    controller = {'state_timeout': 5.0 if args.lockstep else 0.5, 'status_rate': 2000.0}
    if not args.lockstep:
        controller['loop'] = 'direct'
    overrides = out / 'grasp-overrides.yaml'
    overrides.write_text(yaml.safe_dump({'/**/sim': {'ros__parameters': sim},
                                         '/**/controller': {'ros__parameters': controller}}))

    def work(children):
        names = ('sim_node', 'controller_node') if args.lockstep else ('bringup',)
        for name in names:
            children.start([str(lib / name), '--ros-args', '--params-file', str(config),
                            '--params-file', str(overrides)], name)
        observer = Observer()
        children.observers.append(observer)
        print('[demo grasp] waiting for the closed loop and the grasp action ...', flush=True)
        deadline = time.monotonic() + 60.0
        while not observer.status or not observer.action.server_is_ready():
            children.check()
            if time.monotonic() > deadline:
                raise RuntimeError('no controller_status / grasp action within 60 s')
            time.sleep(0.1)
        if not args.no_calibration:
            calibrate(observer, children, args, plant)
        results = []
        for name, k, b in OBJECTS:
            print(f'[demo grasp] {name} object (k = {k} N m/rad, b = {b} N m s/rad) ...',
                  flush=True)
            m = grasp_one(observer, children, name, k, b, args.speed, args.grip)
            results.append(m)
            plot(m, out / f'grasp_{name}.png')
        report(results, factors, args)
        print('\nforce-position plots: ' + ', '.join(str(out / f'grasp_{n}.png')
                                                   for n, _, _ in OBJECTS))
        return 0

    return run_guarded('demo grasp', out, work)


if __name__ == '__main__':
    sys.exit(main())
