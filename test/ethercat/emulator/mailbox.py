"""The mailbox of an emulated slave: SM0 (master -> slave) and SM1 (slave -> master).

ETG.1000.4/.6 and what SOEM does with them (``ecx_mbxsend``, ``ecx_mbxreceive``):

* the master waits until SM0's status (0x0805) shows bit 3 (mailbox full) clear, then writes
  the whole SM0 buffer; the write of its last byte fills it. The slave takes the message at
  once (the status bit is clear again by the time the master looks) and queues its answer;
* the master polls SM1's status (0x080D) until bit 3 is set, then reads the whole SM1 buffer;
  reading its last byte empties it, and the next queued message (an emergency, say) moves in;
* a message is a 6-byte header (length u16 of what follows, address u16, channel/priority u8,
  type u8: low nibble 3 = CoE, bits 4-6 the counter 1..7) and the protocol's bytes. A request
  with the same non-zero counter as the previous one is a retry: answered again, not executed
  twice;
* a lost read is repeated by the master toggling the repeat bit (0x080E bit 1); the slave puts
  its last message back and acknowledges in 0x080F bit 1;
* an unsupported protocol is answered with a mailbox error (type 0, service 1, detail 2).
"""

import struct
from collections import deque

MBX_ERROR, MBX_COE = 0x00, 0x03
MBX_ERR_UNSUPPORTED_PROTOCOL = 0x0002
MBX_ERR_INVALID_HEADER = 0x0005
MBX_ERR_SIZE_TOO_SHORT = 0x0006

SM_STATUS_FULL = 0x08
HEADER = struct.Struct("<HHBB")


class Mailbox:
    """Mailbox endpoint of one slave.

    Parameters
    ----------
    coe : callable
        ``coe(payload) -> reply payload or None`` for CoE messages (the SDO server).
    """

    def __init__(self, coe):
        self.coe = coe
        self.queue = deque()          # messages waiting for SM1 (header included)
        self.in_sm1 = None            # the message in SM1 now (None: empty)
        self.last = None              # the last message read (for a repeat)
        self._last_counter = 0
        self._last_reply = None
        self.received = 0
        self.sent = 0
        self.counter = 0              # counter of the slave's own messages

    def _next_counter(self):
        self.counter = self.counter % 7 + 1
        return self.counter

    def message(self, mtype, payload):
        """A whole message of ``mtype`` with the slave's next counter."""
        return HEADER.pack(len(payload), 0, 0, mtype | (self._next_counter() << 4)) + payload

    def post(self, mtype, payload):
        """Queue a message the slave sends on its own (an emergency)."""
        self.queue.append(self.message(mtype, payload))

    def on_request(self, raw):
        """The master filled SM0 with ``raw`` (the whole buffer)."""
        self.received += 1
        if len(raw) < HEADER.size:
            return
        length, _, _, mtype = HEADER.unpack_from(raw)
        counter = (mtype >> 4) & 0x07
        protocol = mtype & 0x0F
        body = bytes(raw[HEADER.size:HEADER.size + length])
        if counter and counter == self._last_counter and self._last_reply is not None:
            self.queue.append(self._last_reply)        # a retry: the same answer again
            return
        self._last_counter = counter
        if length > len(raw) - HEADER.size:
            reply = self.message(MBX_ERROR, struct.pack("<HH", 0x01, MBX_ERR_INVALID_HEADER))
        elif protocol == MBX_COE:
            answer = self.coe(body)
            reply = None if answer is None else self.message(MBX_COE, answer)
        else:
            reply = self.message(MBX_ERROR, struct.pack("<HH", 0x01,
                                                        MBX_ERR_UNSUPPORTED_PROTOCOL))
        self._last_reply = reply
        if reply is not None:
            self.queue.append(reply)

    def take(self):
        """The next message for SM1 (None: nothing to send)."""
        if self.in_sm1 is None and self.queue:
            self.in_sm1 = self.queue.popleft()
        return self.in_sm1

    def read_done(self):
        """The master read the whole SM1 buffer: it is empty again."""
        if self.in_sm1 is not None:
            self.last = self.in_sm1
            self.sent += 1
        self.in_sm1 = None

    def repeat(self):
        """The master lost the last read: put that message back."""
        if self.in_sm1 is None and self.last is not None:
            self.in_sm1 = self.last

    def clear(self):
        """Back to INIT: nothing queued."""
        self.queue.clear()
        self.in_sm1 = None
        self.last = None
        self._last_counter = 0
        self._last_reply = None
