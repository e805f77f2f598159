"""A CAN bus for several SLCAN clients on the QEMU handwheel's single SLCAN port.

QEMU's SLCAN line takes one client. The hub is that client and listens on a port of its own
where any number of python-can `slcan` clients (`socket://127.0.0.1:<port>`) connect: every
frame from the device goes to all of them, every frame from a client to the device and to
the other clients, as on a bus. Channel commands from clients (`O`, `C`, `S8`, ...) are
answered `\\r` locally and not passed on: the device's channel is open from its power-on.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from typing import List

FRAME_COMMANDS = b"tTrR"


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
        self._buffers = {}
        self.error: Exception = None
        self.thread = threading.Thread(target=self._run, name="slcan-hub", daemon=True)
        self.thread.start()

    @property
    def channel(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def _connect_upstream(self) -> socket.socket:
        # Never probe QEMU's port with a throw-away connection: it would be its client.
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
        up = self._connect_upstream()
        try:
            self._pump(up)
        finally:
            up.close()

    def _pump(self, up: socket.socket) -> None:
        up_buf = b""
        while not self._stop.is_set():
            readable, _, _ = select.select([up, self.server] + self._clients, [], [], 0.05)
            for s in readable:
                if s is self.server:
                    conn, _ = self.server.accept()
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._clients.append(conn)
                    self._buffers[conn] = b""
                elif s is up:
                    data = up.recv(4096)
                    if not data:
                        raise RuntimeError("the device's SLCAN port closed")
                    up_buf += data
                    *lines, up_buf = up_buf.split(b"\r")
                    for line in lines:
                        line = line.lstrip(b"\x07")
                        if line[:1] and line[:1] in FRAME_COMMANDS:
                            self._send_all(line + b"\r", exclude=None)
                else:
                    self._from_client(s, up)

    def _from_client(self, s: socket.socket, up: socket.socket) -> None:
        try:
            data = s.recv(4096)
        except OSError:
            data = b""
        if not data:
            self._drop(s)
            return
        buf = self._buffers[s] + data
        *lines, self._buffers[s] = buf.split(b"\r")
        for line in lines:
            if line[:1] and line[:1] in FRAME_COMMANDS:
                up.sendall(line + b"\r")
                self._send_all(line + b"\r", exclude=s)
            else:
                self._send(s, b"\r")

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
            self._buffers.pop(s, None)
            s.close()

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for c in list(self._clients):
            self._drop(c)
        self.server.close()
