"""``python -m ethercat.emulator --interface IF --control SOCKET [--config FILE]``

Runs the EtherCAT slave emulator on ``IF`` (normally the slave end of a veth pair inside
a network namespace) with the control side channel on the UNIX socket ``SOCKET``.
Without ``--config`` the default bus (wrist drive, pinch drive, pressure terminal) is
used.  Run from ``test/`` on PYTHONPATH (the harness does this).
"""

import argparse
import json
import os
import sys

from . import config as cfg
from .server import serve


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m ethercat.emulator", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--interface", help="network interface to serve")
    parser.add_argument("--control", help="path of the control UNIX socket")
    parser.add_argument("--config", help="JSON (.json) or YAML bus configuration")
    parser.add_argument("--realtime", type=int, default=0, metavar="PRIO",
                        help="run with SCHED_FIFO priority PRIO (default 0: normal)")
    parser.add_argument("--print-default-config", action="store_true",
                        help="print the default configuration as JSON and exit")
    args = parser.parse_args(argv)
    if args.print_default_config:
        print(json.dumps(cfg.default_config(), indent=2))
        return 0
    if not args.interface or not args.control:
        parser.error("--interface and --control are required")
    if args.realtime:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
    try:
        config = cfg.load(args.config) if args.config else cfg.default_config()
        bus = cfg.build(config)
    except (OSError, ValueError) as exc:
        print("emulator: bad configuration: %s" % exc, file=sys.stderr, flush=True)
        return 2
    serve(bus, args.interface, args.control, rebuild=lambda: cfg.build(config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
