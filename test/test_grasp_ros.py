"""Grasping over ROS: the controller_node's ``~/grasp`` action on the simulated gripper.

* Objects drawn at random by the test (stiffness, damping, where, closing speed, grip; the sim's
  plant 15 % off the controller's model, its endpoint friction recalibrated first with
  ``~/calibrate_friction``, as docs/grasping.md says to), one after the other in one lockstep
  run: the grasp's goals asserted from what the sim reports (true contact force) and what the
  controller publishes (controller_status at every cycle, feedback, result); then the plant dies
  mid-grasp (its process killed): the goal aborted with the reason, the next one refused.
* The direct layout (bringup, real time): bad goals rejected with a reason, a second goal on a
  held channel, a goal on a faulted channel, a cancel that releases into the mode before the
  goal without the grip, a fault during a grasp that leaves zero torque.
* The default layout (sim_node + controller_node in real time, a CPU hog beside them): lost
  states and late commands -- free-air approaches find nothing, objects are held.
"""
import math
import os
import signal
import time

import numpy as np
import pytest
import yaml
from action_msgs.msg import GoalStatus
from seaforce_msgs.action import Grasp
from seaforce_msgs.msg import ActuatorState, ControllerStatus

from helpers.actions import ActionTestClient, CalibrationClient
from helpers.nodes import start_node
from helpers.states import stamp_ns, value

DT = 5e-4
#: status bits of a channel whose torque the plant replaced (its command timeout, a fault)
PLANT_STOPPED = ActuatorState.STATUS_COMMAND_TIMEOUT | ActuatorState.STATUS_FAULT
PLANT_KEYS = ('motor_inertia', 'motor_damping', 'motor_stiffness', 'endpoint_inertia',
              'endpoint_damping', 'endpoint_stiffness', 'hose_damping', 'hose_stiffness')
TABLE_I = {'motor_inertia': 1.1116e-3, 'motor_damping': 2.9814e-2, 'motor_stiffness': 0.1642,
           'endpoint_inertia': 0.7089e-3, 'endpoint_damping': 3.3879e-2,
           'endpoint_stiffness': 0.0637, 'hose_damping': 9.2453e-3, 'hose_stiffness': 13.0782}
#: grasps of one object at most, when the probe lost samples of the goal's span
ATTEMPTS = 3
CONTACT_DAMPING = 0.08          # grasp.contact_damping's default (the soft objects' creep)


class Client(ActionTestClient):
    """Grasp goals through an ActionClient on the probe's node."""

    def __init__(self, probe):
        super().__init__(probe, Grasp, '/controller/grasp')

    def goal(self, channel='pinch', closing_velocity=0.3, grip_force=0.3, max_force=0.6,
             probe=True):
        return Grasp.Goal(channel=channel, closing_velocity=float(closing_velocity),
                          grip_force=float(grip_force), max_force=float(max_force),
                          probe=probe)


def draw_objects(rng, n):
    """``n`` objects within the goal ranges: k log-uniform in 0.2..20 N m/rad, b 0.04..0.1
    N m s/rad, 0.15..0.3 rad beyond the finger, closed at 0.05..0.3 rad/s, gripped with
    0.2..0.5 N m but at most k x 1 rad (within grasp.give_way_travel), max_force twice that."""
    objects = []
    for _ in range(n):
        k = float(np.exp(rng.uniform(np.log(0.2), np.log(20.0))))
        objects.append(dict(k=k, b=float(rng.uniform(0.04, 0.1)),
                            gap=float(rng.uniform(0.15, 0.3)), v=float(rng.uniform(0.05, 0.3)),
                            grip=min(float(rng.uniform(0.2, 0.5)), max(0.2, k))))
    return objects


def wait_cycle(probe, topic, cycle, timeout=120.0):
    probe.wait_cycle(topic, cycle, timeout)
    return [m for m in probe.messages(topic) if m.cycle >= cycle]


def _grasp_once(probe, client, obj, where):
    """One grasp of ``obj`` over ROS from the finger's present position, canceled in a settled
    hold, released into passive; -> the figures the test judges, and the cycles of the goal's
    span the probe never got (a starved test process loses samples like any subscriber: the
    sim keeps 1000 for a reliable reader; the 2 kHz status is needed complete only from 0.1 s
    before the touch to the squeeze)."""
    now = probe.messages('actuator_state')[-1]
    position = value(now, 'pinch', 'endpoint_position') + obj['gap']
    # the squeeze ends inside the joint range's walls (1.35 rad): beyond, a wall takes part
    # of the grip (a soft object after the last one's release was squeezed into it)
    obj['grip'] = min(obj['grip'], obj['k'] * (1.25 - position))
    ok, reason = probe.set_parameters('/sim', {
        'pinch.environment.position': position, 'pinch.environment.stiffness': obj['k'],
        'pinch.environment.damping': obj['b']})
    assert ok, reason
    probe.clear('actuator_state')
    probe.clear('controller_status')
    max_force = 2.0 * obj['grip']
    handle, feedback = client.send(closing_velocity=obj['v'], grip_force=obj['grip'],
                                   max_force=max_force)
    probe.wait_for(lambda: feedback and feedback[-1].phase == 'hold', timeout=180,
                   what=f'hold ({where})')
    # the span starts at the first cycle both records hold: the two clears above are not one
    # instant, and a state that arrived just before the first is gone while its status, which
    # arrives after it, was kept by the second
    start = max(probe.messages('controller_status')[0].cycle,
                probe.messages('actuator_state')[0].cycle)
    touched = probe.wait_messages('actuator_state', 1, where=lambda m: m.cycle > start and
                                  value(m, 'pinch', 'external_force') < 0.0)[0].cycle
    wait_cycle(probe, 'controller_status', touched + int(0.5 / DT))
    settle = max(0.3, 6.0 * (obj['b'] + CONTACT_DAMPING) / obj['k'])
    wait_cycle(probe, 'actuator_state', probe.messages('actuator_state')[-1].cycle
               + int(settle / DT), timeout=300)
    canceled = probe.messages('actuator_state')[-1].cycle
    answer = client.cancel(handle)
    assert answer.status == GoalStatus.STATUS_CANCELED, where
    passive = probe.wait_messages('controller_status', 1, where=lambda m: m.cycle > start
                                  and value(m, 'pinch', 'grasp_phase') == '')[-1].cycle
    released = wait_cycle(probe, 'actuator_state', passive + 20)
    assert all(value(m, 'pinch', 'motor_effort') == 0.0
               for m in released if m.cycle > passive + 2), where

    states = {m.cycle: m for m in probe.messages('actuator_state')}
    status = {m.cycle: m for m in probe.messages('controller_status')}
    force = {c: -value(m, 'pinch', 'external_force') for c, m in states.items()}
    detected = min(c for c, m in status.items() if value(m, 'pinch', 'grasp_phase')
                   in ('contact', 'squeeze', 'probe', 'hold'))
    squeeze = min(c for c, m in status.items() if value(m, 'pinch', 'grasp_phase')
                  in ('squeeze', 'probe', 'hold'))
    at_half_second = status[min(c for c in status if c >= touched + int(0.5 / DT))]
    k_hat = value(at_half_second, 'pinch', 'object_stiffness')
    k_sigma = value(at_half_second, 'pinch', 'object_stiffness_sigma')
    b_hat = value(at_half_second, 'pinch', 'object_damping')
    b_sigma = value(at_half_second, 'pinch', 'object_damping_sigma')
    held = [force[c] for c in sorted(force) if c <= canceled][-int(0.1 / DT):]
    grip_error = abs(np.mean(held) - obj['grip']) / obj['grip']

    # the states over the whole span (forces, grip); the status where it times the contact
    spans = {'actuator_state': (states, start, canceled),
             'controller_status': (status, max(start, touched - int(0.1 / DT)), squeeze)}
    missing = {name: sorted(set(range(first, last + 1)) - set(record))
               for name, (record, first, last) in spans.items()}
    return dict(position=position, max_force=max_force, touched=touched, canceled=canceled,
                detected=detected, squeeze=squeeze, force=force, k_hat=k_hat, k_sigma=k_sigma,
                b_hat=b_hat, b_sigma=b_sigma, grip_error=grip_error, answer=answer,
                feedback=feedback), missing


def test_grasp_random_objects_over_ros(processes, tmp_path, probe):
    """Three objects drawn by the test (seed printed on failure; SEAFORCE_GRASP_SEED repeats a
    run), the sim's plant 15 % off the model, the friction recalibrated first (6 s in free
    air, 0.1 rad at 0.5 rad/s): stiffness within 10 % (25 % beyond 5 N m/rad, 30 % beyond 15)
    0.5 s after the contact and within 2.5 of its reported 1-sigma; damping within 30 % up to
    5 N m/rad; contact detected within 10 ms at 0.15-0.3 rad/s (30 ms slower), peak contact
    force before the squeeze below 0.05 N m (up to 5 N m/rad); grip within 5 % in a settled
    hold (8 % below 0.3 N m/rad: the finger's own spring's error); max_force never exceeded;
    the cancel releases the object into passive: zero torque. Then the sim's process is
    killed during a grasp: the goal ends ABORTED with 'no actuator_state for ...' and the
    next goal is refused with that reason."""
    seed = int(os.environ.get('SEAFORCE_GRASP_SEED', int.from_bytes(os.urandom(4), 'little')))
    rng = np.random.default_rng(seed)
    signs = [float(s) for s in rng.choice((-1.0, 1.0), size=len(PLANT_KEYS) + 2)]
    sim = {'clock_mode': 'lockstep', 'pinch.environment.mode': 'object',
           'pinch.environment.position': 10.0,
           **{f'pinch.sim.plant.{k}': TABLE_I[k] * (1.0 + 0.15 * s)
              for k, s in zip(PLANT_KEYS, signs)},
           'pinch.sim.dahl.sigma': 12.8 * (1.0 + 0.15 * signs[-2]),
           'pinch.sim.dahl.coulomb_force': 0.032 * (1.0 + 0.15 * signs[-1])}
    probe.record(ActuatorState, 'actuator_state')
    probe.record(ControllerStatus, 'controller_status')
    plant = start_node(processes, 'sim_node', 'sim', tmp_path, sim)
    probe.wait_messages('actuator_state', 1, timeout=60, where=lambda m: m.cycle == 0)
    start_node(processes, 'controller_node', 'controller', tmp_path,
               {'state_timeout': 5.0, 'status_rate': 2000.0,
                'pinch.friction.calibration_duration': 6.0})
    probe.wait_messages('controller_status', 5, timeout=60)       # the loop runs
    # with no object in reach: without it the model's b_e and Dahl F_c errors alone put the
    # object damping 30-60 % off at 3-5 N m/rad (docs/grasping.md)
    calibration = CalibrationClient(probe)
    handle, _ = calibration.send(amplitude=0.1, speed=0.5)
    answer = calibration.result(handle, timeout=240.0)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED and answer.result.applied, (
        seed, answer.result.message)
    client = Client(probe)
    for n, obj in enumerate(draw_objects(rng, 3)):
        where = f'seed {seed}, object {n}: {obj}'
        # judged only on a complete record of the goal's span: again (the same object) when
        # the probe lost samples, at most three times
        for attempt in range(1, ATTEMPTS + 1):
            run, missing = _grasp_once(probe, client, obj, where)
            if not any(missing.values()):
                break
            print(f'{where}: the probe lost ' + ', '.join(
                f'{len(c)} {name} samples' for name, c in missing.items() if c)
                + f' (attempt {attempt}/{ATTEMPTS})')
        assert not any(missing.values()), (where, {k: v[:10] for k, v in missing.items()})
        (position, max_force, touched, detected, squeeze, force, k_hat, k_sigma, b_hat, b_sigma,
         grip_error, answer, feedback) = (run[key] for key in (
            'position', 'max_force', 'touched', 'detected', 'squeeze', 'force', 'k_hat',
            'k_sigma', 'b_hat', 'b_sigma', 'grip_error', 'answer', 'feedback'))
        k, b = obj['k'], obj['b']

        assert max(force.values()) <= max_force, where
        assert abs(k_hat - k) <= (0.10 if k <= 5.0 else 0.25 if k <= 15.0 else 0.30) * k, (where, k_hat)
        assert abs(k_hat - k) <= 2.5 * k_sigma, (where, k_hat, k_sigma)
        if k <= 5.0:
            assert abs(b_hat - b) <= 0.30 * b, (where, b_hat)
        assert abs(b_hat - b) <= 2.5 * b_sigma, (where, b_hat, b_sigma)
        if k <= 5.0:
            assert 0 <= (detected - touched) * DT <= (0.010 if obj['v'] >= 0.15 else 0.030), where
            assert max(f for c, f in force.items() if touched <= c < squeeze) < 0.05, where
        assert grip_error <= (0.05 if k >= 0.3 else 0.08), (where, grip_error)
        result = answer.result
        assert result.contact and abs(result.contact_position - position) < 0.05, where
        assert result.object_stiffness == pytest.approx(k_hat, rel=0.3), where
        assert abs(result.grip_force - obj['grip']) < 0.05 * obj['grip'], where
        # (feedback at 50 Hz of wall time: a fast lockstep run can pass a 0.1 s phase unseen)
        assert {f.phase for f in feedback} >= {'approach', 'hold'}, where
        assert all(math.isfinite(f.endpoint_position) for f in feedback), where

    # the plant dies during a grasp (its process killed): the goal ends ABORTED with the
    # reason once no state has come for state_timeout, and the next goal is refused with it
    ok, reason = probe.set_parameters('/sim', {'pinch.environment.position': 10.0})
    assert ok, reason
    handle, feedback = client.send(closing_velocity=0.2, grip_force=0.3, max_force=0.6)
    probe.wait_for(lambda: feedback and feedback[-1].phase == 'approach', timeout=60,
                   what='approach')
    plant.send_signal(signal.SIGKILL)
    assert plant.wait(10.0) is not None
    answer = client.result(handle, timeout=60.0)
    assert answer.status == GoalStatus.STATUS_ABORTED, answer.result.message
    assert answer.result.message.startswith('no actuator_state for '), answer.result.message
    assert 'the plant stopped, or the link to it' in answer.result.message
    refused = client.rejected()
    assert 'no actuator_state for' in refused and 'held' not in refused, refused


def test_rejections_cancel_and_faults_in_the_direct_layout(processes, tmp_path, probe):
    """bringup loop:=direct in real time (the cycle thread runs the grasp; the executor serves
    the action): every bad goal ends at once with the reason; a cancel releases into hold
    without carrying the grip over; a fault during a grasp aborts it and leaves zero torque."""
    sections = tmp_path / 'bringup-overrides.yaml'
    sections.write_text(yaml.safe_dump({
        'controller': {'ros__parameters': {
            'loop': 'direct', 'state_timeout': 0.5, 'pinch.mode': 'hold',
            'wrist.mode': 'force', 'wrist.target.force': 2.0, 'wrist.max_torque': 1.0}},
        'sim': {'ros__parameters': {
            'pinch.environment.mode': 'object', 'pinch.environment.position': 0.2,
            'pinch.environment.stiffness': 3.0, 'pinch.environment.damping': 0.06,
            'command_timeout': 0.1}}}))
    start_node(processes, 'bringup', 'controller', tmp_path,
               ros_args=('--params-file', str(sections)))
    probe.record(ControllerStatus, 'controller_status')
    probe.record(ActuatorState, 'actuator_state')
    probe.wait_messages('controller_status', 5, timeout=60)
    client = Client(probe)
    assert 'unknown channel' in client.rejected(channel='thumb')
    assert 'closing_velocity = nan' in client.rejected(closing_velocity=math.nan)
    assert 'grip_force = inf' in client.rejected(grip_force=math.inf)
    assert 'max_torque = 20' in client.rejected(max_force=1e300)
    assert '|closing_velocity| must be within 0.01' in client.rejected(closing_velocity=0.0)
    assert 'max_force = 0.1 N m: must be >= grip_force' in client.rejected(max_force=0.1)
    # wrist: force mode beyond its max_torque has latched a fault
    probe.wait_messages('controller_status', 1, where=lambda m: 'torque' in value(
        m, 'wrist', 'fault'))
    assert 'wrist is faulted' in client.rejected(channel='wrist')
    assert 'call ~/reset' in client.rejected(channel='wrist')

    # pinch (in hold): grasp, a second goal on it, cancel -> hold again, without the grip
    handle, feedback = client.send(closing_velocity=0.3, grip_force=0.4, max_force=0.8)
    probe.wait_for(lambda: feedback and feedback[-1].phase == 'hold', timeout=60, what='hold')
    assert 'held by a grasp goal' in client.rejected()
    grip_torque = value(probe.messages('actuator_state')[-1], 'pinch', 'motor_effort')
    assert grip_torque > 0.3
    # (the status before the first grasp matches too: only the ones after the cancel count.
    # Beside a busy worker the cancel's answer came before the first of them, and the test
    # took the grasp's own squeeze, 0.62 N m, for what hold did after it)
    canceled = probe.messages('controller_status')[-1].cycle
    answer = client.cancel(handle)
    assert answer.status == GoalStatus.STATUS_CANCELED and answer.result.contact
    assert answer.result.message == 'released (goal canceled)'
    back = probe.wait_messages('controller_status', 1, where=lambda m: m.cycle > canceled
                               and value(m, 'pinch', 'grasp_phase') == ''
                               and value(m, 'pinch', 'mode') == 'hold')[-1].cycle
    probe.wait_cycle('actuator_state', back + 2001)
    after = [value(m, 'pinch', 'motor_effort') for m in probe.messages('actuator_state')
             if m.cycle > back]
    assert max(abs(e) for e in after) < 0.15 * grip_torque
    assert max(-value(m, 'pinch', 'external_force') for m in probe.messages('actuator_state')
               if m.cycle > back + 1000) < 0.05

    # a fault during a grasp: the channel's max_torque set below the grip's torque
    handle, feedback = client.send(closing_velocity=0.3, grip_force=0.4, max_force=0.8)
    probe.wait_for(lambda: feedback and feedback[-1].phase == 'hold', timeout=60, what='hold')
    ok, reason = probe.set_parameters('/controller', {'pinch.max_torque': 0.1})
    assert ok, reason
    answer = client.result(handle)
    assert answer.status == GoalStatus.STATUS_ABORTED
    assert answer.result.message.startswith('fault latched: torque'), answer.result.message
    faulted = probe.wait_messages('controller_status', 1, where=lambda m: value(
        m, 'pinch', 'fault') != '')[-1].cycle
    probe.wait_cycle('actuator_state', faulted + 101)
    assert all(value(m, 'pinch', 'motor_effort') == 0.0
               for m in probe.messages('actuator_state') if m.cycle > faulted + 5)


def test_grasps_in_the_default_layout_in_real_time(processes, tmp_path, probe, cpu_hog):
    """sim_node and controller_node as separate processes in real time (the default layout,
    a CPU-burning process per core beside them): the controller misses states now and then
    (a depth-1 subscription keeps the newest) and commands late. Free-air approaches both ways,
    canceled after 0.6 s, find no contact (before: every one aborted 'pushed from the side
    away from the object', the estimator taking a gap for a force); two objects drawn by the
    test are held, the stiffness within 15 %, the grip within 10 %."""
    seed = int.from_bytes(os.urandom(4), 'little')
    rng = np.random.default_rng(seed)
    start_node(processes, 'sim_node', 'sim', tmp_path, {
        'pinch.environment.mode': 'object', 'pinch.environment.position': 10.0})
    # state_timeout 1 s: beside the hog a CI run starved the controller process for 100 ms
    # (206 states unseen), a re-arm with 0.05 s (and the goal sent then refused: re-arming);
    # with 0.5 s such a gap is integrated, and the estimator is quiet after it -- but a fresh
    # clone's run (2026-12-06) had no state for 0.51 s and aborted a free-air approach 'no
    # actuator_state' before its cancel: the safe answer, not this test's subject
    start_node(processes, 'controller_node', 'controller', tmp_path, {'state_timeout': 1.0})
    probe.record(ActuatorState, 'actuator_state')
    probe.record(ControllerStatus, 'controller_status')
    # 2 s of the loop running before the first goal (a fresh clone's run beside the hog and the
    # other worker starved the just-started controller for 545 ms: the first approach aborted
    # 'stale state'; the loop settled, the test's subject is how the grasp rides such load)
    probe.wait_messages('controller_status', 200, timeout=60)
    client = Client(probe)
    for n in range(4):
        handle, _ = client.send(closing_velocity=0.3 * (-1) ** n, grip_force=0.3,
                                max_force=0.6)
        time.sleep(0.6)
        answer = client.cancel(handle)
        assert answer.status == GoalStatus.STATUS_CANCELED, (n, answer.result.message)
        assert not answer.result.contact, n
        time.sleep(0.2)
    for k in (float(rng.uniform(0.5, 2.0)), float(rng.uniform(2.0, 5.0))):
        where = f'seed {seed}, k = {k:.3g}'
        x = value(probe.messages('actuator_state')[-1], 'pinch', 'endpoint_position')
        ok, reason = probe.set_parameters('/sim', {
            'pinch.environment.position': x + 0.2, 'pinch.environment.stiffness': k,
            'pinch.environment.damping': 0.06})
        assert ok, reason
        handle, feedback = client.send(closing_velocity=0.2, grip_force=0.3, max_force=0.6)
        probe.wait_for(lambda: (feedback and feedback[-1].phase == 'hold')
                       or handle.status == GoalStatus.STATUS_ABORTED, timeout=30,
                       what=f'hold ({where})')
        if handle.status == GoalStatus.STATUS_ABORTED:
            pytest.fail(f'{where}: {client.result(handle).result.message}')
        time.sleep(max(1.0, 6.0 * (0.06 + CONTACT_DAMPING) / k))    # a soft object creeps
        canceled_ns = time.time_ns()
        answer = client.cancel(handle)
        result = answer.result
        assert answer.status == GoalStatus.STATUS_CANCELED, (where, result.message)
        assert result.contact and abs(result.object_stiffness - k) <= 0.15 * k, (
            where, result.object_stiffness)
        # the held grip is an average with a 0.1 s time constant: the 10 % goal is for a
        # settled hold, one in which the plant applied the commands over the last 0.3 s. A
        # plant stop under the hog (its command timeout: zero torque for 10 ms or more) in
        # that window pulls the average down -- a fresh-clone run measured 0.262 for 0.3 --
        # and the grip is then held to 30 %
        window = [m for m in probe.messages('actuator_state')
                  if 0 <= canceled_ns - stamp_ns(m) <= 300_000_000]
        assert len(window) > 100, (where, len(window))       # the probe saw the hold
        stopped = [m.cycle for m in window if value(m, 'pinch', 'status') & PLANT_STOPPED]
        tolerance = 0.30 if stopped else 0.10
        assert abs(result.grip_force - 0.3) <= tolerance * 0.3, (
            where, result.grip_force, f'plant stopped in {len(stopped)} of the last states')
        ok, reason = probe.set_parameters('/sim', {'pinch.environment.position': 10.0})
        assert ok, reason
        time.sleep(0.5)
