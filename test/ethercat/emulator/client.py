"""Client of the emulator's control side channel (a UNIX stream socket, JSON lines).

Every method sends one request and returns the ``result`` of the reply, or raises
:class:`EmulatorCommandError` with the emulator's message.
"""

import json
import socket


class EmulatorCommandError(RuntimeError):
    """The emulator rejected a side-channel command."""


class EmulatorClient:
    """Connection to one emulator's control socket.

    Parameters
    ----------
    path : str
        Control socket path.
    timeout : float > 0
        Socket timeout [s] of each request.
    """

    def __init__(self, path, timeout=5.0):
        self.path = str(path)
        self.timeout = timeout
        self._sock = None
        self._buf = b""

    def connect(self):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        sock.connect(self.path)
        self._sock = sock
        self._buf = b""
        return self

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self):
        return self if self._sock is not None else self.connect()

    def __exit__(self, *exc):
        self.close()

    def request(self, cmd, **args):
        if self._sock is None:
            self.connect()
        self._sock.sendall((json.dumps(dict(args, cmd=cmd)) + "\n").encode())
        while b"\n" not in self._buf:
            chunk = self._sock.recv(1 << 20)
            if not chunk:
                self.close()
                raise ConnectionError("emulator closed the control socket")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        reply = json.loads(line)
        if not reply.get("ok"):
            raise EmulatorCommandError(reply.get("error", "unknown error"))
        return reply.get("result")

    # --- queries ---------------------------------------------------------------------------
    def ping(self):
        """``{"pid", "interface", "control", "slaves"}``."""
        return self.request("ping")

    def status(self):
        """Whole bus: ``slaves`` (list of slave status dicts in bus order), ``channels``
        (physics per channel), ``counters``, ``physics_steps``, ``last_process_wkc``..."""
        return self.request("status")

    def slave(self, slave):
        """Status dict of one slave (name or 0-based position)."""
        return self.request("slave", slave=slave)

    def al_state(self, slave):
        """AL state (1, 2, 4, 8) of one slave."""
        return self.slave(slave)["al_state"]

    def cia402_state(self, slave):
        """CiA 402 state name of a drive, e.g. ``operation_enabled``."""
        return self.slave(slave)["cia402_state"]

    def torque_applied(self, slave):
        """True when the drive applies a non-zero torque this cycle."""
        return self.slave(slave)["torque_applied"]

    def channel(self, name):
        """Physics of one channel: true states, F_p, F_e, X_e, environment, steps."""
        return self.status()["channels"][name]

    def al_history(self):
        """Every AL control write: ``{"time", "slave", "position", "value", "state", "ack"}``."""
        return self.request("al_history")

    def last_al_request(self, slave):
        """Last value written to AL control 0x0120 of ``slave`` (None: never)."""
        return self.slave(slave)["last_al_request"]

    def events(self):
        """State changes, AL errors, watchdog expiries: ``{"time", "slave", "text"}``."""
        return self.request("events")

    def clear_history(self):
        return self.request("clear_history")

    def start_trace(self, decimation=1, max_samples=100000):
        """Start recording the true plant states of every channel at every
        ``decimation``-th physics step (restarts a running trace)."""
        return self.request("start_trace", decimation=decimation, max_samples=max_samples)

    def trace(self, stop=True):
        """``{channel: {field: [values]}}``: fields time [s], torque [N m],
        motor_position, endpoint_position [rad], motor_velocity, endpoint_velocity
        [rad/s], pressure_force, external_force [N m].  Fetch it after the measurement: a
        long trace stalls the emulator while it is sent."""
        return self.request("trace", stop=stop)

    # --- fault injection ---------------------------------------------------------------------
    def silent(self, on=True):
        """Cable pull: no frame reaches a slave or gets an answer while on."""
        return self.request("silent", on=on)

    def drop(self, count=1, direction="request", frames="process"):
        """Lose the next ``count`` frames (``process``: only those with process data)."""
        return self.request("drop", count=count, direction=direction, frames=frames)

    def corrupt(self, count=1, how="wkc", frames="process"):
        """Corrupt the next ``count`` replies: ``wkc`` (0), ``data`` (inverted), ``index``."""
        return self.request("corrupt", count=count, how=how, frames=frames)

    def set_identity(self, slave, **fields):
        """Change vendor_id / product_code / revision / serial in the SII (next config_init)."""
        return self.request("set_identity", slave=slave, **fields)

    def drive_fault(self, slave, code=0x5400, latched=False, reason="injected"):
        """Fault a drive (statusword bit 3); ``latched``: fault reset refused until cleared."""
        return self.request("drive_fault", slave=slave, code=code, latched=latched,
                            reason=reason)

    def clear_fault(self, slave):
        """Remove a latched fault condition (a fault reset is still needed)."""
        return self.request("clear_fault", slave=slave)

    def al_error(self, slave, code=0x0001, state=None):
        """Slave-side AL error (default: drop to SAFE-OP with the error flag)."""
        return self.request("al_error", slave=slave, code=code, state=state)

    def set_environment(self, channel, environment):
        """Install an endpoint environment, e.g. ``{"mode": "position_sine",
        "amplitude": 0.5, "frequency": 1.0}`` (None: free)."""
        return self.request("set_environment", channel=channel, environment=environment)

    def reset(self):
        """Every slave as at power-up (a fresh line of the same configuration)."""
        return self.request("reset")

    def shutdown(self):
        """Stop the emulator process."""
        return self.request("shutdown")
