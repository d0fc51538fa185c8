"""EK1100-like EtherCAT coupler: an ESC with identity and name only (no mailbox, no process
data); it passes the line on to the terminals behind it. It still counts as a slave for
SOEM (``config_init`` finds it; ``config_map`` maps nothing for it) and takes AL requests."""

from .esc import EscSlave
from .sii import Identity, SiiSpec

#: vendor 2 = Beckhoff, product code of the EK1100 (as in pysoem's basic example)
DEFAULT_IDENTITY = Identity(vendor_id=0x00000002, product_code=0x044C2C52,
                            revision=0x00120000, serial=0)


def coupler_sii_spec(identity=DEFAULT_IDENTITY, name="EK1100 EtherCAT Coupler (emulated)"):
    return SiiSpec(identity=identity, name=name, sync_managers=[], fmmus=[], group="Coupler")


class Coupler(EscSlave):
    """A coupler: nothing but an ESC on the line."""

    kind = "coupler"

    def __init__(self, name, identity=DEFAULT_IDENTITY, **kwargs):
        super().__init__(name, coupler_sii_spec(identity), **kwargs)
