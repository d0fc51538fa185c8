"""One emulated EtherCAT slave controller (ESC): register memory, AL state machine, SII
EEPROM interface, SyncManagers, FMMUs and the process-data watchdog.

The ESC is a 64 KiB byte array (registers 0x0000-0x0FFF, process RAM from 0x1000).
Datagrams read and write it; writes to a few registers have side effects:

* 0x0120 AL control -> AL state machine (:meth:`EscSlave.al_control`), every request is
  recorded (``last_al_request``, the bus's history);
* 0x0502 EEPROM control -> SII read (8 bytes into 0x0508, never busy) or write;
* 0x0600-0x06FF FMMUs and 0x0800-0x087F SyncManagers -> re-parsed on the next use;
* the mailbox (a slave with one, :mod:`.mailbox`): a write of SM0's last byte hands the
  message to the slave, a read of SM1's last byte empties SM1 (the next message moves in),
  0x080E bit 1 toggled = repeat the last message; SM status bit 3 says full;
* distributed clocks (``dc=True``: ESC feature bit 2 and 64-bit DC): a write to 0x0900 latches
  the port receive times (0x0900-0x090C, 0x0918), 0x0910 reads the system time (local time
  + offset 0x0920; a write of it is the drift control's and changes nothing here, the clocks
  do not drift), 0x0981 activates SYNC0 (bit 0 cyclic unit, bit 1 SYNC0) at the start time
  0x0990 and cycle 0x09A0.

Read-only registers (0x0000-0x000F, DL status 0x0110, AL status 0x0130-0x0135, watchdog
status 0x0440-0x0443, every SM's status and PDI control byte) ignore writes.  Application
behaviour (a drive, an analog terminal) lives in subclasses: :meth:`process_outputs`,
:meth:`update_inputs`, :meth:`on_state_change`, :meth:`on_watchdog_expired`,
:meth:`check_transition`.
"""

import struct
import time

from . import frames as F
from .sii import Identity, build_image, set_identity

# AL states
INIT, PREOP, BOOT, SAFEOP, OP = 1, 2, 3, 4, 8
AL_STATE_NAMES = {INIT: "INIT", PREOP: "PRE-OP", BOOT: "BOOT", SAFEOP: "SAFE-OP", OP: "OP"}
AL_ERROR_FLAG = 0x10
_RANK = {INIT: 0, PREOP: 1, BOOT: 1, SAFEOP: 2, OP: 3}
_UP = {(INIT, PREOP), (PREOP, SAFEOP), (SAFEOP, OP)}

# AL status codes (ETG.1000.6 table 11)
AL_CODE_NONE = 0x0000
AL_CODE_INVALID_STATE_CHANGE = 0x0011
AL_CODE_UNKNOWN_STATE = 0x0012
AL_CODE_BOOTSTRAP_NOT_SUPPORTED = 0x0013
AL_CODE_INVALID_MAILBOX_CONFIG = 0x0016
AL_CODE_SYNC_ERROR = 0x001A
AL_CODE_SM_WATCHDOG = 0x001B
AL_CODE_INVALID_OUTPUT_CONFIG = 0x001D
AL_CODE_INVALID_INPUT_CONFIG = 0x001E
AL_CODE_INVALID_DC_SYNC_CONFIG = 0x0030
AL_CODE_INVALID_SYNC_CYCLE_TIME = 0x0035

# registers
REG_TYPE = 0x0000
REG_PORT_DESC = 0x0007
REG_FEATURES = 0x0008
REG_STATION = 0x0010
REG_ALIAS = 0x0012
REG_DL_STATUS = 0x0110
REG_AL_CONTROL = 0x0120
REG_AL_STATUS = 0x0130
REG_AL_CODE = 0x0134
REG_PDI_CONTROL = 0x0140
REG_WD_DIVIDER = 0x0400
REG_WD_TIME_PDI = 0x0410
REG_WD_TIME_PD = 0x0420
REG_WD_STATUS = 0x0440
REG_WD_COUNTER = 0x0442
REG_EEP_CONTROL = 0x0502
REG_EEP_ADDRESS = 0x0504
REG_EEP_DATA = 0x0508
REG_FMMU = 0x0600
REG_SM = 0x0800
REG_SM0_STATUS, REG_SM1_STATUS = 0x0805, 0x080D
REG_SM1_ACTIVATE, REG_SM1_PDI = 0x080E, 0x080F
REG_DC_RECEIVE_TIME = 0x0900       # port 0..3, u32 each
REG_DC_SYSTEM_TIME = 0x0910
REG_DC_RECEIVE_TIME_EPU = 0x0918
REG_DC_OFFSET = 0x0920
REG_DC_DELAY = 0x0928
REG_DC_ACTIVATION = 0x0981
REG_DC_START0 = 0x0990
REG_DC_CYCLE0 = 0x09A0
REG_DC_CYCLE1 = 0x09A4
DC_CYCLIC, DC_SYNC0, DC_SYNC1 = 0x01, 0x02, 0x04
#: forward delay of one hop of the line [ns] (the port receive times SOEM measures delays from)
DC_HOP_NS = 250

SM_STATUS_FULL = 0x08

EEP_READ_8_BYTES = 0x0040
EEP_CMD_MASK = 0x0700
EEP_CMD_READ = 0x0100
EEP_CMD_WRITE = 0x0200

SM_CONTROL_WATCHDOG = 0x40

READ_ONLY = ((0x0000, 0x0010), (REG_DL_STATUS, REG_DL_STATUS + 2),
             (REG_AL_STATUS, REG_AL_STATUS + 6), (REG_WD_STATUS, REG_WD_STATUS + 4)) + tuple(
    (REG_SM + 8 * n + k, REG_SM + 8 * n + k + 1) for n in range(8) for k in (5, 7))

MEM_SIZE = 0x10000
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MASK64 = (1 << 64) - 1


class EscSlave:
    """An ESC with its SII image.  Subclasses add the application.

    Parameters
    ----------
    name : str
        Name used by the control side-channel and in status reports.
    sii_spec : sii.SiiSpec
        Identity, SMs, FMMUs and PDOs of the SII image.
    clock : callable
        Monotonic time source [s] (the watchdog's time base).
    block_lrw : bool
        Set the SII GENERAL flag blockLRW: SOEM then uses LWR + LRD instead of LRW.
    mailbox : mailbox.Mailbox, optional
        The slave's mailbox (the SII spec then gives SM0/SM1 and the CoE details).
    dc : bool
        The ESC has distributed clocks (feature register bit 2, 64-bit system time).
    """

    kind = "esc"

    def __init__(self, name, sii_spec, clock=time.monotonic, block_lrw=False, mailbox=None,
                 dc=False):
        if block_lrw:
            sii_spec.block_lrw = True
        self.name = name
        self.clock = clock
        self.sii_spec = sii_spec
        self.sii = build_image(sii_spec)
        self.identity = sii_spec.identity
        self.mem = bytearray(MEM_SIZE)
        self.position = 0
        self.al_state = INIT
        self.al_error = False
        self.al_code = AL_CODE_NONE
        self.last_al_request = None
        self.al_request_count = 0
        self.on_al_request = None      # callback(slave, value) set by the bus
        self.on_event = None           # callback(slave, text) set by the bus
        self.watchdog_expiries = 0
        self.last_watchdog_gap = None  # [s] last write -> expiry, at the last expiry
        self.outputs_fresh = False     # an armed (watchdog-trigger) SM was written this frame
        self._wd_last = clock()
        self._fmmus = None
        self._sms = None
        self.mailbox = mailbox
        self.dc = bool(dc)
        self.line_length = 1           # slaves on the line (the bus sets it)
        # each ESC's local clock starts somewhere else (SOEM's config_dc makes the system
        # times agree through the offsets)
        self._dc_base = 0x100000000 * (7 + sum(name.encode()) % 97)
        self.sync0_activated_at = None  # local time [ns] SYNC0 was switched on
        m = self.mem
        m[REG_TYPE] = 0x11
        m[0x0004] = 8                  # FMMUs supported
        m[0x0005] = 8                  # SyncManagers supported
        m[0x0006] = 8                  # process RAM [KiB]
        m[REG_PORT_DESC] = 0x0F        # ports 0 and 1: MII
        # features: bit 2 DC, bit 3 64-bit DC (without: SOEM's config_dc stops at once)
        _U16.pack_into(m, REG_FEATURES, 0x000C if self.dc else 0x0000)
        _U16.pack_into(m, REG_PDI_CONTROL, 0x0005)
        _U16.pack_into(m, REG_WD_DIVIDER, 2498)     # 100 us ticks
        _U16.pack_into(m, REG_WD_TIME_PDI, 1000)
        _U16.pack_into(m, REG_WD_TIME_PD, 1000)     # 100 ms process-data watchdog
        _U16.pack_into(m, REG_WD_STATUS, 0x0001)
        _U16.pack_into(m, REG_EEP_CONTROL, EEP_READ_8_BYTES)
        self.set_link(last=True)
        self._write_al_status()

    # --- identity / topology --------------------------------------------------------
    def set_link(self, last):
        """DL status 0x0110: port 0 communicating; port 1 communicating unless last."""
        value = 0x0010 | 0x0200 | 0x1000 | 0x4000      # link p0, comm p0, p2/p3 loop closed
        value |= 0x0400 if last else (0x0020 | 0x0800)
        _U16.pack_into(self.mem, REG_DL_STATUS, value)

    def set_identity(self, **fields):
        """Change vendor_id / product_code / revision / serial in the SII image (seen by
        the next ``config_init``)."""
        values = self.identity.as_dict()
        for key, value in fields.items():
            if key not in values:
                raise KeyError("unknown identity field %r (one of %s)" % (key, ", ".join(values)))
            values[key] = int(value)
        self.identity = Identity(**values)
        set_identity(self.sii, self.identity)

    @property
    def station_address(self):
        return _U16.unpack_from(self.mem, REG_STATION)[0]

    # --- register access ----------------------------------------------------------------
    def read_into(self, ado, data, combine_or=False):
        """Copy registers ``[ado, ado+len(data))`` into ``data`` (OR them for BRD)."""
        n = len(data)
        end = min(ado + n, MEM_SIZE)
        if self.dc and ado < 0x09B0 and end > REG_DC_SYSTEM_TIME:
            self._refresh_dc()
        chunk = self.mem[ado:end]
        if combine_or:
            for i, b in enumerate(chunk):
                data[i] |= b
        else:
            data[:end - ado] = chunk
        if self.mailbox is not None and ado >= 0x1000:
            self._mailbox_read(ado, end)

    def write(self, ado, data):
        """Store ``data`` at ``ado`` (read-only registers keep their value) and run the
        side effects of the registers written."""
        end = min(ado + len(data), MEM_SIZE)
        if end <= ado:
            return
        saved = [(lo, bytes(self.mem[lo:hi])) for lo, hi in READ_ONLY if ado < hi and end > lo]
        repeat_bit = self.mem[REG_SM1_ACTIVATE] & 0x02
        dc_time = bytes(self.mem[REG_DC_SYSTEM_TIME:REG_DC_SYSTEM_TIME + 8])
        self.mem[ado:end] = data[:end - ado]
        for lo, value in saved:
            self.mem[lo:lo + len(value)] = value
        if ado < 0x0900 and end > 0x0600:
            if end > REG_FMMU and ado < REG_FMMU + 0x100:
                self._fmmus = None
            if end > REG_SM and ado < REG_SM + 0x80:
                self._sms = None
                if ado <= REG_SM1_ACTIVATE < end and self.mailbox is not None and (
                        self.mem[REG_SM1_ACTIVATE] & 0x02) != repeat_bit:
                    self._mailbox_repeat()
        if ado <= REG_EEP_CONTROL + 1 and end > REG_EEP_CONTROL:
            self._eeprom_command()
        if ado <= REG_AL_CONTROL + 1 and end > REG_AL_CONTROL:
            self.al_control(_U16.unpack_from(self.mem, REG_AL_CONTROL)[0])
        if self.dc and 0x0900 <= end and ado < 0x09B0:
            self._dc_written(ado, end, dc_time)
        if self.mailbox is not None and ado >= 0x1000:
            self._mailbox_written(ado, end)

    # --- mailbox ------------------------------------------------------------------------------
    def mailbox_active(self):
        return self.mailbox is not None and self.al_state in (PREOP, SAFEOP, OP)

    def _mailbox_sm(self, n):
        start, length, _, activate = self.sync_managers()[n]
        return (start, length) if length and activate & 1 else None

    def _mailbox_written(self, ado, end):
        sm0 = self._mailbox_sm(0)
        if sm0 is None or not self.mailbox_active():
            return
        start, length = sm0
        if ado < start + length <= end:                 # the last byte: the message is in
            self.mailbox.on_request(bytes(self.mem[start:start + length]))
            self.mem[REG_SM0_STATUS] &= ~SM_STATUS_FULL & 0xFF
            self._mailbox_refresh()

    def _mailbox_read(self, ado, end):
        sm1 = self._mailbox_sm(1)
        if sm1 is None or not self.mailbox_active():
            return
        start, length = sm1
        if ado < start + length <= end and self.mem[REG_SM1_STATUS] & SM_STATUS_FULL:
            self.mailbox.read_done()
            self.mem[REG_SM1_STATUS] &= ~SM_STATUS_FULL & 0xFF
            self._mailbox_refresh()

    def _mailbox_repeat(self):
        self.mailbox.repeat()
        self.mem[REG_SM1_PDI] = (self.mem[REG_SM1_PDI] & ~0x02 & 0xFF) | (
            self.mem[REG_SM1_ACTIVATE] & 0x02)              # repeat acknowledged
        self._mailbox_refresh()

    def _mailbox_refresh(self):
        """Move the next message into SM1 if it is empty."""
        sm1 = self._mailbox_sm(1)
        if sm1 is None or self.mem[REG_SM1_STATUS] & SM_STATUS_FULL:
            return
        message = self.mailbox.take()
        if message is None:
            return
        start, length = sm1
        self.mem[start:start + length] = message[:length].ljust(length, b"\0")
        self.mem[REG_SM1_STATUS] |= SM_STATUS_FULL

    def post_mailbox(self, mtype, payload):
        """Send a message of the slave's own (an emergency) through the mailbox."""
        if self.mailbox is None:
            return
        self.mailbox.post(mtype, payload)
        if self.mailbox_active():
            self._mailbox_refresh()

    def _check_mailbox_config(self):
        """AL code for a mailbox SM0/SM1 set-up unlike the SII's at INIT -> PRE-OP (0: fine)."""
        rx_start, rx_size, tx_start, tx_size = self.sii_spec.mailbox
        sms = self.sync_managers()
        for n, (start, size) in ((0, (rx_start, rx_size)), (1, (tx_start, tx_size))):
            p_start, p_len, _, p_act = sms[n]
            if p_start != start or p_len != size or not p_act & 1:
                self._event("SM%d (mailbox) programmed start 0x%04X length %d enable %d, expected "
                            "0x%04X/%d/1" % (n, p_start, p_len, p_act & 1, start, size))
                return AL_CODE_INVALID_MAILBOX_CONFIG
        return AL_CODE_NONE

    # --- distributed clocks ---------------------------------------------------------------------
    def local_time_ns(self):
        """The ESC's local clock [ns] (the host's monotonic clock plus this ESC's start)."""
        return int(self.clock() * 1e9) + self._dc_base

    def system_time_ns(self, local=None):
        """Local time + the offset the master wrote into 0x0920 (64 bits, wrapping)."""
        local = self.local_time_ns() if local is None else local
        return (local + _U64.unpack_from(self.mem, REG_DC_OFFSET)[0]) & _MASK64

    def _refresh_dc(self):
        _U64.pack_into(self.mem, REG_DC_SYSTEM_TIME, self.system_time_ns())

    def _dc_written(self, ado, end, old_time):
        # the system time is read-only here: a write of it feeds a real ESC's drift control
        self.mem[REG_DC_SYSTEM_TIME:REG_DC_SYSTEM_TIME + 8] = old_time
        if ado <= REG_DC_RECEIVE_TIME < end:
            self._latch_receive_times()
        if ado <= REG_DC_ACTIVATION < end:
            self._dc_activation()

    def _latch_receive_times(self):
        """The frame that wrote 0x0900 passed port 0 of slave p at t + p hops and comes back
        through port 1 (open on all but the last slave) at t + (2 (n - 1) - p) hops."""
        local = self.local_time_ns()
        p, n = self.position, self.line_length
        forward = local + p * DC_HOP_NS
        back = local + (2 * (n - 1) - p) * DC_HOP_NS if p < n - 1 else 0
        _U32.pack_into(self.mem, REG_DC_RECEIVE_TIME, forward & 0xFFFFFFFF)
        _U32.pack_into(self.mem, REG_DC_RECEIVE_TIME + 4, back & 0xFFFFFFFF)
        _U32.pack_into(self.mem, REG_DC_RECEIVE_TIME + 8, 0)
        _U32.pack_into(self.mem, REG_DC_RECEIVE_TIME + 12, 0)
        _U64.pack_into(self.mem, REG_DC_RECEIVE_TIME_EPU, forward & _MASK64)

    def _dc_activation(self):
        act = self.mem[REG_DC_ACTIVATION]
        if act & (DC_CYCLIC | DC_SYNC0) == DC_CYCLIC | DC_SYNC0:
            self.sync0_activated_at = self.local_time_ns()
            self._event("SYNC0 on: cycle %d ns, start %d" % (self.sync0_cycle_ns(),
                                                             self.sync0_start_ns()))
        else:
            if self.sync0_activated_at is not None:
                self._event("SYNC0 off")
            self.sync0_activated_at = None

    def sync0_cycle_ns(self):
        return _U32.unpack_from(self.mem, REG_DC_CYCLE0)[0]

    def sync0_start_ns(self):
        return _U64.unpack_from(self.mem, REG_DC_START0)[0]

    def sync0_active(self):
        """SYNC0 pulses are generated (cyclic unit and SYNC0 on, a cycle time set)."""
        return self.dc and self.sync0_activated_at is not None and self.sync0_cycle_ns() > 0

    # --- SII EEPROM -------------------------------------------------------------------------
    def _eeprom_command(self):
        m = self.mem
        control = _U16.unpack_from(m, REG_EEP_CONTROL)[0]
        command = control & EEP_CMD_MASK
        word = _U16.unpack_from(m, REG_EEP_ADDRESS)[0]
        if command == EEP_CMD_READ:
            start = 2 * word
            chunk = bytes(self.sii[start:start + 8])
            m[REG_EEP_DATA:REG_EEP_DATA + 8] = chunk + b"\xff" * (8 - len(chunk))
        elif command == EEP_CMD_WRITE:
            start = 2 * word
            if start + 2 > len(self.sii):
                self.sii.extend(b"\xff" * (start + 2 - len(self.sii)))
            self.sii[start:start + 2] = m[REG_EEP_DATA:REG_EEP_DATA + 2]
        # done at once: never busy, no error bits, 8-byte reads supported
        _U16.pack_into(m, REG_EEP_CONTROL, EEP_READ_8_BYTES)

    # --- SyncManagers and FMMUs -------------------------------------------------------------
    def sync_managers(self):
        """List of ``(start, length, control, activate)`` of SM0-SM7 as programmed."""
        if self._sms is None:
            self._sms = [struct.unpack_from("<HHBxBx", self.mem, REG_SM + 8 * i)
                         for i in range(8)]
        return self._sms

    def fmmus(self):
        """Active FMMUs as ``(log_start, length, phys_start, type)``."""
        if self._fmmus is None:
            active = []
            for i in range(16):
                log_start, length, _, _, phys, _, ftype, act = struct.unpack_from(
                    "<IHBBHBBB", self.mem, REG_FMMU + 16 * i)
                if act & 1 and length:
                    active.append((log_start, length, phys, ftype))
            self._fmmus = active
        return self._fmmus

    def _sm_at(self, phys):
        for start, length, control, activate in self.sync_managers():
            if length and start <= phys < start + length:
                return start, length, control, activate
        return None

    def _pd_accessible(self, phys, write=False):
        """Process data SMs are served only when enabled and in SAFE-OP or OP (the PDI
        enables them at PRE-OP -> SAFE-OP); the outputs' SM only in OP (in SAFE-OP the
        application keeps it deactivated, as slave stacks do: a write is not taken and not
        counted, so a slave that fell back to SAFE-OP shows in the working counter)."""
        sm = self._sm_at(phys)
        if sm is None:
            return True
        if write:
            return bool(sm[3] & 1) and self.al_state == OP
        return bool(sm[3] & 1) and self.al_state in (SAFEOP, OP)

    def logical(self, cmd, address, data):
        """Serve one LRD/LWR/LRW datagram (``data`` = memoryview of its data, modified in
        place).  Returns ``(read_hit, write_hit)``: writes come first, from the bytes as
        they arrived at this slave, then reads."""
        n = len(data)
        end = address + n
        read_hit = write_hit = False
        fmmus = self.fmmus()
        if not fmmus:
            return False, False
        if cmd != F.LRD:
            for log_start, length, phys, ftype in fmmus:
                if not ftype & 2:
                    continue
                lo = address if address > log_start else log_start
                hi = min(end, log_start + length)
                if lo >= hi:
                    continue
                p = phys + lo - log_start
                if not self._pd_accessible(p, write=True):
                    continue
                self.mem[p:p + hi - lo] = data[lo - address:hi - address]
                write_hit = True
                sm = self._sm_at(p)
                if sm is not None and sm[2] & SM_CONTROL_WATCHDOG:
                    self._wd_last = self.clock()      # (also when the outputs arrived)
                    self.outputs_fresh = True
        if cmd != F.LWR:
            for log_start, length, phys, ftype in fmmus:
                if not ftype & 1:
                    continue
                lo = address if address > log_start else log_start
                hi = min(end, log_start + length)
                if lo >= hi:
                    continue
                p = phys + lo - log_start
                if not self._pd_accessible(p):
                    continue
                data[lo - address:hi - address] = self.mem[p:p + hi - lo]
                read_hit = True
        return read_hit, write_hit

    # --- AL state machine ---------------------------------------------------------------------
    def _write_al_status(self):
        _U16.pack_into(self.mem, REG_AL_STATUS,
                       self.al_state | (AL_ERROR_FLAG if self.al_error else 0))
        _U16.pack_into(self.mem, REG_AL_CODE, self.al_code)

    def _event(self, text):
        if self.on_event is not None:
            self.on_event(self, text)

    def al_control(self, value):
        """Handle a write of ``value`` to AL control 0x0120.

        Policy (as SOEM's requests need it): the ack bit clears the error flag and code; with
        the error flag set and no ack, requests for a higher state are ignored; INIT ->
        PRE-OP -> SAFE-OP -> OP, any step down and the current state are accepted; any
        other request keeps the state and sets the error flag with code 0x0011 (0x0012
        unknown state, 0x0013 BOOT).  PRE-OP -> SAFE-OP checks SM2/SM3 (0x001D/0x001E).
        """
        value &= 0x1F
        self.last_al_request = value
        self.al_request_count += 1
        if self.on_al_request is not None:
            self.on_al_request(self, value)
        requested = value & 0x0F
        if value & AL_ERROR_FLAG:
            self.al_error = False
            self.al_code = AL_CODE_NONE
        current = self.al_state
        if requested not in _RANK:
            self._al_fail(current, AL_CODE_UNKNOWN_STATE)
            return
        if requested == current:
            self._write_al_status()
            return
        if self.al_error and _RANK[requested] > _RANK[current]:
            self._write_al_status()      # error not acknowledged: stay
            return
        if requested == BOOT:
            self._al_fail(current, AL_CODE_BOOTSTRAP_NOT_SUPPORTED)
            return
        if not (_RANK[requested] < _RANK[current] or (current, requested) in _UP):
            self._al_fail(current, AL_CODE_INVALID_STATE_CHANGE)
            return
        code = self.check_transition(current, requested)
        if code:
            self._al_fail(current, code)
            return
        self._set_state(requested)

    def check_transition(self, current, requested):
        """AL status code refusing ``current -> requested`` (0: allowed). The ESC checks the
        mailbox SMs at INIT -> PRE-OP and the process-data SMs at PRE-OP -> SAFE-OP; an
        application adds its own (a drive that needs SYNC0 for OP)."""
        if (current, requested) == (INIT, PREOP) and self.mailbox is not None:
            return self._check_mailbox_config()
        if (current, requested) == (PREOP, SAFEOP):
            return self.check_process_data_config()
        return AL_CODE_NONE

    def _set_state(self, new):
        old = self.al_state
        self.al_state = new
        if new == OP:
            self._wd_last = self.clock()
            _U16.pack_into(self.mem, REG_WD_STATUS, 0x0001)
        if new == INIT and self.mailbox is not None:
            self.mailbox.clear()
            self.mem[REG_SM0_STATUS] = 0
            self.mem[REG_SM1_STATUS] = 0
        elif old == INIT and self.mailbox is not None:
            self._mailbox_refresh()          # what the application posted meanwhile
        self._write_al_status()
        if old != new:
            self._event("AL %s -> %s" % (AL_STATE_NAMES[old], AL_STATE_NAMES[new]))
            self.on_state_change(old, new)

    def _al_fail(self, state, code):
        self.al_error = True
        self.al_code = code
        if state != self.al_state:
            self._set_state(state)
        self._write_al_status()
        self._event("AL error 0x%04X in %s" % (code, AL_STATE_NAMES[self.al_state]))

    def inject_al_error(self, code, state=None):
        """Slave-side AL error: drop to ``state`` (default: SAFE-OP if higher) with the
        error flag and ``code``."""
        if state is None:
            state = SAFEOP if _RANK[self.al_state] > _RANK[SAFEOP] else self.al_state
        self._al_fail(state, code)

    def expected_sync_managers(self):
        """``{sm: (start, bytes, is_output)}`` the PDO assignment requires."""
        bits = {}
        outputs = {}
        for pdo in self.sii_spec.rx_pdos:
            bits[pdo.sm] = bits.get(pdo.sm, 0) + pdo.bits
            outputs[pdo.sm] = True
        for pdo in self.sii_spec.tx_pdos:
            bits[pdo.sm] = bits.get(pdo.sm, 0) + pdo.bits
            outputs.setdefault(pdo.sm, False)
        specs = self.sii_spec.sync_managers
        return {sm: (specs[sm].start, (b + 7) // 8, outputs[sm]) for sm, b in bits.items()}

    def check_process_data_config(self):
        """AL code for a bad SM2/SM3 set-up at PRE-OP -> SAFE-OP (0 when fine)."""
        programmed = self.sync_managers()
        for sm, (start, nbytes, is_output) in sorted(self.expected_sync_managers().items()):
            if nbytes == 0:
                continue
            p_start, p_len, _, p_act = programmed[sm]
            if p_start != start or p_len != nbytes or not p_act & 1:
                self._event("SM%d programmed start 0x%04X length %d enable %d, expected "
                            "0x%04X/%d/1" % (sm, p_start, p_len, p_act & 1, start, nbytes))
                return AL_CODE_INVALID_OUTPUT_CONFIG if is_output else AL_CODE_INVALID_INPUT_CONFIG
        return AL_CODE_NONE

    # --- process-data watchdog --------------------------------------------------------------------
    def watchdog_time(self):
        """Process-data watchdog time [s] from 0x0400/0x0420 (0: disabled)."""
        divider = _U16.unpack_from(self.mem, REG_WD_DIVIDER)[0]
        ticks = _U16.unpack_from(self.mem, REG_WD_TIME_PD)[0]
        return 40e-9 * (divider + 2) * ticks

    def _watchdog_armed(self):
        for start, length, control, activate in self.sync_managers():
            if length and activate & 1 and control & SM_CONTROL_WATCHDOG:
                return True
        return False

    def watchdog_deadline(self):
        """Monotonic time at which the watchdog expires, or None when not running."""
        if self.al_state != OP:
            return None
        wd = self.watchdog_time()
        if wd <= 0.0 or not self._watchdog_armed():
            return None
        return self._wd_last + wd

    def check_watchdog(self, now):
        """Expire the watchdog if its deadline has passed: SAFE-OP + error 0x001B, outputs
        safe (:meth:`on_watchdog_expired`)."""
        deadline = self.watchdog_deadline()
        if deadline is None or now < deadline:
            return False
        self.watchdog_expiries += 1
        self.last_watchdog_gap = now - self._wd_last
        _U16.pack_into(self.mem, REG_WD_STATUS, 0x0000)
        count = self.mem[REG_WD_COUNTER]
        self.mem[REG_WD_COUNTER] = min(count + 1, 0xFF)
        self._event("process-data watchdog expired after %.1f ms" % (1e3 * self.last_watchdog_gap))
        self.on_watchdog_expired()
        self._al_fail(SAFEOP, AL_CODE_SM_WATCHDOG)
        return True

    # --- application hooks -----------------------------------------------------------------------
    def on_state_change(self, old, new):
        """Called after every AL state change."""

    def on_watchdog_expired(self):
        """Called when the process-data watchdog expires (before the AL drop)."""

    def process_outputs(self):
        """Called once after each process-data frame (the application reads outputs)."""

    def update_inputs(self, physics):
        """Called once after each physics step (the application writes inputs)."""

    def tick(self, now):
        """Called from the server loop between frames."""

    def status(self):
        """JSON-able state for the side channel."""
        sms = self.sync_managers()
        return {
            "name": self.name,
            "kind": self.kind,
            "position": self.position,
            "station_address": self.station_address,
            "identity": self.identity.as_dict(),
            "al_state": self.al_state,
            "al_state_name": AL_STATE_NAMES.get(self.al_state, "?"),
            "al_error": self.al_error,
            "al_status_code": self.al_code,
            "last_al_request": self.last_al_request,
            "al_request_count": self.al_request_count,
            "watchdog_time": self.watchdog_time(),
            "watchdog_expiries": self.watchdog_expiries,
            "last_watchdog_gap": self.last_watchdog_gap,
            "sync_managers": [list(s) for s in sms],
            "fmmus": [list(f) for f in self.fmmus()],
        }
