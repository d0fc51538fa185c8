"""The EtherCAT master of the hardware node: pysoem (SOEM) driven from a :class:`BusConfig`.

No ROS here. :class:`EthercatBus` opens the interface (:meth:`~EthercatBus.open`), brings
the bus to SAFE-OP with every identity checked before anything is written to a drive
(:meth:`~EthercatBus.configure`), to OP and back (:meth:`~EthercatBus.request_op`,
:meth:`~EthercatBus.request_safe_op`), exchanges process data once per cycle, packs/unpacks
the configured PDO entries, and takes the bus back to INIT. The per-cycle path does no allocation beyond the
bytes objects pysoem itself returns.
"""
from __future__ import annotations

import fcntl
import socket
import struct
import time
from typing import List

from .bus_config import BusConfig, SlaveConfig
from .errors import BusError, IdentityError


_SIOCGIFFLAGS, _SIOCSIFFLAGS, IFF_PROMISC = 0x8913, 0x8914, 0x100


def interface_flags(interface: str) -> int:
    """The interface's flags (``IFF_*``, as ``ip link`` shows them); OSError if there is no
    such interface."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        request = struct.pack('16sH14x', interface.encode()[:15], 0)
        return struct.unpack('16sH14x', fcntl.ioctl(sock, _SIOCGIFFLAGS, request))[1]


def set_promiscuous(interface: str, on: bool) -> None:
    """Set or clear the interface's promiscuous flag, leaving the others as they are now."""
    flags = interface_flags(interface)
    flags = (flags | IFF_PROMISC) if on else (flags & ~IFF_PROMISC)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        fcntl.ioctl(sock, _SIOCSIFFLAGS, struct.pack('16sH14x', interface.encode()[:15], flags))


def _hex(value):
    return 'none' if value is None else f'0x{value:08X}'


class EthercatBus:
    """pysoem master for one bus configuration.

    Parameters
    ----------
    config : BusConfig
    interface : str
        Network interface the bus is on (needs CAP_NET_RAW and CAP_NET_ADMIN).
    receive_timeout_us : int
        How long ``exchange`` waits for the frame to come back [us].
    """

    def __init__(self, config: BusConfig, interface: str, receive_timeout_us: int = 400):
        self.config = config
        self.interface = interface
        self.receive_timeout_us = int(receive_timeout_us)
        self.master = None
        self._was_promiscuous = None     # the interface's flag before open(); None: not opened
        self.expected_wkc = None
        self._outputs: List[bytearray] = [bytearray(s.outputs.size) for s in config.slaves]
        self._out_offsets = [s.outputs.offsets() for s in config.slaves]
        self._in_offsets = [s.inputs.offsets() for s in config.slaves]
        self._inputs: List[bytes] = [bytes(s.inputs.size) for s in config.slaves]

    # --- bring-up ------------------------------------------------------------------------
    def open(self) -> None:
        """Open the interface (a raw socket; nothing is sent yet). Raises :class:`BusError`
        naming what to check; then nothing is left open."""
        try:
            import pysoem
        except ImportError as exc:
            raise BusError('pysoem is not installed (it has no rosdep key): '
                           '`pip install pysoem` into the Python that runs hardware_node') from exc
        self._pysoem = pysoem
        try:
            # SOEM switches the interface to promiscuous mode and never switches it back:
            # close() restores what it was
            was_promiscuous = bool(interface_flags(self.interface) & IFF_PROMISC)
        except OSError as exc:
            raise BusError(f'no network interface {self.interface!r} ({exc.strerror}); '
                           '`ip link` lists them') from None
        master = pysoem.Master()
        self._was_promiscuous = was_promiscuous
        try:
            master.open(self.interface)
        except Exception as exc:
            self.close()
            raise BusError(
                f'cannot open EtherCAT interface {self.interface!r}: {exc}. Check the name '
                '(ip link) and the capabilities: sudo setcap cap_net_raw,cap_net_admin+ep '
                '$(readlink -f $(which python3))') from exc
        self.master = master

    def configure(self) -> None:
        """Find and check every slave, map the process data, bring the bus to SAFE-OP.

        Nothing is written to a drive's outputs before every identity has been checked.
        Raises :class:`BusError` (:class:`IdentityError` for a wrong device) naming what to
        check; the bus is then left as it is for :meth:`to_init` and :meth:`close`.
        """
        pysoem, master = self._pysoem, self.master
        if master is None:
            raise BusError('the EtherCAT interface is not open')
        self.expected_wkc = None
        self._inputs = [bytes(s.inputs.size) for s in self.config.slaves]
        for out in self._outputs:
            out[:] = bytes(len(out))
        found = master.config_init()
        if found <= 0:
            raise BusError(f'no EtherCAT slave answered on {self.interface} (config_init '
                           f'returned {found}); check cabling and power')
        expected = self.config.slaves
        if found != len(expected):
            names = [master.slaves[i].name for i in range(found)]
            raise BusError(f'{found} slave(s) on the bus ({", ".join(names)}) but the '
                           f'configuration lists {len(expected)} '
                           f'({", ".join(s.name for s in expected)})')
        for position, want in enumerate(expected):
            self._check_identity(position, want, master.slaves[position])
        try:
            master.config_map()
        except Exception as exc:
            raise BusError(f'process data mapping failed: {exc}') from exc
        for position, want in enumerate(expected):
            slave = master.slaves[position]
            n_out, n_in = len(slave.output), len(slave.input)
            if n_out != want.outputs.size or n_in != want.inputs.size:
                raise BusError(
                    f'slave {position + 1} ({want.name}) maps {n_out} output / {n_in} input '
                    f'bytes but the configuration describes {want.outputs.size} / '
                    f'{want.inputs.size}: fix its outputs/inputs entries')
        if master.state_check(pysoem.SAFEOP_STATE, 50000) != pysoem.SAFEOP_STATE:
            raise BusError(f'slaves did not reach SAFE-OP: {self._states()}')
        self.expected_wkc = master.expected_wkc
        try:
            master.always_release_gil = True
        except AttributeError:
            pass

    def _states(self) -> str:
        """Every slave's AL state and status code, read from the bus now (for a message)."""
        master = self.master
        master.read_state()
        return ', '.join(f'{want.name}: 0x{master.slaves[i].state:02X} '
                         f'(AL {master.slaves[i].al_status:#06x})'
                         for i, want in enumerate(self.config.slaves))

    def set_process_data_watchdog(self, seconds: float) -> None:
        """Program every drive's SyncManager (process-data) watchdog: a drive whose outputs stop
        for this long drops its torque and faults on its own."""
        for position, want in enumerate(self.config.slaves):
            if want.kind == 'cia402_drive':
                self.master.slaves[position].set_watchdog('processdata', 1e3 * seconds)

    def _check_identity(self, position: int, want: SlaveConfig, slave) -> None:
        got = (slave.man, slave.id, slave.rev)
        mismatch = got[0] != want.vendor_id or got[1] != want.product_code or (
            want.revision is not None and got[2] != want.revision)
        if mismatch:
            raise IdentityError(
                f'slave {position + 1} ({want.name}, "{slave.name}") is not the configured '
                f'device: vendor {_hex(got[0])} product code {_hex(got[1])} revision '
                f'{_hex(got[2])}, expected vendor {_hex(want.vendor_id)} product code '
                f'{_hex(want.product_code)} revision {_hex(want.revision)}. No torque was '
                'commanded; fix the bus YAML or the cabling order.')

    def request_op(self, timeout_s: float = 2.0) -> None:
        """Request OP while exchanging process data (the outputs as they are set now), as
        SOEM needs; :class:`BusError` if the slaves do not all get there in time."""
        pysoem = self._pysoem
        master = self.master
        master.state = pysoem.OP_STATE
        master.write_state()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.exchange()
            if master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                return
            time.sleep(0.0005)
        raise BusError(f'slaves did not reach OP within {timeout_s} s: {self._states()}')

    def request_safe_op(self) -> None:
        """Bring every slave back to SAFE-OP (their outputs go to their safe state; inputs
        stay readable); :class:`BusError` if they do not all report it."""
        pysoem = self._pysoem
        master = self.master
        master.state = pysoem.SAFEOP_STATE
        master.write_state()
        if master.state_check(pysoem.SAFEOP_STATE, 50000) != pysoem.SAFEOP_STATE:
            raise BusError(f'slaves did not go back to SAFE-OP: {self._states()}')

    # --- cycle ---------------------------------------------------------------------------
    def set_output(self, slave: int, entry: str, value: int) -> None:
        offset, fmt = self._out_offsets[slave][entry]
        struct.pack_into(fmt, self._outputs[slave], offset, value)

    def get_input(self, slave: int, entry: str):
        offset, fmt = self._in_offsets[slave][entry]
        return struct.unpack_from(fmt, self._inputs[slave], offset)[0]

    def send(self) -> None:
        """Write the outputs and send one process-data frame (it comes back with the inputs,
        which :meth:`receive` reads)."""
        master = self.master
        slaves = master.slaves
        for i, data in enumerate(self._outputs):
            if data:
                slaves[i].output = bytes(data)
        master.send_processdata()

    def receive(self) -> int:
        """Receive the frame :meth:`send` sent and read its inputs; return the working
        counter (inputs are only taken from a complete frame)."""
        master = self.master
        wkc = master.receive_processdata(self.receive_timeout_us)
        if wkc == self.expected_wkc:
            slaves = master.slaves
            for i in range(len(self._inputs)):
                self._inputs[i] = slaves[i].input
        return wkc

    def exchange(self) -> int:
        """:meth:`send` then :meth:`receive` (bring-up and shut-down); returns the WKC."""
        self.send()
        return self.receive()

    # --- shut-down -----------------------------------------------------------------------
    def to_init(self) -> bool:
        """Request INIT on every slave; True when they report it."""
        if self.master is None:
            return False
        pysoem = self._pysoem
        try:
            self.master.state = pysoem.INIT_STATE
            self.master.write_state()
            return self.master.state_check(pysoem.INIT_STATE, 50000) == pysoem.INIT_STATE
        except Exception:
            return False

    def close(self) -> None:
        """Close the master (if open) and give the interface back its promiscuous flag as it
        was before :meth:`open`. Idempotent; safe on every exit path."""
        try:
            if self.master is not None:
                try:
                    self.master.close()
                finally:
                    self.master = None
        finally:
            was = self._was_promiscuous
            self._was_promiscuous = None
            if was is not None:
                try:
                    set_promiscuous(self.interface, was)
                except OSError:
                    pass  # the interface went away meanwhile: nothing to restore
