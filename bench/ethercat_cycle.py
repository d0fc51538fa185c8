#!/usr/bin/env python3
"""EtherCAT cycle benchmark: pysoem (SOEM) master against the software slave emulator
on a veth pair, with absolute deadlines.

    sudo -E python bench/ethercat_cycle.py [--duration 20] [--rate 2000] [--realtime PRIO]
        [--bring-ups 5] [--only soem|master] [--quick]      (1 s: a smoke run)

Creates its own network namespace and veth pair (test/ethercat/harness.py), starts the
emulator (wrist drive, pinch drive, pressure terminal) in its own process, brings the
bus to OP, enables both drives in cyclic synchronous torque mode with a small torque,
then runs ``send_processdata`` / ``receive_processdata`` once per period.  Cycle k starts
at ``t0 + k T``; a late cycle does not shift later deadlines (a cycle that starts more
than one period late is counted as an overrun and its deadline skipped).

Prints: cycles and achieved rate, period p50/p99/max and period jitter |period - T|
p50/p99, send->receive round trip p50/p99/max, working-counter errors (wkc !=
expected_wkc, with a histogram), overruns, and the emulator's own counters.

Then the project's master (``EthercatBackend`` with ``PlantCycle``, as hardware_node runs it)
on a line of two CoE drives, an EK1100-like coupler and the EL3102-like terminal:

* **INIT -> OP**: open, configure (config_init, identities, SII, CoE configuration of each
  drive at PRE-OP -- start-up SDOs, mapping written and read back, 0x6060 = 10, scaling --
  config_map, SAFE-OP) and activate (OP), median of ``--bring-ups`` runs, with its parts;
* **drive fault -> code**: a fault injected in each drive, the time until the latched fault
  names its 0x603F code (mapped on one drive, read over CoE on the other) and its emergency;
* **cycle CPU**: the node's cycle (read, drives, PlantCycle, write) at 2 kHz, free run (the
  baseline, measured in the same run) and with distributed clocks on both drives (SYNC0, the
  FRMW of the reference clock in every frame, the PI lock of the cycle): the thread's CPU time
  per cycle of each and their ratio, the lock's phase error and jitter, and the SYNC0 events
  the drives saw without outputs (0x1C32:0B).

Figures, not pass/fail.  Needs root (raw sockets, namespaces).
"""

import argparse
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
sys.path.insert(0, str(ROOT))

import pysoem  # noqa: E402

from ethercat.harness import EmulatorHarness  # noqa: E402
from ethercat.soem_bus import CW_ENABLE_OPERATION, SoemBus  # noqa: E402


def percentile(sorted_values, q):
    if not sorted_values:
        return float("nan")
    i = min(len(sorted_values) - 1, max(0, int(round(q / 100.0 * (len(sorted_values) - 1)))))
    return sorted_values[i]


def run(args):
    period = 1.0 / args.rate
    period_ns = int(round(1e9 / args.rate))
    timeout_us = args.receive_timeout_us or int(period * 1e6)
    harness = EmulatorHarness(realtime=args.realtime)
    harness.start()
    master = pysoem.Master()
    try:
        if args.realtime:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
        master.open(harness.master_interface)
        bus = SoemBus(master)
        state = bus.bring_up()
        if state != pysoem.OP_STATE:
            print("bus did not reach OP (state 0x%02X)" % state)
            return 1
        for i in bus.drives:
            bus.enable(i, 20)
            bus.set_drive(i, CW_ENABLE_OPERATION, 20)
        expected = master.expected_wkc
        status0 = harness.client.status()
        n = int(round(args.duration * args.rate))
        starts = [0] * n
        rtts = [0] * n
        wkcs = [0] * n
        send, receive = master.send_processdata, master.receive_processdata
        mono = time.monotonic_ns
        sleep = time.sleep
        spin_ns = int(args.spin_us * 1000)
        overruns = 0
        t0 = mono() + 10 * period_ns
        deadline = t0
        for k in range(n):
            now = mono()
            wait = deadline - now - spin_ns
            if wait > 0:
                sleep(wait * 1e-9)
            while mono() < deadline:
                pass
            start = mono()
            send(release_gil=True)
            w = receive(timeout_us, release_gil=True)
            end = mono()
            starts[k] = start
            rtts[k] = end - start
            wkcs[k] = w
            deadline += period_ns
            if end > deadline + period_ns:            # more than a period behind: skip
                missed = (end - deadline) // period_ns
                overruns += 1
                deadline += missed * period_ns
        status1 = harness.client.status()
        for cw in (0x06, 0x00):
            for i in bus.drives:
                bus.set_drive(i, cw, 0)
            bus.cycle(3)
        bus.request_state(pysoem.INIT_STATE)
    finally:
        master.close()
        harness.stop()

    elapsed = (starts[-1] - starts[0]) * 1e-9
    periods = sorted((starts[i + 1] - starts[i]) * 1e-3 for i in range(n - 1))
    jitter = sorted(abs(p - period * 1e6) for p in periods)
    rtt = sorted(r * 1e-3 for r in rtts)
    errors = [w for w in wkcs if w != expected]
    hist = {}
    for w in errors:
        hist[w] = hist.get(w, 0) + 1
    c0, c1 = status0["counters"], status1["counters"]
    print("EtherCAT cycle benchmark: pysoem %s master -> emulator on veth %s (%s)"
          % (pysoem.__version__, harness.master_interface,
             "SCHED_FIFO %d" % args.realtime if args.realtime else "normal scheduling"))
    print("  target            %8.0f Hz   (period %.1f us, receive timeout %d us, spin %d us)"
          % (args.rate, period * 1e6, timeout_us, args.spin_us))
    print("  cycles            %8d      over %.2f s" % (n, elapsed))
    print("  achieved rate     %8.1f Hz" % ((n - 1) / elapsed))
    print("  period  p50/p99/max   %7.1f / %7.1f / %7.1f us"
          % (percentile(periods, 50), percentile(periods, 99), periods[-1]))
    print("  jitter |T-T0| p50/p99 %7.1f / %7.1f us" % (percentile(jitter, 50), percentile(jitter, 99)))
    print("  round trip p50/p99/max %6.1f / %7.1f / %7.1f us"
          % (percentile(rtt, 50), percentile(rtt, 99), rtt[-1]))
    print("  wkc errors        %8d      (expected wkc %d; %s)"
          % (len(errors), expected, ", ".join("wkc %d: %d" % kv for kv in sorted(hist.items()))
             or "none"))
    print("  overruns          %8d      (cycles ending > 1 period late; deadlines skipped)" % overruns)
    print("  emulator          %8d process frames served, %d physics steps, %d watchdog expiries"
          % (c1["process_frames"] - c0["process_frames"],
             status1["physics_steps"] - status0["physics_steps"],
             sum(s["watchdog_expiries"] for s in status1["slaves"])))
    print("  load average      %s" % " ".join("%.2f" % x for x in os.getloadavg()))
    return 0


def fault_latency(harness, backend, plant, channels, period):
    """A drive fault injected on each drive (c0: 0x603F mapped, c1: not): how long until
    the latched fault names its code, and its emergency [ms]; then reset."""
    drive = {"c0": "drive0", "c1": "drive1"}
    code = {"c0": 0x2310, "c1": 0x3210}
    for ch in channels:
        harness.client.drive_fault(drive[ch], code=code[ch])
    t0 = time.monotonic()
    seen, cycles = {}, 0
    from seaforce_ros.core.backend import PlantSample
    while len(seen) < 3 and time.monotonic() - t0 < 1.0:
        sample = PlantSample(2)
        link = backend.read(sample)
        if link.received and plant.exchange(link.counter, link.expected):
            plant.command(list(channels), [0.0, 0.0], plant.state_published())
        backend.write(plant.step(time.monotonic(), sample.velocity, backend.drives()))
        cycles += 1
        faults = plant.latched_faults()
        now = 1e3 * (time.monotonic() - t0)
        for ch in channels:
            text = next((f for f in faults if f.startswith(ch + ":")), "")
            if "0x%04X" % code[ch] in text.split("emergency")[0] and ch not in seen:
                seen[ch] = (now, cycles)
            if "emergency 0x%04X" % code[ch] in text and ch == "c1" and "em" not in seen:
                seen["em"] = (now, cycles)
        time.sleep(period)
    plant.request_reset()
    for _ in range(200):
        sample = PlantSample(2)
        link = backend.read(sample)
        if link.received and plant.exchange(link.counter, link.expected):
            plant.command(list(channels), [0.0, 0.0], plant.state_published())
        backend.write(plant.step(time.monotonic(), sample.velocity, backend.drives()))
        time.sleep(period)
    nan = (float("nan"), 0)
    return (seen.get("c0", nan)[0], seen.get("c0", nan)[1], seen.get("c1", nan)[0],
            seen.get("em", nan)[0])


def master_figures(args):
    """INIT -> OP and the cycle's CPU with and without DC, through the project's master."""
    import statistics
    from ethercat.lines import bus_yaml, line
    from seaforce_ros.core.backend import PlantSample
    from seaforce_ros.core.plant_cycle import PlantCycle, PlantLimits
    from seaforce_ros.ethercat.backend import EthercatBackend
    from seaforce_ros.ethercat.bus_config import BusConfig

    period = 1.0 / args.rate
    emulator = line("standard", "standard", cycle_time=period)
    # the emulator stands for the slaves' hardware: real-time where the host allows it
    from ethercat.fixtures import EMULATOR_PRIORITY, realtime_allowed
    priority = args.realtime + 10 if args.realtime else (
        EMULATOR_PRIORITY if realtime_allowed() else 0)
    harness = EmulatorHarness(emulator, realtime=priority)
    harness.start()
    plain = bus_yaml(emulator)
    # the second drive without 0x603F in its inputs: its code is read over CoE on a fault
    plain["slaves"][1]["inputs"] = [e for e in plain["slaves"][1]["inputs"]
                                    if e[0] != "error_code"]
    with_dc = bus_yaml(emulator, **{d: {"dc": {"assign_activate": 0x0300},
                                        "sdo": [[0x10F1, 2, "u16", 1000]]}
                                    for d in ("drive0", "drive1")})
    channels = ("c0", "c1")
    rows = {}
    try:
        if args.realtime:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
        bring_ups = []
        for _ in range(args.bring_ups):
            config = BusConfig.from_dict(plain)
            backend = EthercatBackend(config, channels, harness.master_interface, period,
                                      drive_watchdog=2.0)
            t0 = time.monotonic()
            backend.open()
            backend.configure()
            t1 = time.monotonic()
            backend.activate()
            t2 = time.monotonic()
            timings = dict(backend.bus.timings)
            backend.close()
            bring_ups.append((t2 - t0, timings.get("init", 0.0), timings.get("map", 0.0),
                              t1 - t0, t2 - t1))
        # the two alternate (not in --quick: free run, DC, DC, free run): the host's load
        # drifts over a run, and the one run first after a bring-up may cost more: each
        # runs first once
        pair = (("free run", plain), ("DC", with_dc))
        for name, yaml_dict in pair if args.quick else pair + pair[::-1]:
            config = BusConfig.from_dict(yaml_dict)
            backend = EthercatBackend(config, channels, harness.master_interface, period,
                                      drive_watchdog=2.0)
            backend.open()
            backend.configure()
            plant = PlantCycle(channels, period, PlantLimits(command_timeout=0.5),
                               units_per_nm=backend.units_per_nm)
            backend.activate()
            before = harness.client.status()["slaves"]
            n = int(round(args.duration * args.rate))
            cpu = [0] * n
            mono, tt = time.monotonic, time.thread_time_ns
            deadline = mono()
            for k in range(n):
                wait = deadline - mono()
                if wait > 0:
                    time.sleep(wait)
                c0 = tt()
                sample = PlantSample(2)
                link = backend.read(sample)
                if link.received and plant.exchange(link.counter, link.expected):
                    plant.command(list(channels), [0.02, -0.02], plant.state_published())
                backend.write(plant.step(mono(), sample.velocity, backend.drives()))
                deadline += period + backend.clock_correction()
                cpu[k] = tt() - c0
                if mono() > deadline + period:
                    deadline = mono()
            if name == "free run" and "fault" not in rows:
                rows["fault"] = fault_latency(harness, backend, plant, channels, period)
            lock = backend._lock
            after = harness.client.status()["slaves"]
            missed = sum(a["sm_event_missed"] - b["sm_event_missed"]
                         for a, b in zip(after[:2], before[:2]))
            old = rows.get(name)
            cpu_all = (old[8] if old else []) + cpu
            rows[name] = (statistics.median(cpu_all) * 1e-3, statistics.mean(cpu_all) * 1e-3,
                          lock.mean_ns * 1e-3, lock.jitter_ns * 1e-3,
                          missed + (old[4] if old else 0), lock.locked,
                          backend.wkc_errors_total + (old[6] if old else 0),
                          n + (old[7] if old else 0), cpu_all)
            try:
                backend.deactivate()
            except Exception as exc:           # a figure too: what went wrong
                print("  %s: %s" % (name, exc))
            backend.close()
    finally:
        harness.stop()
    med = [statistics.median(col) * 1e3 for col in zip(*bring_ups)]
    print("project master on a line of 2 CoE drives, a coupler and an analog terminal:")
    print("  INIT -> OP        %8.0f ms   median of %d (config_init + identities %.0f, "
          "SII + CoE + config_map %.0f, configure %.0f, activate to OP %.0f ms)"
          % (med[0], len(bring_ups), med[1], med[2], med[3], med[4]))
    base = rows["free run"][0]
    fault = rows.pop("fault")
    print("  drive fault -> its code in the latched fault: 0x603F mapped %.1f ms (%d cycles), "
          "read over CoE %.1f ms; its emergency %.1f ms" % fault)
    for name, (cpu_med, cpu_mean, phase, jitter, missed, locked, wkc, n, _) in rows.items():
        dc = ("" if name == "free run" else
              "; lock %s, phase %+.1f us, jitter %.1f us, SYNC0 without outputs %d"
              % ("locked" if locked else "NOT locked", phase, jitter, missed))
        print("  cycle CPU %-8s %6.1f us median, %6.1f mean (ratio %.2f to free run); "
              "%d cycles, wkc errors %d%s" % (name, cpu_med, cpu_mean, cpu_med / base, n, wkc, dc))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=20.0, help="seconds (default 20)")
    parser.add_argument("--rate", type=float, default=2000.0, help="Hz (default 2000)")
    parser.add_argument("--receive-timeout-us", type=int, default=0,
                        help="receive_processdata timeout (default: one period)")
    parser.add_argument("--spin-us", type=float, default=0.0,
                        help="busy-wait the last N us before each deadline (default 0)")
    parser.add_argument("--realtime", type=int, default=0, metavar="PRIO",
                        help="SCHED_FIFO priority for master and emulator (default 0: off)")
    parser.add_argument("--bring-ups", type=int, default=5,
                        help="INIT -> OP runs of the project's master (default 5)")
    parser.add_argument("--only", choices=("soem", "master"),
                        help="only the bare pysoem cycle, or only the project's master")
    parser.add_argument("--quick", action="store_true", help="smoke run: 1 s")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.bring_ups = 1.0, 1
    code = 0 if args.only == "master" else run(args)
    if args.only != "soem" and code == 0:
        master_figures(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
