"""2-channel 16-bit analog input terminal, EL3102-like, no mailbox.

TxPDO 0x1A00 (channel 1, objects 0x6000) and 0x1A02 (channel 2, 0x6010) on SM3 (phys
0x1180, 8 bytes, control 0x20); per channel 4 bytes:

====== ======================== =====================================================
offset entry                    meaning
====== ======================== =====================================================
0      0x60n0:01..:10 (16 bits) status: bit 0 underrange, 1 overrange, 2-3 limit 1,
                                4-5 limit 2 (always 0), 6 error (= under/overrange),
                                14 TxPDO state (0 = valid), 15 TxPDO toggle (flips
                                with every new value)
2      0x60n0:11 (INT16)        value: +-10 V = +-32767 counts, clipped
====== ======================== =====================================================

SM2 is in the SII (0x1100, control 0x24, disabled) as on the real terminal; SOEM
programs it with length 0 and enable 0.  What each channel measures is an
:class:`~.physics.AnalogSource` (default: hose pressure of a channel).
"""

import struct

from .esc import EscSlave
from .physics import ADC_FULL_SCALE_COUNTS, COUNTS_PER_VOLT
from .sii import (Identity, Pdo, PdoEntry, SiiSpec, SyncManagerSpec, DT_BIT2, DT_BOOLEAN,
                  DT_INT16, SM_TYPE_INPUTS, SM_TYPE_OUTPUTS, SM_TYPE_UNUSED)

TX_START = 0x1180
CHANNEL_FORMAT = struct.Struct("<Hh")

ST_UNDERRANGE = 0x0001
ST_OVERRANGE = 0x0002
ST_ERROR = 0x0040
ST_TXPDO_STATE = 0x4000
ST_TXPDO_TOGGLE = 0x8000

#: vendor 2 = Beckhoff; the EL3102 product code is inferred from the EL3121's, not checked.
DEFAULT_IDENTITY = Identity(vendor_id=0x00000002, product_code=0x0C1E3052,
                            revision=0x00100000, serial=1)


def _channel_pdo(n):
    base = 0x6000 + 0x10 * n
    entries = (
        PdoEntry(base, 0x01, 1, DT_BOOLEAN, "Underrange"),
        PdoEntry(base, 0x02, 1, DT_BOOLEAN, "Overrange"),
        PdoEntry(base, 0x03, 2, DT_BIT2, "Limit 1"),
        PdoEntry(base, 0x05, 2, DT_BIT2, "Limit 2"),
        PdoEntry(base, 0x07, 1, DT_BOOLEAN, "Error"),
        PdoEntry(0x0000, 0x00, 7, 0, ""),                 # gap
        PdoEntry(base, 0x0F, 1, DT_BOOLEAN, "TxPDO State"),
        PdoEntry(base, 0x10, 1, DT_BOOLEAN, "TxPDO Toggle"),
        PdoEntry(base, 0x11, 16, DT_INT16, "Value"),
    )
    return Pdo(0x1A00 + 2 * n, 3, entries, "AI Standard Channel %d" % (n + 1))


def analog_sii_spec(identity=DEFAULT_IDENTITY, name="EL3102 2Ch. Ana. Input +/-10V (emulated)"):
    sms = [SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED),
           SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED),
           SyncManagerSpec(0x1100, 0, 0x24, 0, SM_TYPE_OUTPUTS),
           SyncManagerSpec(TX_START, 0, 0x20, 1, SM_TYPE_INPUTS)]
    return SiiSpec(identity=identity, name=name, sync_managers=sms, fmmus=[2, 0xFF],
                   tx_pdos=[_channel_pdo(0), _channel_pdo(1)], group="AnaIn")


def volts_to_counts(volts):
    """ADC conversion: ``(counts, status bits)``; +-10 V = +-32767, clipped."""
    counts = int(round(volts * COUNTS_PER_VOLT))
    status = 0
    if counts > ADC_FULL_SCALE_COUNTS:
        counts, status = ADC_FULL_SCALE_COUNTS, ST_OVERRANGE | ST_ERROR
    elif counts < -ADC_FULL_SCALE_COUNTS:
        counts, status = -ADC_FULL_SCALE_COUNTS, ST_UNDERRANGE | ST_ERROR
    return counts, status


class AnalogInputTerminal(EscSlave):
    """Two channels, each an :class:`~.physics.AnalogSource` (``None``: 0 V)."""

    kind = "analog_input"

    def __init__(self, name, sources, identity=DEFAULT_IDENTITY, **kwargs):
        if len(sources) != 2:
            raise ValueError("an analog input terminal has 2 channels, got %d sources"
                             % len(sources))
        super().__init__(name, analog_sii_spec(identity), **kwargs)
        self.sources = list(sources)
        self.values = [0, 0]
        self.status_words = [0, 0]
        self.volts = [0.0, 0.0]
        self._toggle = 0

    def update_inputs(self, physics):
        self._toggle ^= ST_TXPDO_TOGGLE
        for i, src in enumerate(self.sources):
            volts = src.volts(physics) if src is not None else 0.0
            counts, status = volts_to_counts(volts)
            status |= self._toggle
            self.volts[i] = volts
            self.values[i] = counts
            self.status_words[i] = status
            CHANNEL_FORMAT.pack_into(self.mem, TX_START + 4 * i, status, counts)

    def status(self):
        st = super().status()
        st.update({
            "channels": [
                {"source": None if s is None else {"channel": s.channel, "quantity": s.quantity},
                 "volts": v, "counts": c, "status": w}
                for s, v, c, w in zip(self.sources, self.volts, self.values, self.status_words)
            ],
        })
        return st
