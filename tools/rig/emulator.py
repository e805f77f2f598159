"""The emulated handwheel: `cargo xtask board` (the release image on the emulated board) as
a child process, its control line (`Stimulus`, `Board.control`), and python-can's slcan bus
on its CAN port.

`HANDWHEEL_BOARD_COMMAND` overrides the runner, e.g. to skip cargo:
"python tools/board-emu/server.py --elf ELF --can-port {can_port} --stim-port {stim_port}
--flash {flash}" (the defmt stream then is not decoded).

`HANDWHEEL_BOARD_SERVER` (the release image) and `HANDWHEEL_BOARD_SERVER_STACK_OVERFLOW`, set
by the `cargo xtask` suites once they built everything, hold the server's command up to the
board's own options (a shell line): the board then starts without cargo and the task runner.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import socket
import subprocess
import time
from pathlib import Path
from typing import List, Optional

import can

from .constants import FRAME_TIMEOUT, ROOT, START_TIMEOUT, STIM_TIMEOUT


def free_ports(count: int) -> List[int]:
    """`count` distinct free TCP ports on 127.0.0.1 (bound together, then released)."""
    socks = []
    try:
        for _ in range(count):
            s = socket.socket()
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def server_variable(image: str | None) -> str:
    """The variable that holds the prepared server command of `image` (None: the release
    image): `HANDWHEEL_BOARD_SERVER`, with `_STACK_OVERFLOW` for `stack-overflow`."""
    if image in (None, "release"):
        return "HANDWHEEL_BOARD_SERVER"
    return "HANDWHEEL_BOARD_SERVER_" + image.upper().replace("-", "_")


class Board:
    """`cargo xtask board --can-port P --stim-port Q --flash FILE`, its stderr (the server's
    messages and the decoded defmt log) in `log_path`. `flash` is its parameter page file
    (kept across `power`), `dip` its DIP switch, `image` the firmware (default: the release
    image). Besides the stimulus client of the rig, `control()` sends the board's own
    commands on a connection of its own."""

    def __init__(
        self,
        log_path: Path,
        flash: Path | None = None,
        dip: int | str | None = None,
        image: str | None = None,
    ) -> None:
        self.can_port, self.stim_port = free_ports(2)
        self.log_path = log_path
        self.flash = flash if flash is not None else log_path.with_name("flash.bin")
        self._log_file = open(log_path, "wb")
        self._control: socket.socket | None = None
        self._reader = None
        # Further options of the task (`--name value`), also offered to the override.
        extra = {"flash": str(self.flash)}
        if dip is not None:
            extra["dip"] = str(dip)
        if image is not None:
            extra["image"] = image  # `cargo xtask board --image`: release, stack-overflow
        template = os.environ.get("HANDWHEEL_BOARD_COMMAND")
        server = os.environ.get(server_variable(image))
        if template:
            command = shlex.split(
                template.format(can_port=self.can_port, stim_port=self.stim_port, **extra)
            )
        elif server:
            command = shlex.split(server) + [
                "--can-port",
                str(self.can_port),
                "--stim-port",
                str(self.stim_port),
                "--flash",
                str(self.flash),
            ]
            if dip is not None:
                command += ["--dip", str(dip)]
        else:
            command = [
                os.environ.get("CARGO", "cargo"),
                "xtask",
                "board",
                "--can-port",
                str(self.can_port),
                "--stim-port",
                str(self.stim_port),
            ]
            for name, value in extra.items():
                command += [f"--{name}", value]
        self.proc = subprocess.Popen(
            command,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: cargo, xtask, the server, defmt-print
        )

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            tail = "\n".join(self.log().splitlines()[-40:])
            raise RuntimeError(f"`cargo xtask board` exited with {code}:\n{tail}")

    def wait_for_log(
        self, pattern: str, timeout: float = FRAME_TIMEOUT, start: int = 0
    ) -> re.Match:
        """The first match of the regex `pattern` in the log after character `start`."""
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern, re.MULTILINE)
        while True:
            m = rx.search(self.log(), start)
            if m:
                return m
            if time.monotonic() > deadline:
                tail = "\n".join(self.log().splitlines()[-30:])
                raise AssertionError(f"log line /{pattern}/ not seen in {timeout} s:\n{tail}")
            time.sleep(0.05)

    # -- the control line (a second connection beside the stimulus client) ---------------------

    def control(self, command: str, timeout: float = 30.0) -> list[str]:
        """Sends one control command; returns the lines before its `ok` (fails on `err`)."""
        if self._control is None:
            deadline = time.monotonic() + timeout
            while True:
                self.check_alive()
                try:
                    self._control = socket.create_connection(
                        ("127.0.0.1", self.stim_port), timeout=timeout
                    )
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)
            self._reader = self._control.makefile("rb")
        self._control.sendall(command.encode() + b"\n")
        lines = []
        while True:
            line = self._reader.readline().decode(errors="replace").rstrip("\r\n")
            if line == "ok":
                return lines
            if line.startswith("err") or not line:
                raise AssertionError(f"control {command!r} answered {line!r}")
            lines.append(line)

    def status(self) -> dict[str, str]:
        (line,) = self.control("status")
        return dict(word.split("=", 1) for word in line.split()[1:])

    def outputs(self) -> tuple[int, bool]:
        """The digital outputs driven high (bit n = board output n + 1: output 1 is "jog
        live", outputs 2..8 are 0x6A00:1 bits 0..6) and "jog live" alone, from `status`."""
        status = self.status()
        return int(status["outputs"], 16), status["jog"] == "1"

    def leds(self) -> list[tuple[float, str, bool]]:
        """The LED history: (ms of emulated time, "run" or "err", on)."""
        out = []
        for line in self.control("leds"):
            _, ms, led, on = line.split()
            out.append((float(ms), led, on == "1"))
        return out

    def stop(self) -> None:
        if self._control is not None:
            try:
                self._reader.close()
                self._control.close()
            except OSError:
                pass
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._log_file.close()


class Stimulus:
    """The control line as the rig's stimulus client (wheel and switches): one command line
    out, one reply line back."""

    def __init__(self, port: int, board: Board) -> None:
        deadline = time.monotonic() + FRAME_TIMEOUT
        while True:
            board.check_alive()
            try:
                self._sock = socket.create_connection(("127.0.0.1", port), timeout=STIM_TIMEOUT)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._reader = self._sock.makefile("rb")

    def send(self, command: str) -> str:
        """Sends one command; returns the reply line without its newline."""
        self._sock.sendall(command.encode() + b"\n")
        line = self._reader.readline()
        assert line.endswith(b"\n"), f"{command!r}: reply {line!r} cut short"
        return line.decode(errors="replace").rstrip("\r\n")

    def cmd(self, command: str) -> None:
        reply = self.send(command)
        assert reply == "ok", f"stimulus {command!r} answered {reply!r}"

    def turn(self, detents: int) -> None:
        self.cmd(f"turn {detents}")

    def ab(self, levels: int) -> None:
        self.cmd(f"ab {levels}")

    def axis(self, axis: str) -> None:
        self.cmd(f"axis {axis}")

    def mult(self, factor: int) -> None:
        self.cmd(f"mult {factor}")

    def close(self) -> None:
        try:
            self._reader.close()
            self._sock.close()
        except OSError:
            pass


def _refused(error: BaseException) -> bool:
    """Whether `error` (python-can's CanInitializationError, from pyserial's
    SerialException) goes back to a refused TCP connection."""
    seen: Optional[BaseException] = error
    while seen is not None:
        if isinstance(seen, ConnectionRefusedError):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def slcan_line(channel: str, **bus_kwargs) -> can.BusABC:
    """python-can's slcan bus on a TCP line (`socket://host:port`: a board, a relay, a hub)
    that opens and closes at once: no pause after opening (that is for serial adapters), and
    none in closing. pyserial's socket handler (3.5) sleeps 0.3 s in `close()` so that a
    server has time before a quick reconnect; the boards, relays and hubs here take a new
    client at once, and every test paid it at its end (the component's own bus closes its
    line the same way: `canopen_handwheel.bus`)."""
    from canopen_handwheel.bus import close_port_at_once

    bus = can.Bus(interface="slcan", channel=channel, sleep_after_open=0, **bus_kwargs)
    port = bus.serialPortOrig
    if hasattr(port, "_socket"):  # pyserial's socket:// port, the only one it pauses for
        port.close = lambda: close_port_at_once(port)
    return bus


def connect_bus(board: Board, **bus_kwargs) -> can.BusABC:
    """python-can's slcan bus on the CAN port, as docs/EMULATED-BOARD.md connects (extra
    `bus_kwargs` such as `bitrate` go to `can.Bus`). The board listens (and starts its CPU
    with this client) only once it is built and up: retry while the connection is refused,
    and only then. Never probe the port with a throw-away connection: the board would take
    it as its client."""
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        board.check_alive()
        try:
            return slcan_line(f"socket://127.0.0.1:{board.can_port}", **bus_kwargs)
        except can.CanError as e:
            if not _refused(e) or time.monotonic() > deadline:
                raise
            time.sleep(0.1)
