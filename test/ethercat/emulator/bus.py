"""The emulated line of slaves: serves EtherCAT frames in chain order, steps the physics
once per process-data frame, runs the watchdogs and applies fault injection.

Frame handling (:meth:`Bus.handle`) works in place on the received Ethernet frame; the
reply is the same frame with data, ADP (auto-increment / broadcast) and WKC updated and
the source MAC set to 03:01:01:01:01:01.  WKC rules (ETG.1000.4): each
addressed slave adds 1 for a read, 1 for a write, 3 for a read-write (LRW: +1 if a read
FMMU matched, +2 if a write FMMU matched), once per slave per datagram.

After the reply is sent, :meth:`Bus.after_frame` runs the "PDI" side when the frame
carried process data: drives read their outputs, the physics advances one step, every
slave writes its inputs.
"""

import time
from collections import deque

from . import frames as F
from .esc import _U16

_ADDR = __import__("struct").Struct("<I")

FRAME_FILTERS = ("process", "all")
CORRUPTIONS = ("wkc", "data", "index")


class _Injection:
    """Pending frame faults: ``count`` frames matching ``frames`` get ``action``."""

    __slots__ = ("count", "frames", "action")

    def __init__(self, count, frames, action):
        self.count, self.frames, self.action = count, frames, action


class Bus:
    """Slaves in bus order plus the physics they share.

    Parameters
    ----------
    slaves : list of EscSlave
    physics : physics.Physics
    clock : callable
        Monotonic time [s].
    """

    def __init__(self, slaves, physics, clock=time.monotonic, history_length=1000):
        self.slaves = list(slaves)
        self.physics = physics
        self.clock = clock
        self.drives = [s for s in self.slaves if hasattr(s, "torque_command")]
        self.al_history = deque(maxlen=history_length)
        self.events = deque(maxlen=history_length)
        for i, s in enumerate(self.slaves):
            s.position = i
            s.line_length = len(self.slaves)
            s.set_link(last=(i == len(self.slaves) - 1))
            s.on_al_request = self._record_al_request
            s.on_event = self._record_event
        self.silent = False
        self._drop = []
        self._corrupt = []
        self.counters = dict(frames=0, answered=0, ignored=0, silent=0, dropped_requests=0,
                             dropped_replies=0, corrupted=0, process_frames=0,
                             malformed=0, datagrams=0)
        self.last_process_wkc = None
        self._process_pending = False
        self._t0 = clock()
        for s in self.slaves:
            s.update_inputs(physics)

    # --- records -------------------------------------------------------------------------------
    def _record_al_request(self, slave, value):
        self.al_history.append({"time": self.clock() - self._t0, "slave": slave.name,
                                "position": slave.position, "value": value,
                                "state": value & 0x0F, "ack": bool(value & 0x10)})

    def _record_event(self, slave, text):
        self.events.append({"time": self.clock() - self._t0, "slave": slave.name, "text": text})

    def slave(self, key):
        """Slave by name or 0-based bus position."""
        if isinstance(key, int) and not isinstance(key, bool):
            if 0 <= key < len(self.slaves):
                return self.slaves[key]
        else:
            for s in self.slaves:
                if s.name == key:
                    return s
        raise KeyError("no slave %r (slaves: %s)" % (key, ", ".join(s.name for s in self.slaves)))

    # --- fault injection -------------------------------------------------------------------------
    def set_silent(self, on):
        """Cable pull: frames reach no slave and get no answer while ``on``."""
        self.silent = bool(on)

    def drop(self, count, direction="request", frames="process"):
        """Lose the next ``count`` frames (``frames``: ``process`` = with LRD/LWR/LRW,
        ``all``); ``direction`` ``request`` = the slaves never see them, ``reply`` = the
        slaves process them but the answer is lost."""
        if direction not in ("request", "reply"):
            raise ValueError("direction must be 'request' or 'reply'")
        if frames not in FRAME_FILTERS:
            raise ValueError("frames must be one of %s" % (FRAME_FILTERS,))
        self._drop.append(_Injection(int(count), frames, direction))

    def corrupt(self, count, how="wkc", frames="process"):
        """Corrupt the reply of the next ``count`` frames: ``wkc`` = WKC 0 in every datagram,
        ``data`` = data bytes inverted, ``index`` = datagram index changed (SOEM cannot match
        the frame)."""
        if how not in CORRUPTIONS:
            raise ValueError("how must be one of %s" % (CORRUPTIONS,))
        if frames not in FRAME_FILTERS:
            raise ValueError("frames must be one of %s" % (FRAME_FILTERS,))
        self._corrupt.append(_Injection(int(count), frames, how))

    @staticmethod
    def _take(queue, is_process):
        for inj in queue:
            if inj.count > 0 and (inj.frames == "all" or is_process):
                inj.count -= 1
                action = inj.action
                queue[:] = [q for q in queue if q.count > 0]
                return action
        return None

    # --- frames ------------------------------------------------------------------------------------
    def handle(self, buf, nbytes):
        """Serve one received Ethernet frame in ``buf[:nbytes]`` in place.

        Returns the number of bytes to send back (0: no reply).
        """
        self.counters["frames"] += 1
        if nbytes < F.ETH_HEADER_LEN + F.FRAME_HEADER_LEN or buf[12] != 0x88 or buf[13] != 0xA4:
            self.counters["ignored"] += 1
            return 0
        fh = buf[14] | (buf[15] << 8)
        if fh >> 12 != 1:
            self.counters["ignored"] += 1
            return 0
        start = F.ETH_HEADER_LEN + F.FRAME_HEADER_LEN
        end = min(nbytes, start + (fh & F.LENGTH_MASK))
        try:
            datagrams = list(F.iter_datagrams(buf, start, end))
        except F.FrameError:
            self.counters["malformed"] += 1
            return 0
        is_process = any(cmd in F.LOGICAL for _, cmd, _ in datagrams)
        if self.silent:
            self.counters["silent"] += 1
            return 0
        if self._drop and self._take_drop(is_process, "request"):
            self.counters["dropped_requests"] += 1
            return 0
        mv = memoryview(buf)
        wkc_total = 0
        for off, cmd, n in datagrams:
            wkc = self._datagram(buf, mv, off, cmd, n)
            wkc_total += wkc
        self.counters["datagrams"] += len(datagrams)
        if is_process:
            self.counters["process_frames"] += 1
            self.last_process_wkc = wkc_total
            self._process_pending = True
        if self._drop and self._take_drop(is_process, "reply"):
            self.counters["dropped_replies"] += 1
            return 0
        how = self._take(self._corrupt, is_process) if self._corrupt else None
        if how is not None:
            self.counters["corrupted"] += 1
            self._apply_corruption(buf, datagrams, how)
        elif is_process:
            for d in self.drives:       # the master receives these inputs
                d.reply_delivered()
        buf[6:12] = F.REPLY_SOURCE_MAC
        self.counters["answered"] += 1
        return nbytes

    def _take_drop(self, is_process, direction):
        for inj in self._drop:
            if inj.count > 0 and inj.action == direction and (inj.frames == "all" or is_process):
                inj.count -= 1
                self._drop = [q for q in self._drop if q.count > 0]
                return True
        return False

    @staticmethod
    def _apply_corruption(buf, datagrams, how):
        for off, cmd, n in datagrams:
            if how == "wkc":
                buf[off + 10 + n] = 0
                buf[off + 11 + n] = 0
            elif how == "data":
                for i in range(off + 10, off + 10 + n):
                    buf[i] ^= 0xFF
            elif how == "index":
                buf[off + 1] = (buf[off + 1] + 0x80) & 0xFF

    def _datagram(self, buf, mv, off, cmd, n):
        """Serve one datagram; returns the WKC it gained."""
        data = mv[off + 10: off + 10 + n]
        wkc_off = off + 10 + n
        gained = 0
        slaves = self.slaves
        if cmd in F.LOGICAL:
            address = _ADDR.unpack_from(buf, off + 2)[0]
            for s in slaves:
                r, w = s.logical(cmd, address, data)
                if cmd == F.LRW:
                    gained += (1 if r else 0) + (2 if w else 0)
                else:
                    gained += 1 if (r or w) else 0
        else:
            adp = buf[off + 2] | (buf[off + 3] << 8)
            ado = buf[off + 4] | (buf[off + 5] << 8)
            if cmd in F.CONFIGURED:
                for s in slaves:
                    if s.station_address == adp:
                        gained += self._access(s, cmd, ado, data, addressed=True)
                    elif cmd == F.FRMW:
                        gained += self._access(s, cmd, ado, data, addressed=False)
            elif cmd in F.AUTO_INCREMENT:
                for s in slaves:
                    if adp == 0:
                        gained += self._access(s, cmd, ado, data, addressed=True)
                    elif cmd == F.ARMW:
                        gained += self._access(s, cmd, ado, data, addressed=False)
                    adp = (adp + 1) & 0xFFFF
                _U16.pack_into(buf, off + 2, adp)
            elif cmd in F.BROADCAST:
                for s in slaves:
                    gained += self._access(s, cmd, ado, data, addressed=True)
                    adp = (adp + 1) & 0xFFFF
                _U16.pack_into(buf, off + 2, adp)
        if gained:
            wkc = (buf[wkc_off] | (buf[wkc_off + 1] << 8)) + gained
            _U16.pack_into(buf, wkc_off, wkc & 0xFFFF)
        return gained

    @staticmethod
    def _access(s, cmd, ado, data, addressed):
        if cmd in (F.ARMW, F.FRMW):
            if addressed:
                s.read_into(ado, data)
            else:
                s.write(ado, bytes(data))
            return 1
        if cmd in F.READS:
            s.read_into(ado, data, combine_or=(cmd == F.BRD))
            return 1
        if cmd in F.WRITES:
            s.write(ado, bytes(data))
            return 1
        if cmd in F.READ_WRITES:
            old = bytearray(len(data))
            s.read_into(ado, old)
            s.write(ado, bytes(data))
            data[:] = old
            return 3
        return 0

    def after_frame(self):
        """PDI side of a process-data frame: outputs -> physics step -> inputs."""
        if not self._process_pending:
            return
        self._process_pending = False
        for s in self.slaves:
            s.process_outputs()
        torques = {}
        for d in self.drives:
            torques[d.channel] = torques.get(d.channel, 0.0) + d.torque_command()
        self.physics.step(torques)
        for s in self.slaves:
            s.update_inputs(self.physics)

    # --- time -------------------------------------------------------------------------------------
    def poll(self, now=None):
        """Run the watchdogs and automatic transitions; returns the next deadline or None."""
        now = self.clock() if now is None else now
        nxt = None
        for s in self.slaves:
            s.check_watchdog(now)
            s.tick(now)
            d = s.watchdog_deadline()
            if d is not None and (nxt is None or d < nxt):
                nxt = d
        return nxt

    # --- inspection ----------------------------------------------------------------------------------
    def status(self):
        return {
            "slaves": [s.status() for s in self.slaves],
            "channels": self.physics.status(),
            "physics_steps": self.physics.steps,
            "cycle_time": self.physics.cycle_time,
            "silent": self.silent,
            "pending_drops": [[i.count, i.frames, i.action] for i in self._drop],
            "pending_corruptions": [[i.count, i.frames, i.action] for i in self._corrupt],
            "counters": dict(self.counters),
            "last_process_wkc": self.last_process_wkc,
        }
