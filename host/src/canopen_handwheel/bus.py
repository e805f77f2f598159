"""Finding the device without HAL: its EDS as installed with the package, the bus options
(the component's and `update`'s), and python-can's bus for them (SLCAN lines read in bulk).
The component (`component.py`) and the update command (`update_cli.py`) open the bus with
these; the decoder reads the EDS's object names."""

from __future__ import annotations

import argparse
import collections
import os
import select
import socket
import time
from importlib import resources
from typing import Optional

from . import slcan


def default_eds() -> str:
    """The device's EDS as installed with the package (built from the repository's
    `eds/handwheel.eds`, which `handwheel.eds` in the source tree links to)."""
    return str(resources.files(__package__).joinpath("handwheel.eds"))


def add_bus_options(p: argparse.ArgumentParser) -> None:
    """The options that find the device: the component's, and `update`'s."""
    p.add_argument("--interface", default="socketcan", help="python-can interface (socketcan)")
    p.add_argument(
        "--channel",
        default="can0",
        help="python-can channel (can0; for slcan a serial port or socket://host:port)",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=None,
        help="bit rate for interfaces that set it (default: leave it as it is)",
    )
    p.add_argument("--node", type=int, default=16, help="the handwheel's node-ID (16)")


def close_port_at_once(port) -> None:
    """Closes a pyserial port now. pyserial's `socket://` handler (3.5) sleeps 0.3 s in
    `close()` "for quick reconnects", in whatever thread closes it; its socket is shut and
    closed here instead (a second call finds it closed). Other ports close as pyserial
    closes them."""
    if not hasattr(port, "_socket"):
        port.close()
        return
    sock, port._socket = port._socket, None
    port.is_open = False
    if sock is None:
        return
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass  # the other end closed it already
    sock.close()


def slcan_bus(channel: str, **kwargs):
    """python-can's SLCAN bus (`can.Bus(interface="slcan")`), receiving in bulk: every read
    takes what the port holds (`os.read` on its descriptor, a serial port or a socket) and
    parses all complete lines at once. python-can reads one byte per call (two `select`s and
    a `recv` per byte on a `socket://` line), about 3 000 frames/s at most on a busy PC. Lines
    other than standard data frames (`t`, as `slcan.decode` reads them), and lines too long
    for one, are ignored. `recv(0)` returns None only when no parsed frame is left and the port
    has nothing to read."""
    import can
    from can.interfaces.slcan import slcanBus

    class BulkSlcanBus(slcanBus):
        LONGEST_LINE = 64

        def __init__(self, *args, **kw) -> None:
            super().__init__(*args, **kw)
            self._frames: "collections.deque" = collections.deque()
            self._lines = slcan.LineSplitter(self.LONGEST_LINE)
            try:
                self._fd = self.serialPortOrig.fileno()
            except Exception:  # a URL handler without a descriptor: python-can's reading
                self._fd = None

        def _recv_internal(self, timeout):
            if self._fd is None:
                return super()._recv_internal(timeout)
            deadline = None if timeout is None else time.monotonic() + timeout
            while not self._frames:
                wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    ready, _, _ = select.select([self._fd], [], [], wait)
                    if not ready:
                        return None, False
                    data = os.read(self._fd, 65536)
                except (OSError, ValueError) as e:
                    raise can.CanOperationError(f"reading the SLCAN line: {e!r}") from e
                if not data:
                    raise can.CanOperationError("the SLCAN line closed")
                self._parse(data)
            return self._frames.popleft(), False

        def shutdown(self) -> None:
            """Closes the channel (`C`) if the line still takes it, and the line itself
            always, at once. python-can's `shutdown` raises when the `C` cannot be written
            (a line the other end broke) before it closes the port, which then stays open
            until the garbage collector finalises it, in any thread, with pyserial's 0.3 s
            pause: seen as a send of the component's next line blocked for 0.3 s (the
            sequence probe late, a detent not credited)."""
            if self._is_shutdown:
                return
            can.BusABC.shutdown(self)
            try:
                self.close()
            except can.CanError:
                pass  # the line is gone: nothing to tell the adapter
            close_port_at_once(self.serialPortOrig)

        def _parse(self, data: bytes) -> None:
            for line in self._lines.feed(data):
                frame = slcan.decode(line)
                # The component reads CANopen's frames: 11-bit data frames.
                if frame is None or frame.extended or frame.remote:
                    continue
                # An adapter's own timestamp (`Z1`) wraps every minute: the host's clock it is.
                self._frames.append(slcan.to_message(frame, time.time()))

    return BulkSlcanBus(channel=channel, **kwargs)


def open_bus(interface: str, channel: str, bitrate: Optional[int]):
    """python-can's bus for the bus options (SLCAN lines read in bulk: `slcan_bus`)."""
    import can

    kwargs = {}
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    if interface == "slcan":
        if str(channel).startswith("socket://"):
            kwargs["sleep_after_open"] = 0
        return slcan_bus(channel, **kwargs)
    return can.Bus(interface=interface, channel=channel, **kwargs)
