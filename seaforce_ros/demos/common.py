"""What the demos share: the package's executables and config, node processes ended by their
PIDs, parameter and friction-calibration calls over ROS, the sim's drawn model error."""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time
from typing import List

import numpy as np

CHANNEL = 'pinch'
DT = 5e-4

PLANT_KEYS = ('motor_inertia', 'motor_damping', 'motor_stiffness', 'endpoint_inertia',
              'endpoint_damping', 'endpoint_stiffness', 'hose_damping', 'hose_stiffness')
# --- model error, and what the friction calibration recovers ------------------------------
FRICTION_LABELS = ('b_e [N m s/rad]', 'k_e [N m/rad]', 'F_c [N m]', 'sigma [N m/rad]',
                   'offset [N m]')
CALIBRATION_ATTEMPTS = 3
CALIBRATION_STATE_TIMEOUT = 0.25   # s, controller state_timeout while calibrating
#: s for a node to answer a parameter request: a busy host held a sim's answer back 20 s
SERVICE_TIMEOUT = 60.0


def prepare(out):
    """A demo's start: localhost-only discovery unless set, the output directory made;
    ``(out directory, lib dir with the executables, default config file)``."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return (out, *_package_paths())


def _package_paths():
    """(lib dir with the executables, default config file)."""
    try:
        from ament_index_python.packages import (get_package_prefix,
                                                 get_package_share_directory)
        lib = pathlib.Path(get_package_prefix('seaforce_ros')) / 'lib' / 'seaforce_ros'
        config = pathlib.Path(get_package_share_directory('seaforce_ros')) / 'config' / 'gripper.yaml'
        if (lib / 'sim_node').exists() and config.exists():
            return lib, config
    except Exception:
        pass
    root = pathlib.Path(__file__).resolve().parent.parent
    return root / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros', root / 'config' / 'gripper.yaml'


class Children:
    """Node processes of the demo; each is ended by its own PID."""

    def __init__(self, log_dir: pathlib.Path):
        self.log_dir = log_dir
        self.procs: List[subprocess.Popen] = []
        self.observers = []              # closed (before the processes stop) by stop_all

    def start(self, argv, name):
        log = open(self.log_dir / f'{name}.log', 'wb')
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        proc.log_path = self.log_dir / f'{name}.log'
        self.procs.append(proc)
        return proc

    def check(self):
        """RuntimeError if a node has exited."""
        for proc in self.procs:
            if proc.poll() is not None:
                raise RuntimeError(f'{proc.args[0]} exited; see {proc.log_path}')

    def stop_all(self):
        for observer in self.observers:
            observer.close()
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for proc in self.procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)


def run_guarded(label, out, work):
    """``work(children)`` -> exit code, with the demos' hygiene: SIGTERM is an interrupt, every
    node started through ``children`` is ended by its PID (observers it lists closed first),
    an error is one line and exit code 1, Ctrl-C 130."""
    children = Children(out)

    def on_signal(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, on_signal)
    print(f'[{label}] ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}; logs in {out}/',
          flush=True)
    try:
        return work(children)
    except KeyboardInterrupt:
        print(f'[{label}] interrupted; stopping the nodes', file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        print(f'[{label}] failed: {exc}', file=sys.stderr)
        return 1
    finally:
        children.stop_all()


def set_parameters(node, target, values, timeout=SERVICE_TIMEOUT, atomically=False):
    """Set ``values`` (name -> value) on ``target``'s node, all or none if ``atomically``;
    RuntimeError with the node's reason if it refuses or does not answer."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from ..nodes.ros_common import request_until_answered
    client = AsyncParameterClient(node, target)
    if not client.wait_for_services(timeout_sec=timeout):
        raise RuntimeError(f'the parameter services of {target} did not come up')
    parameters = [Parameter(k, value=v) for k, v in values.items()]
    request = (client.set_parameters_atomically if atomically else client.set_parameters)
    try:
        response = request_until_answered(lambda: request(parameters), timeout)
    except TimeoutError:
        raise RuntimeError(f'no answer setting {list(values)} on {target}') from None
    results = [response.result] if atomically else response.results
    failed = [r.reason for r in results if not r.successful]
    if failed:
        raise RuntimeError(f'{target} rejected {list(values)}: {failed[0]}')


def get_parameter(node, target, name, timeout=SERVICE_TIMEOUT):
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    from ..nodes.ros_common import request_until_answered
    client = AsyncParameterClient(node, target)
    if not client.wait_for_services(timeout_sec=timeout):
        raise RuntimeError(f'the parameter services of {target} did not come up')
    try:
        response = request_until_answered(lambda: client.get_parameters([name]), timeout)
    except TimeoutError:
        raise RuntimeError(f'no answer reading {name} on {target}') from None
    return parameter_value_to_python(response.values[0])


def run_friction_calibration(observer, children, args):
    """Release the finger into free air and run ~/calibrate_friction; its result. The
    controller's ``state_timeout`` and the channel's mode are left as the calibration set them
    (``hold``): the caller restores them."""
    from seaforce_msgs.action import CalibrateFriction
    node = observer.node
    # held where the drive left it, then released (in dob_full_ff a model that
    # over-compensates k_e lets the free finger creep away, out of the joint range); a
    # longer state_timeout while it runs (never a shorter one: a lockstep loop has a long
    # one): a loaded host's real-time loop stalls now and then, and a stall aborts a
    # calibration (zero torque, nothing applied)
    state_timeout = max(CALIBRATION_STATE_TIMEOUT,
                        get_parameter(node, '/controller', 'state_timeout'))
    set_parameters(node, '/controller', {
        f'{CHANNEL}.mode': 'hold', 'state_timeout': state_timeout,
        f'{CHANNEL}.friction.calibration_duration': float(args.calibration_time)})
    set_parameters(node, '/sim', {f'{CHANNEL}.environment.mode': 'free'})
    time.sleep(0.5)                                  # the released finger settles
    goal = CalibrateFriction.Goal(channel=CHANNEL, amplitude=0.4, speed=1.0, apply=True)
    for attempt in range(1, CALIBRATION_ATTEMPTS + 1):
        print(f'[demo] friction calibration: the finger in free air, '
              f'{args.calibration_time:g} s of motion ...', flush=True)
        result = run_action(observer, children, CalibrateFriction,
                            '/controller/calibrate_friction', goal,
                            3.0 * args.calibration_time + 60.0)
        if result.applied or attempt == CALIBRATION_ATTEMPTS:
            return result
        # a real-time loop on a loaded host stalls now and then: the stall zeroes the torque
        # and aborts the calibration (nothing applied); try again
        print(f'[demo]   aborted: {result.message}', flush=True)


def wait_until(children, done, timeout, what, poll=0.05):
    """Poll ``done()`` until it is true; RuntimeError when a node exits or after ``timeout`` s
    (``inf``: none), saying ``<what> within <timeout> s``."""
    deadline = time.monotonic() + timeout
    while not done():
        children.check()
        if time.monotonic() > deadline:
            raise RuntimeError(f'{what} within {timeout:g} s')
        time.sleep(poll)


def run_action(observer, children, kind, name, goal, timeout, on_feedback=None):
    """Send ``goal`` to the action server ``name`` (type ``kind``) and wait for its result
    (``on_feedback(feedback)`` for each feedback); RuntimeError when a node exits, the server
    is missing, the goal is rejected or nothing ends within ``timeout`` s."""
    from rclpy.action import ActionClient
    client = ActionClient(observer.node, kind, name)
    if not client.wait_for_server(timeout_sec=20.0):
        raise RuntimeError(f'the {name} action server did not come up')
    deadline = time.monotonic() + timeout
    callback = (lambda m: on_feedback(m.feedback)) if on_feedback else None

    def wait(future, what):
        wait_until(children, future.done, max(0.0, deadline - time.monotonic()),
                   f'{name}: {what}')
        return future.result()
    # (requests from the spin thread: from this one rclpy can drop the answer)
    handle = wait(observer.background.call(
        lambda: client.send_goal_async(goal, feedback_callback=callback)), 'no answer')
    if not handle.accepted:
        raise RuntimeError(f'{name} rejected the goal (the node\'s log says why)')
    return wait(observer.background.call(handle.get_result_async), 'no result').result


def print_calibration(result, truth, seconds):
    """The table of what ~/calibrate_friction recovered: model, new value, 1-sigma, the sim's
    truth (``{'<ch>.sim.<key>': value}``; the model where it has none) and the error."""
    print(f'\nFriction calibration (~/calibrate_friction, {seconds:g} s in free air): '
          f'{result.message}')
    print(f'{"parameter":18s}{"model":>11s}{"recalibrated":>14s}{"1-sigma":>10s}'
          f'{"sim truth":>11s}{"error":>9s}')
    for label, key, old, new, sigma in zip(FRICTION_LABELS, result.names, result.old_values,
                                           result.new_values, result.new_values_sigma):
        if key == 'pressure_offset':    # (the sim's sensor offset; an error in mN m)
            true = truth.get(f'{CHANNEL}.sensors.pressure_offset', 0.0)
            print(f'{label:18s}{old:11.4g}{new:14.4g}{sigma:10.2g}{true:11.4g}'
                  f'{1e3 * (new - true):+6.2f} mN m')
            continue
        true = truth.get(f'{CHANNEL}.sim.{key}', old)
        print(f'{label:18s}{old:11.4g}{new:14.4g}{sigma:10.2g}{true:11.4g}'
              f'{100.0 * (new / true - 1.0):+8.1f}%')


def _plant_values(factors):
    """``{'<ch>.sim.<key>': value}`` of Table I and the Dahl fit scaled by ``factors``."""
    from ..core.params import DahlParams, PlantParams
    table, dahl = PlantParams.table_i(), DahlParams()
    values = {f'{CHANNEL}.sim.plant.{k}': getattr(table, k) * factors[k] for k in PLANT_KEYS}
    values.update({f'{CHANNEL}.sim.dahl.{k}': getattr(dahl, k) * factors[k]
                   for k in ('sigma', 'coulomb_force')})
    return values


def true_plant(seed):
    """The sim's plant: Table I and the Dahl fit with every parameter 10-20 % off, signs at
    random; returns ``{'<ch>.sim.<key>': value}`` and ``{key: factor}``."""
    rng = np.random.default_rng(seed)
    factors = {key: float(1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(0.10, 0.20))
               for key in PLANT_KEYS + ('sigma', 'coulomb_force')}
    return _plant_values(factors), factors


def drawn_plant(seed, low, high):
    """The sim's plant: Table I and the Dahl fit with every parameter log-uniform in [low x,
    high x]; returns ``{'<ch>.sim.<key>': value}`` and ``{key: factor}``."""
    rng = np.random.default_rng(seed)
    factors = {key: float(np.exp(rng.uniform(np.log(low), np.log(high))))
               for key in PLANT_KEYS + ('sigma', 'coulomb_force')}
    return _plant_values(factors), factors
