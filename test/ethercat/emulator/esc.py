"""One emulated EtherCAT slave controller (ESC): register memory, AL state machine, SII
EEPROM interface, SyncManagers, FMMUs and the process-data watchdog.

The ESC is a 64 KiB byte array (registers 0x0000-0x0FFF, process RAM from 0x1000).
Datagrams read and write it; writes to a few registers have side effects:

* 0x0120 AL control -> AL state machine (:meth:`EscSlave.al_control`), every request is
  recorded (``last_al_request``, the bus's history);
* 0x0502 EEPROM control -> SII read (8 bytes into 0x0508, never busy) or write;
* 0x0600-0x06FF FMMUs and 0x0800-0x087F SyncManagers -> re-parsed on the next use.

Read-only registers (0x0000-0x000F, DL status 0x0110, AL status 0x0130-0x0135, watchdog
status 0x0440-0x0443) ignore writes.  Application behaviour (a drive, an analog terminal)
lives in subclasses: :meth:`process_outputs`, :meth:`update_inputs`,
:meth:`on_state_change`, :meth:`on_watchdog_expired`.
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
AL_CODE_SM_WATCHDOG = 0x001B
AL_CODE_INVALID_OUTPUT_CONFIG = 0x001D
AL_CODE_INVALID_INPUT_CONFIG = 0x001E

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

EEP_READ_8_BYTES = 0x0040
EEP_CMD_MASK = 0x0700
EEP_CMD_READ = 0x0100
EEP_CMD_WRITE = 0x0200

SM_CONTROL_WATCHDOG = 0x40

READ_ONLY = ((0x0000, 0x0010), (REG_DL_STATUS, REG_DL_STATUS + 2),
             (REG_AL_STATUS, REG_AL_STATUS + 6), (REG_WD_STATUS, REG_WD_STATUS + 4))

MEM_SIZE = 0x10000
_U16 = struct.Struct("<H")


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
    """

    kind = "esc"

    def __init__(self, name, sii_spec, clock=time.monotonic, block_lrw=False):
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
        m = self.mem
        m[REG_TYPE] = 0x11
        m[0x0004] = 8                  # FMMUs supported
        m[0x0005] = 8                  # SyncManagers supported
        m[0x0006] = 8                  # process RAM [KiB]
        m[REG_PORT_DESC] = 0x0F        # ports 0 and 1: MII
        _U16.pack_into(m, REG_FEATURES, 0x0000)     # no DC: SOEM's config_dc then stops
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
        chunk = self.mem[ado:end]
        if combine_or:
            for i, b in enumerate(chunk):
                data[i] |= b
        else:
            data[:end - ado] = chunk

    def write(self, ado, data):
        """Store ``data`` at ``ado`` (read-only registers keep their value) and run the
        side effects of the registers written."""
        end = min(ado + len(data), MEM_SIZE)
        if end <= ado:
            return
        saved = [(lo, bytes(self.mem[lo:hi])) for lo, hi in READ_ONLY if ado < hi and end > lo]
        self.mem[ado:end] = data[:end - ado]
        for lo, value in saved:
            self.mem[lo:lo + len(value)] = value
        if ado < 0x0900 and end > 0x0600:
            if end > REG_FMMU and ado < REG_FMMU + 0x100:
                self._fmmus = None
            if end > REG_SM and ado < REG_SM + 0x80:
                self._sms = None
        if ado <= REG_EEP_CONTROL + 1 and end > REG_EEP_CONTROL:
            self._eeprom_command()
        if ado <= REG_AL_CONTROL + 1 and end > REG_AL_CONTROL:
            self.al_control(_U16.unpack_from(self.mem, REG_AL_CONTROL)[0])

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

    def _pd_accessible(self, phys):
        """Process data SMs are served only when enabled and in SAFE-OP or OP (the PDI
        enables them at PRE-OP -> SAFE-OP)."""
        sm = self._sm_at(phys)
        if sm is None:
            return True
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
                if not self._pd_accessible(p):
                    continue
                self.mem[p:p + hi - lo] = data[lo - address:hi - address]
                write_hit = True
                sm = self._sm_at(p)
                if sm is not None and sm[2] & SM_CONTROL_WATCHDOG:
                    self._wd_last = self.clock()
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
        if (current, requested) == (PREOP, SAFEOP):
            code = self.check_process_data_config()
            if code:
                self._al_fail(current, code)
                return
        self._set_state(requested)

    def _set_state(self, new):
        old = self.al_state
        self.al_state = new
        if new == OP:
            self._wd_last = self.clock()
            _U16.pack_into(self.mem, REG_WD_STATUS, 0x0001)
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
