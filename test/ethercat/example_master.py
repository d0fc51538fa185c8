"""A minimal pysoem master for tests: ``python -m ethercat.example_master IFACE [WD_MS]``.

Configures the bus, goes to OP, enables every drive in CST with a small torque, prints
``READY`` and cycles at 2 kHz (``SoemBus.period``) until SIGINT/SIGTERM; then disables the
drives (shutdown, disable voltage), requests INIT for the whole bus, prints
``STOPPED <state>`` and exits 0.  It shows the shutdown sequence the hardware node
performs and lets a test check what the emulator recorded.
"""

import signal
import sys

import pysoem

from ethercat.soem_bus import (CW_DISABLE_VOLTAGE, CW_SHUTDOWN, SoemBus)


def main(interface, watchdog_ms=None, torque=100):
    stop = []
    signal.signal(signal.SIGINT, lambda *a: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    master = pysoem.Master()
    master.open(interface)
    try:
        bus = SoemBus(master)
        if bus.bring_up() != pysoem.OP_STATE:
            print("FAILED to reach OP", flush=True)
            return 1
        for i in bus.drives:
            if watchdog_ms:
                bus.slaves[i].set_watchdog("processdata", watchdog_ms)
            bus.enable(i, torque)
        print("READY", flush=True)
        while not stop:
            bus.cycle()                     # paced at bus.period (2 kHz)
        for cw in (CW_SHUTDOWN, CW_DISABLE_VOLTAGE):
            for i in bus.drives:
                bus.set_drive(i, cw, 0)
            bus.cycle(3)
        state = bus.request_state(pysoem.INIT_STATE)
        print("STOPPED %d" % state, flush=True)
        return 0
    finally:
        master.close()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], float(sys.argv[2]) if len(sys.argv) > 2 else None))
