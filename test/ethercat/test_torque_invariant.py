"""No torque ever reaches a drive that is not in cyclic synchronous torque and Operation
enabled -- a property over every emulated drive profile and random lifecycles.

**The invariant.** Every process-data frame that carries a non-zero target torque (0x6071) to
a drive was sent when the newest inputs the master had received from that drive showed
*Operation enabled* with mode 10 in 0x6061; and no drive is ever in *Operation enabled* (in OP)
in another mode. The drives themselves count the violations (``unsafe_torque_frames``,
``enables_outside_cst``: ethercat/emulator/cia402.py); they must stay 0 whatever happens.

**What happens.** Hypothesis draws a profile for one drive (a standard drive beside it, a
coupler and the pressure terminal behind them), how its YAML maps the mode objects, and a
sequence of events: cycles with a random
torque command, drive faults (latched or not) and their clearing, ``~/reset``, deactivate and
activate, a master silent long enough for the drives' watchdog, lost frames, an AL error, and
someone else writing 0x6060 (while the master is inactive, or on a drive whose 0x6061 it
sees every cycle). The
master is the project's (EthercatBus, EthercatBackend and PlantCycle as the node runs them),
the line the emulator's, in this process (ethercat/inprocess.py).
"""

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ethercat.test_master_inprocess import DRIVE_PROFILES, Rig, assert_no_unsafe_torque
from ethercat.lines import CST_INPUTS, CST_OUTPUTS, bus_yaml, line
from seaforce_ros.core.plant_cycle import PlantLimits
from seaforce_ros.ethercat.errors import EthercatError

DRIVES = ('drive0', 'drive1')


@pytest.fixture(autouse=True, scope='module')
def short_waits():
    """The line in this process answers at once: a drive that cannot be seen disabled, or a
    bus that cannot come back, is known after a few cycles (the node waits 0.5 s and 1 s)."""
    import seaforce_ros.ethercat.backend as backend
    saved = backend.DISABLE_TIMEOUT, backend.RECOVERY_TIMEOUT
    backend.DISABLE_TIMEOUT, backend.RECOVERY_TIMEOUT = 0.02, 0.02
    yield
    backend.DISABLE_TIMEOUT, backend.RECOVERY_TIMEOUT = saved

# the ordinary events (cycles, resets, lifecycle) come more often than the disruptions, so
# that the drives are enabled for much of a script
_ordinary = st.one_of(
    st.tuples(st.just('run'), st.integers(1, 60), st.floats(-1.0, 1.0)),
    st.tuples(st.just('clear'), st.sampled_from(DRIVES)),
    st.tuples(st.just('reset')),
    st.tuples(st.just('deactivate')),
    st.tuples(st.just('activate')),
)
_disruptions = st.one_of(
    st.tuples(st.just('fault'), st.sampled_from(DRIVES), st.booleans()),
    st.tuples(st.just('silence'), st.one_of(st.floats(0.001, 0.05), st.floats(0.1, 0.2))),
    st.tuples(st.just('drop'), st.integers(1, 20)),
    st.tuples(st.just('al_error'), st.sampled_from(DRIVES)),
    st.tuples(st.just('mode'), st.sampled_from(DRIVES), st.sampled_from((0, 8, 9))),
)
events = st.one_of(_ordinary, _ordinary, _disruptions)


def apply(rig, event, torque):
    """Apply one event to the rig; returns the torque commanded from now on."""
    kind = event[0]
    fake, backend = rig.fake, rig.backend
    active = backend.state == 'active'
    if kind == 'run':
        torque = event[2]
        if active:
            rig.cycles(event[1], torque)
    elif kind == 'fault':
        rig.drive(event[1]).inject_fault(0x2310, 'over current', latched=event[2])
    elif kind == 'clear':
        rig.drive(event[1]).clear_fault()
    elif kind == 'reset' and active:
        rig.plant.request_reset()
        rig.cycles(5, torque)
    elif kind == 'deactivate' and active:
        try:
            backend.deactivate()
        except EthercatError:
            pass                          # a drive that stays powered: reported, bus SAFE-OP
    elif kind == 'activate' and not active:
        try:
            rig.activate()
        except EthercatError:
            pass                          # refused (a drive in error): stays inactive
    elif kind == 'silence':
        fake.bus.set_silent(True)
        if active:
            rig.cycles(3, torque)
        fake.idle(event[1])
        fake.bus.set_silent(False)
    elif kind == 'drop':
        fake.bus.drop(event[1], 'reply')
    elif kind == 'al_error':
        rig.drive(event[1]).inject_al_error(0x0001)
    elif kind == 'mode':
        # someone else (a vendor tool) writes 0x6060: while the master is inactive, or where
        # it sees 0x6061 every cycle (else, while it runs, the drive's mode is what the
        # master set and read: the premise of the property)
        name, mode = event[1], event[2]
        entries = rig.config.slaves[rig.config.slave_index(name)].inputs.names()
        if not active or 'mode_display' in entries:
            drive = rig.drive(name)
            drive.od.objects[0x6060].entries[0].value = mode
            drive.od.set(0x6061, 0, mode)
            drive.refresh_inputs()
    return torque


#: how the drive under test maps the mode: both objects, the display only (an outside 0x6060
#: write then stays), or neither (the master writes and reads them over CoE)
VARIANTS = {
    'both': {},
    'display_only': {'outputs': CST_OUTPUTS[:2]},
    'neither': {'outputs': CST_OUTPUTS[:2], 'inputs': CST_INPUTS[:4] + CST_INPUTS[5:]},
}


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(profile=st.sampled_from(DRIVE_PROFILES), variant=st.sampled_from(sorted(VARIANTS)),
       start_active=st.booleans(), script=st.lists(events, min_size=3, max_size=20))
def test_no_torque_reaches_a_drive_not_in_cst_operation_enabled(profile, variant,
                                                                start_active, script):
    emulator = line(profile, 'standard')
    yaml = bus_yaml(emulator, drive0=VARIANTS[variant])
    rig = Rig(emulator, yaml, limits=PlantLimits(command_timeout=0.05, wkc_error_limit=5))
    if start_active:
        rig.up()
    else:
        rig.backend.open()
        rig.backend.configure()
    torque = 0.1
    try:
        for event in script:
            torque = apply(rig, event, torque)
            if rig.backend.state == 'active':
                rig.cycles(10, torque)            # every event is followed by cycles
            assert_no_unsafe_torque(rig)
        if rig.backend.state == 'active':
            rig.cycles(20, torque)
        assert_no_unsafe_torque(rig)
    finally:
        try:
            rig.down()
        except EthercatError:
            rig.backend.close()            # a deactivation that could not see the drives
    assert_no_unsafe_torque(rig)
