"""A CAN bus for several SLCAN clients on the emulated board's single SLCAN port.

The board's SLCAN line takes one client. The hub is that client and listens on a port of its own
where any number of python-can `slcan` clients (`socket://127.0.0.1:<port>`) connect: every
frame from the device goes to all of them, every frame from a client to the device and to
the other clients, as on a bus. Channel commands from clients (`O`, `C`, `S8`, ...) are
answered `\\r` locally and not passed on: the device's channel is open from its power-on.

The LinuxCNC suite also uses it to make faults: the device gone and another one on the bus
(`attach` a new upstream port after the emulator was restarted; the clients stay connected
meanwhile, as on a bus whose one node was unplugged), a client's line that breaks
(`break_clients`: its connection closed, new ones refused for a while, as a CAN adapter
that errors and comes back; `protect_current` spares the test's listener) and a device that
does not answer (`mute`: nothing from it reaches the clients for a while).
"""

from __future__ import annotations

import select
import socket
import threading
import time
from typing import List

# The component's package (installed in the venv the LinuxCNC suite runs with) has the codec.
from canopen_handwheel import slcan


class SlcanHub:
    def __init__(self, upstream_port: int, connect_timeout: float = 900) -> None:
        self.upstream_port = upstream_port
        self.connect_timeout = connect_timeout
        self.server = socket.socket()
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(8)
        self.port = self.server.getsockname()[1]
        self._stop = threading.Event()
        self._clients: List[socket.socket] = []
        self._lines = {}  # client -> its slcan.LineSplitter
        self._protected: set = set()
        self._refuse_until = 0.0
        self._mute_until = 0.0
        self._lock = threading.Lock()  # the fault settings, set from the tests' thread
        self._breaking = False
        self._attached = threading.Event()
        self._attached.set()
        self.upstream_lost = threading.Event()
        self.error: Exception = None
        self.thread = threading.Thread(target=self._run, name="slcan-hub", daemon=True)
        self.thread.start()

    # Faults ----------------------------------------------------------------------------

    def attach(self, upstream_port: int) -> None:
        """The device's SLCAN port after the old one closed (a restarted emulator)."""
        self.upstream_port = upstream_port
        self.upstream_lost.clear()
        self._attached.set()

    def protect_current(self, count: int = 1, timeout: float = 10) -> None:
        """Once `count` clients are connected, they survive `break_clients` (the test's
        listener, connected before anyone else)."""
        deadline = time.monotonic() + timeout
        while len(self._clients) < count:
            if time.monotonic() > deadline:
                raise RuntimeError(f"{len(self._clients)} of {count} clients connected")
            time.sleep(0.01)
        with self._lock:
            self._protected = set(self._clients)

    def break_clients(self, refuse_for: float) -> None:
        """Closes every unprotected client's connection and, for `refuse_for` seconds,
        closes new ones as soon as they are accepted."""
        with self._lock:
            self._refuse_until = time.monotonic() + refuse_for
            self._breaking = True

    def mute(self, seconds: float) -> None:
        """For `seconds`, frames from the device reach no client."""
        with self._lock:
            self._mute_until = time.monotonic() + seconds

    @property
    def channel(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def _connect_upstream(self) -> socket.socket:
        # Never probe the board's port with a throw-away connection: it would be its client.
        deadline = time.monotonic() + self.connect_timeout
        while not self._stop.is_set():
            try:
                s = socket.create_connection(("127.0.0.1", self.upstream_port), timeout=5)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return s
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        raise RuntimeError("stopped")

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as e:  # shown by the tests that use the hub
            self.error = e

    def _loop(self) -> None:
        while not self._stop.is_set():
            if not self._attached.wait(0.05):
                self._pump(None)  # no device: the clients still talk to each other
                continue
            up = self._connect_upstream()
            try:
                self._pump(up)
            finally:
                up.close()
            if not self._stop.is_set():
                # The device's port closed (its emulator stopped): wait for `attach`.
                self._attached.clear()
                self.upstream_lost.set()

    def _pump(self, up) -> None:
        """Moves frames until the upstream closes (or, with `up` None, for one round)."""
        from_up = slcan.LineSplitter()
        while not self._stop.is_set():
            self._apply_faults()
            waiting = [self.server] + self._clients + ([up] if up is not None else [])
            readable, _, _ = select.select(waiting, [], [], 0.05)
            for s in readable:
                if s is self.server:
                    conn, _ = self.server.accept()
                    if time.monotonic() < self._refuse_until:
                        conn.close()
                        continue
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._clients.append(conn)
                    self._lines[conn] = slcan.LineSplitter()
                elif s is up:
                    try:
                        data = up.recv(4096)
                    except OSError:
                        data = b""
                    if not data:
                        return
                    lines = from_up.feed(data)
                    if time.monotonic() < self._mute_until:
                        continue
                    for line in lines:
                        # Frames only: the device's answers (`z`) were to the clients' frames.
                        if slcan.decode(line) is not None:
                            self._send_all(line + b"\r", exclude=None)
                elif s in self._clients:
                    self._from_client(s, up)
            if up is None:
                return

    def _apply_faults(self) -> None:
        with self._lock:
            breaking, self._breaking = self._breaking, False
            protected = set(self._protected)
        if breaking:
            for c in list(self._clients):
                if c not in protected:
                    self._drop(c)

    def _from_client(self, s: socket.socket, up) -> None:
        try:
            data = s.recv(4096)
        except OSError:
            data = b""
        if not data:
            self._drop(s)
            return
        for line in self._lines[s].feed(data):
            if slcan.decode(line) is not None:
                if up is not None:
                    try:
                        up.sendall(line + b"\r")
                    except OSError:
                        pass  # the device is going; its port's closing shows next round
                self._send_all(line + b"\r", exclude=s)
            else:
                self._send(s, slcan.OK)  # a channel command, answered here

    def _send(self, s: socket.socket, data: bytes) -> None:
        try:
            s.sendall(data)
        except OSError:
            self._drop(s)

    def _send_all(self, data: bytes, exclude) -> None:
        for c in list(self._clients):
            if c is not exclude:
                self._send(c, data)

    def _drop(self, s: socket.socket) -> None:
        if s in self._clients:
            self._clients.remove(s)
            self._lines.pop(s, None)
            s.close()

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for c in list(self._clients):
            self._drop(c)
        self.server.close()
