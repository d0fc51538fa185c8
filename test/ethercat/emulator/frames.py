"""EtherCAT frame and datagram layout (ETG.1000.4).

All fields little-endian.  An EtherCAT frame is an Ethernet frame with EtherType 0x88A4
whose payload starts with a 2-byte frame header (bits 0-10 length, bits 12-15 type = 1),
followed by datagrams: 10-byte header (cmd, idx, ADP/ADO or 32-bit logical address,
length/flags, IRQ), data, 2-byte working counter.
"""

ETHERTYPE = 0x88A4
ETH_HEADER_LEN = 14
FRAME_HEADER_LEN = 2
DATAGRAM_HEADER_LEN = 10
WKC_LEN = 2

# command codes
NOP, APRD, APWR, APRW, FPRD, FPWR, FPRW, BRD, BWR, BRW, LRD, LWR, LRW, ARMW, FRMW = range(15)

COMMAND_NAMES = ("NOP", "APRD", "APWR", "APRW", "FPRD", "FPWR", "FPRW", "BRD", "BWR",
                 "BRW", "LRD", "LWR", "LRW", "ARMW", "FRMW")

AUTO_INCREMENT = frozenset((APRD, APWR, APRW, ARMW))
CONFIGURED = frozenset((FPRD, FPWR, FPRW, FRMW))
BROADCAST = frozenset((BRD, BWR, BRW))
LOGICAL = frozenset((LRD, LWR, LRW))
READS = frozenset((APRD, FPRD, BRD, LRD))
WRITES = frozenset((APWR, FPWR, BWR, LWR))
READ_WRITES = frozenset((APRW, FPRW, BRW, LRW))

LENGTH_MASK = 0x07FF
MORE_FOLLOWS = 0x8000

# Source MAC of a reply: SOEM sends 01:01:01:01:01:01; a real ESC sets bit 1 of the first
# byte on the way back (replies captured from real ESCs come from 03:01:01:01:01:01).
REPLY_SOURCE_MAC = bytes((0x03, 0x01, 0x01, 0x01, 0x01, 0x01))


class FrameError(ValueError):
    """A frame that is not a well-formed EtherCAT frame (ignored by the emulator)."""


def iter_datagrams(buf, start, end):
    """Yield ``(offset, cmd, data_len)`` for each datagram of the EtherCAT payload
    ``buf[start:end]`` (``start`` = first byte after the 2-byte frame header).

    Raises
    ------
    FrameError
        A datagram runs past ``end``.
    """
    off = start
    while True:
        if off + DATAGRAM_HEADER_LEN + WKC_LEN > end:
            raise FrameError("datagram header at %d runs past the frame end %d" % (off, end))
        flags = buf[off + 6] | (buf[off + 7] << 8)
        n = flags & LENGTH_MASK
        if off + DATAGRAM_HEADER_LEN + n + WKC_LEN > end:
            raise FrameError("datagram at %d (%d data bytes) runs past the frame end %d"
                             % (off, n, end))
        yield off, buf[off], n
        off += DATAGRAM_HEADER_LEN + n + WKC_LEN
        if not flags & MORE_FOLLOWS:
            return


def build_frame(datagrams, index=0):
    """Build an EtherCAT payload (frame header + datagrams) for tests.

    ``datagrams``: iterable of ``(cmd, adp, ado, data)`` (for logical commands pass the
    32-bit address as ``adp`` and ``ado=None``).  Returns a ``bytearray``.
    """
    datagrams = list(datagrams)
    body = bytearray()
    for i, (cmd, adp, ado, data) in enumerate(datagrams):
        data = bytes(data)
        more = MORE_FOLLOWS if i < len(datagrams) - 1 else 0
        body.append(cmd)
        body.append(index & 0xFF)
        if ado is None:
            body += (adp & 0xFFFFFFFF).to_bytes(4, "little")
        else:
            body += (adp & 0xFFFF).to_bytes(2, "little") + (ado & 0xFFFF).to_bytes(2, "little")
        body += (len(data) | more).to_bytes(2, "little")
        body += b"\x00\x00" + data + b"\x00\x00"
    return bytearray((len(body) | 0x1000).to_bytes(2, "little")) + body
