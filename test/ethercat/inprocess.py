"""The emulator in this process, behind a pysoem-shaped master: fast tests of the project's
master (``EthercatBus``, ``EthercatBackend``) where timing is not the subject.

:class:`FakePysoem` stands for the ``pysoem`` module; its ``Master`` reaches the emulator's
slaves without a network: AL requests, SII words and registers go straight to the ESCs, SDOs to
their object dictionaries (with the emulator's abort codes), process data as real LRW frames
through the emulator's line (``Bus.handle`` / ``after_frame``: working counters, FMMUs,
injected drops and the drives' evidence counters as on the wire). It does what SOEM was seen
to do, in short: ``config_init`` addresses the slaves, programs the mailbox SMs from the SII and
requests PRE-OP; ``config_map`` runs each ``config_func`` at PRE-OP, takes the mapping from
CoE (the assignment objects) or else the SII, programs SM2/SM3 and the FMMUs (all outputs,
then all inputs) and requests SAFE-OP. The veth tests keep SOEM itself as the judge.

    pysoem = FakePysoem(emulator_config)
    bus = EthercatBus(bus_config, 'inprocess', pysoem=pysoem)
"""

import struct

from ethercat.emulator import config as cfg
from ethercat.emulator import frames as F
from ethercat.emulator.coe import SdoAbort, ABORT_TEXT
from ethercat.emulator.esc import REG_AL_CONTROL, REG_DC_ACTIVATION, REG_DC_CYCLE0, \
    REG_DC_START0, REG_WD_TIME_PD
from ethercat.emulator.mailbox import HEADER, MBX_COE

INIT_STATE, PREOP_STATE, SAFEOP_STATE, OP_STATE, STATE_ACK = 1, 2, 4, 8, 0x10


class SdoError(Exception):
    def __init__(self, slave_pos, index, subindex, abort_code, desc):
        super().__init__(desc)
        self.slave_pos, self.index, self.subindex = slave_pos, index, subindex
        self.abort_code, self.desc = abort_code, desc


class WkcError(Exception):
    pass


class MailboxError(Exception):
    desc = 'mailbox error'


class PacketError(Exception):
    desc = 'packet error'


class Emergency(Exception):
    def __init__(self, slave_pos, error_code, error_reg):
        super().__init__(f'emergency 0x{error_code:04X}')
        self.slave_pos, self.error_code, self.error_reg = slave_pos, error_code, error_reg


class ConfigMapError(Exception):
    def __init__(self, error_list):
        super().__init__(error_list)
        self.error_list = error_list


class _Message:
    def __init__(self, error_code, error_reg):
        self.error_code, self.error_reg = error_code, error_reg


class FakeSlave:
    """One slave as pysoem shows it."""

    def __init__(self, master, esc, position):
        self._master, self._esc, self._pos = master, esc, position
        ident = esc.identity
        self.man, self.id, self.rev = ident.vendor_id, ident.product_code, ident.revision
        self.name = esc.sii_spec.name[:40]
        self.config_func = None
        self._out = bytearray()
        self._in = b''
        self._out_log = self._in_log = 0
        self._callbacks = []
        self.state = 0

    # process data
    @property
    def output(self):
        return bytes(self._out)

    @output.setter
    def output(self, data):
        self._out[:] = data[:len(self._out)]

    @property
    def input(self):
        return self._in

    @property
    def al_status(self):
        return struct.unpack_from('<H', self._esc.mem, 0x0134)[0]

    # CoE
    def _od(self):
        owner = self._master._owner
        if owner.sdo_losses > 0:          # a lost mailbox exchange: SOEM returns no answer
            owner.sdo_losses -= 1
            raise WkcError()
        od = getattr(self._esc, 'od', None)
        if od is None or self._esc.mailbox is None or not self._esc.mailbox_active():
            raise WkcError()
        return od

    def sdo_read(self, index, subindex, size=0, ca=False, release_gil=None):
        od = self._od()
        waiting = self._take_emergencies()
        try:
            data = od.upload(index, subindex, ca)
        except SdoAbort as exc:
            self._hand_over(waiting)
            raise SdoError(self._pos + 1, index, subindex, exc.code,
                           ABORT_TEXT.get(exc.code, '')) from None
        self._hand_over(waiting)
        return data

    def sdo_write(self, index, subindex, data, ca=False, release_gil=None):
        od = self._od()
        waiting = self._take_emergencies()
        self._master._owner.sdo_writes.append((self._pos, index, subindex, ca))
        try:
            od.download(index, subindex, data, self._esc.al_state, ca)
        except SdoAbort as exc:
            self._hand_over(waiting)
            raise SdoError(self._pos + 1, index, subindex, exc.code,
                           ABORT_TEXT.get(exc.code, '')) from None
        self._hand_over(waiting)

    def add_emergency_callback(self, callback):
        self._callbacks.append(callback)

    def _take_emergencies(self):
        """The emergencies in the slave's mailbox, taken out of it: SOEM empties the mailbox
        before a transfer and keeps an emergency it finds on its error stack."""
        esc = self._esc
        out = []
        if esc.mailbox is None or not esc.mailbox_active():
            return out
        while True:
            message = esc.mailbox.take()
            if message is None:
                return out
            esc.mailbox.read_done()
            esc.mem[0x080D] &= 0xF7
            _, _, _, mtype = HEADER.unpack_from(message)
            body = message[HEADER.size:]
            if mtype & 0x0F == MBX_COE and struct.unpack_from('<H', body)[0] >> 12 == 1:
                out.append(struct.unpack_from('<HB', body, 2))

    def _hand_over(self, emergencies):
        """As pysoem after a transfer or a mailbox read: each emergency to the callbacks, or,
        with none registered, the first raised out of the call (whatever it returned is
        lost)."""
        for code, register in emergencies:
            if not self._callbacks:
                raise Emergency(self._pos + 1, code, register)
            for cb in self._callbacks:
                cb(_Message(code, register))

    def mbx_receive(self):
        esc = self._esc
        if esc.mailbox is None or not esc.mailbox_active():
            return 0
        self._hand_over(self._take_emergencies())
        return 1

    # registers
    def eeprom_read(self, word, timeout=20000):
        sii = self._esc.sii
        data = bytes(sii[2 * word:2 * word + 4])
        return data + b'\xff' * (4 - len(data))

    def _fprd(self, address, size, timeout_us=2000):
        if self._master.bus.silent:
            raise WkcError()
        data = bytearray(size)
        self._esc.read_into(address, data)
        return bytes(data)

    def _fpwr(self, address, data, timeout_us=2000):
        self._esc.write(address, bytes(data))

    def set_watchdog(self, wd_type, ms):
        divider = struct.unpack_from('<H', self._esc.mem, 0x0400)[0]
        ticks = int(ms * 1e6 / (40 * (divider + 2)))
        self._esc.write(REG_WD_TIME_PD, struct.pack('<H', min(ticks, 0xFFFF)))

    def dc_sync(self, act, cycle_ns, shift_ns=0, sync1_cycle_ns=None):
        esc = self._esc
        esc.write(REG_DC_ACTIVATION, b'\x00')
        now = esc.system_time_ns()
        start = (now // cycle_ns + 1) * cycle_ns + shift_ns
        esc.write(REG_DC_START0, struct.pack('<Q', start))
        esc.write(REG_DC_CYCLE0, struct.pack('<I', cycle_ns))
        esc.write(REG_DC_ACTIVATION, bytes([0x03 | (0x04 if sync1_cycle_ns is not None else 0)
                                            if act else 0]))

    def write_state(self):
        self._esc.write(REG_AL_CONTROL, struct.pack('<H', self.state))
        return 1


class FakeMaster:
    """pysoem.Master over an in-process emulator line."""

    def __init__(self, owner):
        self._owner = owner
        self.bus = owner.bus
        self.slaves = []
        self.state = 0
        self.expected_wkc = 0
        self.always_release_gil = False
        self.dc_time = 0
        self._reply = None
        self._n_out = self._n_in = 0

    def open(self, ifname):
        self._owner.opened += 1

    def close(self):
        self._owner.opened -= 1

    def config_init(self):
        bus = self.bus
        if bus.silent:
            return -1
        self.slaves = [FakeSlave(self, esc, i) for i, esc in enumerate(bus.slaves)]
        for i, esc in enumerate(bus.slaves):
            esc.write(0x0010, struct.pack('<H', 0x1001 + i))
            esc.al_control(INIT_STATE | STATE_ACK)
            if esc.sii_spec.mailbox is not None:
                rx, rx_n, tx, tx_n = esc.sii_spec.mailbox
                esc.write(0x0800, struct.pack('<HHBBBBHHBBBB', rx, rx_n, 0x26, 0, 1, 0,
                                              tx, tx_n, 0x22, 0, 1, 0))
            esc.al_control(PREOP_STATE)
        return len(self.slaves)

    def config_dc(self):
        found = False
        for esc in self.bus.slaves:
            if esc.dc:
                esc.write(0x0900, b'\0\0\0\0')
                found = True
        return found

    def config_map(self):
        errors = []
        for s in self.slaves:
            if s.config_func is not None:
                try:
                    s.config_func(s._pos + 1)
                except Exception as exc:       # pysoem re-raises the hook's exception
                    errors.append(exc)
        if errors:
            raise errors[0]
        sizes = []
        for s in self.slaves:
            esc = s._esc
            if getattr(esc, 'od', None) is not None and esc.mailbox is not None:
                expected = esc.expected_sync_managers()
                n_out = expected.get(2, (0, 0, True))[1]
                n_in = expected.get(3, (0, 0, False))[1]
            else:
                spec = esc.sii_spec
                n_out = (sum(p.bits for p in spec.rx_pdos) + 7) // 8
                n_in = (sum(p.bits for p in spec.tx_pdos) + 7) // 8
            sizes.append((n_out, n_in))
        log = 0
        fmmu_next = [0] * len(self.slaves)
        for s, (n_out, n_in) in zip(self.slaves, sizes):
            spec = s._esc.sii_spec
            sms = spec.sync_managers
            if len(sms) > 3:
                sm2, sm3 = sms[2], sms[3]
                s._esc.write(0x0810, struct.pack('<HHBBBB', sm2.start, n_out, sm2.control, 0,
                                                 1 if n_out else 0, 0))
                s._esc.write(0x0818, struct.pack('<HHBBBB', sm3.start, n_in, sm3.control, 0,
                                                 1 if n_in else 0, 0))
            s._out = bytearray(n_out)
            if n_out:
                s._esc.write(0x0600, struct.pack('<IHBBHBBB3x', log, n_out, 0, 7, sms[2].start,
                                                 0, 2, 1))
                fmmu_next[s._pos] = 1
                s._out_log = log
                log += n_out
        self._n_out = log
        for s, (n_out, n_in) in zip(self.slaves, sizes):
            if n_in:
                sms = s._esc.sii_spec.sync_managers
                s._esc.write(0x0600 + 16 * fmmu_next[s._pos],
                             struct.pack('<IHBBHBBB3x', log, n_in, 0, 7, sms[3].start, 0, 1, 1))
                s._in_log = log
                log += n_in
            s._in = bytes(n_in)
        self._n_in = log - self._n_out
        self.expected_wkc = 2 * sum(1 for n, _ in sizes if n) + sum(1 for _, n in sizes if n)
        for s in self.slaves:
            s._esc.al_control(SAFEOP_STATE)
        return log

    def read_state(self):
        for s in self.slaves:
            s.state = struct.unpack_from('<H', s._esc.mem, 0x0130)[0]
        return min(s.state & 0x0F for s in self.slaves)

    def write_state(self):
        for s in self.slaves:
            s._esc.al_control(self.state)
        return 1

    def state_check(self, expected, timeout=50000):
        if self.bus.silent:
            return 0
        states = [s._esc.al_state for s in self.slaves]
        return expected if all(x == expected for x in states) else min(states)

    def send_processdata(self):
        clock = self._owner.clock
        if hasattr(clock, 'advance'):
            clock.advance(self._owner.cycle_time)
        data = bytearray(self._n_out + self._n_in)
        for s in self.slaves:
            data[s._out_log:s._out_log + len(s._out)] = s._out
        frame = bytearray(b'\xff' * 6 + b'\x01' * 6 + b'\x88\xa4') + F.build_frame(
            [(F.LRW, 0, None, bytes(data))], index=self._owner.frames & 0x0F)
        self._owner.frames += 1
        n = self.bus.handle(frame, len(frame))
        self.bus.after_frame()
        self.bus.poll()
        if n:
            off, _, dlen = next(F.iter_datagrams(frame, 16, len(frame)))
            self._reply = (bytes(frame[off + 10:off + 10 + dlen]),
                           struct.unpack_from('<H', frame, off + 10 + dlen)[0])
            dc = [esc for esc in self.bus.slaves if esc.dc]
            if dc:
                self.dc_time = dc[0].system_time_ns()
        else:
            self._reply = None
        return 1

    def receive_processdata(self, timeout=2000):
        reply, self._reply = self._reply, None
        if reply is None:
            return -1
        data, wkc = reply
        if wkc == self.expected_wkc:
            for s in self.slaves:
                s._in = data[s._in_log:s._in_log + len(s._in)]
        return wkc


class _StepClock:
    """The line's clock: one cycle per process-data frame (and what :meth:`idle` adds), so
    watchdogs and SYNC0 run on the frames, not on this host's load."""

    def __init__(self, start=1000.0):
        self.t = start

    def __call__(self):
        return self.t

    def advance(self, seconds):
        self.t += seconds


class FakePysoem:
    """A ``pysoem`` stand-in over an in-process emulator line built from ``emulator_config``
    (``bus``: the emulator's :class:`~ethercat.emulator.bus.Bus`)."""

    INIT_STATE, PREOP_STATE, SAFEOP_STATE, OP_STATE, STATE_ACK = (INIT_STATE, PREOP_STATE,
                                                                  SAFEOP_STATE, OP_STATE,
                                                                  STATE_ACK)
    SdoError, WkcError, MailboxError, PacketError = SdoError, WkcError, MailboxError, PacketError
    Emergency, ConfigMapError = Emergency, ConfigMapError

    def __init__(self, emulator_config=None, clock=None):
        config = emulator_config or cfg.default_config()
        self.clock = clock or _StepClock()
        self.bus = cfg.build(config, clock=self.clock)
        self.cycle_time = self.bus.physics.cycle_time
        self.opened = 0
        self.frames = 0
        self.sdo_writes = []          # (position, index, subindex, complete access)
        self.sdo_losses = 0           # the next SDO transfers that get no answer

    def idle(self, seconds):
        """Time passes on the line without a frame (a pulled cable, a stalled master)."""
        self.clock.advance(seconds)
        self.bus.poll()

    def Master(self):
        return FakeMaster(self)

    def drive(self, name):
        return self.bus.slave(name)
