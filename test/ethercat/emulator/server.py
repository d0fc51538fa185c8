"""The emulator process: a raw AF_PACKET socket on the slave end of a veth pair and a
UNIX-socket control side channel, served by one single-threaded poll loop.

Per received frame: serve it (:meth:`Bus.handle`), send the reply, then run the PDI side
and the physics step (:meth:`Bus.after_frame`), so the step does not delay the reply.
Between frames the loop runs the watchdogs (:meth:`Bus.poll`), waking up at least every
``POLL_MS``.

Control protocol: one JSON object per line in each direction.  Request
``{"cmd": name, ...arguments}``; reply ``{"ok": true, "result": ...}`` or
``{"ok": false, "error": message}``.  Commands are listed in :data:`COMMANDS` and
documented in ``test/ethercat/README.md`` and :mod:`.client`.
"""

import errno
import gc
import json
import os
import select
import signal
import socket
import time

from . import frames as F

POLL_MS = 5


def _slave_arg(bus, req):
    if "slave" not in req:
        raise ValueError("argument 'slave' (name or 0-based position) is required")
    return bus.slave(req["slave"])


def _drive_arg(bus, req):
    s = _slave_arg(bus, req)
    if not hasattr(s, "inject_fault"):
        raise ValueError("slave %r is not a drive" % s.name)
    return s


class Controller:
    """Executes side-channel commands on a bus (``rebuild()``: a fresh bus of the same
    configuration, for ``reset``)."""

    def __init__(self, bus, info, rebuild=None):
        self.bus = bus
        self.info = info
        self.rebuild = rebuild
        self.stop_requested = False

    def execute(self, req):
        cmd = req.get("cmd")
        handler = getattr(self, "cmd_" + str(cmd), None)
        if handler is None:
            raise ValueError("unknown command %r (commands: %s)" % (cmd, ", ".join(COMMANDS)))
        return handler(req)

    # queries
    def cmd_ping(self, req):
        return dict(self.info, pid=os.getpid())

    def cmd_status(self, req):
        return self.bus.status()

    def cmd_slave(self, req):
        return _slave_arg(self.bus, req).status()

    def cmd_al_history(self, req):
        return list(self.bus.al_history)

    def cmd_events(self, req):
        return list(self.bus.events)

    def cmd_clear_history(self, req):
        self.bus.al_history.clear()
        self.bus.events.clear()
        return None

    # fault injection
    def cmd_silent(self, req):
        self.bus.set_silent(bool(req.get("on", True)))
        return self.bus.silent

    def cmd_drop(self, req):
        self.bus.drop(int(req.get("count", 1)), req.get("direction", "request"),
                      req.get("frames", "process"))
        return None

    def cmd_corrupt(self, req):
        self.bus.corrupt(int(req.get("count", 1)), req.get("how", "wkc"),
                         req.get("frames", "process"))
        return None

    def cmd_set_identity(self, req):
        s = _slave_arg(self.bus, req)
        fields = {k: req[k] for k in ("vendor_id", "product_code", "revision", "serial")
                  if k in req}
        s.set_identity(**fields)
        return s.identity.as_dict()

    def cmd_drive_fault(self, req):
        d = _drive_arg(self.bus, req)
        d.inject_fault(int(req.get("code", 0x5400)), str(req.get("reason", "injected")),
                       bool(req.get("latched", False)))
        return d.status()

    def cmd_clear_fault(self, req):
        d = _drive_arg(self.bus, req)
        d.clear_fault()
        return d.status()

    def cmd_al_error(self, req):
        s = _slave_arg(self.bus, req)
        s.inject_al_error(int(req.get("code", 0x0001)), req.get("state"))
        return s.status()

    def cmd_set_environment(self, req):
        ch = self.bus.physics.channel(req["channel"])
        ch.set_environment(req.get("environment"))
        return ch.status()

    def cmd_start_trace(self, req):
        self.bus.physics.start_trace(int(req.get("decimation", 1)),
                                     int(req.get("max_samples", 100000)))
        return None

    def cmd_trace(self, req):
        return self.bus.physics.trace(stop=bool(req.get("stop", False)))

    def cmd_shutdown(self, req):
        self.stop_requested = True
        return None

    def cmd_reset(self, req):
        """Every slave as at power-up (a fresh line of the same configuration): tests that
        share one emulator start each from the same state."""
        if self.rebuild is None:
            raise ValueError("this emulator was started without its configuration")
        self.bus = self.rebuild()
        return None


COMMANDS = sorted(n[4:] for n in dir(Controller) if n.startswith("cmd_"))


class _Client:
    def __init__(self, sock):
        self.sock = sock
        self.buf = b""


def serve(bus, interface, control_path, log=print, rebuild=None):
    """Serve ``bus`` on ``interface`` until SIGTERM/SIGINT or the ``shutdown`` command
    (``rebuild()``: a fresh bus, what the ``reset`` command swaps in)."""
    raw = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(F.ETHERTYPE))
    raw.bind((interface, F.ETHERTYPE))
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    raw.setblocking(False)
    try:
        os.unlink(control_path)
    except FileNotFoundError:
        pass
    ctl = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    ctl.bind(control_path)
    ctl.listen(8)
    ctl.setblocking(False)
    controller = Controller(bus, {"interface": interface, "control": control_path,
                                  "slaves": [s.name for s in bus.slaves]}, rebuild)
    stop = []

    def on_signal(signum, frame):
        stop.append(signum)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    poller = select.poll()
    poller.register(raw.fileno(), select.POLLIN)
    poller.register(ctl.fileno(), select.POLLIN)
    clients = {}
    buf = bytearray(2048)
    mv = memoryview(buf)
    raw_fd, ctl_fd = raw.fileno(), ctl.fileno()
    handle, after_frame, send, recv_into = bus.handle, bus.after_frame, raw.send, raw.recv_into
    gc.collect()
    gc.freeze()
    log("emulator ready: interface %s, control %s, slaves %s"
        % (interface, control_path, ", ".join(s.name for s in bus.slaves)), flush=True)
    try:
        while not stop and not controller.stop_requested:
            if controller.bus is not bus:             # reset: a fresh line
                bus = controller.bus
                handle, after_frame = bus.handle, bus.after_frame
            deadline = bus.poll()
            timeout = POLL_MS
            if deadline is not None:
                timeout = max(0, min(POLL_MS, int((deadline - time.monotonic()) * 1e3) + 1))
            for fd, _ in poller.poll(timeout):
                if fd == raw_fd:
                    while True:
                        try:
                            n = recv_into(buf)
                        except (BlockingIOError, InterruptedError):
                            break
                        reply = handle(buf, n)
                        if reply:
                            try:
                                send(mv[:reply])
                            except OSError as exc:
                                if exc.errno not in (errno.ENOBUFS, errno.EAGAIN, errno.ENETDOWN):
                                    raise
                        after_frame()
                elif fd == ctl_fd:
                    try:
                        conn, _ = ctl.accept()
                    except BlockingIOError:
                        continue
                    conn.setblocking(False)
                    clients[conn.fileno()] = _Client(conn)
                    poller.register(conn.fileno(), select.POLLIN)
                else:
                    _serve_client(poller, clients, fd, controller)
    finally:
        for c in clients.values():
            c.sock.close()
        ctl.close()
        raw.close()
        try:
            os.unlink(control_path)
        except FileNotFoundError:
            pass
        log("emulator stopped (%s)" % ("signal %d" % stop[0] if stop else "shutdown command"),
            flush=True)


def _serve_client(poller, clients, fd, controller):
    client = clients.get(fd)
    if client is None:
        return
    try:
        data = client.sock.recv(65536)
    except (BlockingIOError, InterruptedError):
        return
    except OSError:
        data = b""
    if not data:
        poller.unregister(fd)
        client.sock.close()
        del clients[fd]
        return
    client.buf += data
    while b"\n" in client.buf:
        line, client.buf = client.buf.split(b"\n", 1)
        if not line.strip():
            continue
        try:
            req = json.loads(line)
            if not isinstance(req, dict):
                raise ValueError("a request is a JSON object")
            reply = {"ok": True, "result": controller.execute(req)}
        except Exception as exc:      # report every failure to the client, keep serving
            reply = {"ok": False, "error": "%s: %s" % (type(exc).__name__, exc)}
        out = (json.dumps(reply) + "\n").encode()
        client.sock.setblocking(True)
        try:
            client.sock.sendall(out)
        except OSError:
            pass
        finally:
            client.sock.setblocking(False)
