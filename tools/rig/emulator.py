"""The emulated handwheel: `cargo xtask qemu` as a child process, its stimulus port, and
python-can's slcan bus on its CAN port."""

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


class Qemu:
    """`cargo xtask qemu --can-port P --stim-port Q`, its stderr (QEMU's messages and the
    decoded defmt log) in `log_path`. With `task` "board", `cargo xtask board` instead: the
    release image on the emulated board, with the same ports, log and stimulus commands."""

    def __init__(
        self,
        log_path: Path,
        task: str = "qemu",
        extra: dict[str, str] | None = None,
        override: str = "HANDWHEEL_QEMU_COMMAND",
    ) -> None:
        self.task = task
        self.can_port, self.stim_port = free_ports(2)
        self.log_path = log_path
        self._log_file = open(log_path, "wb")
        # `extra`: further options of the task (`--name value`), also offered to the override.
        extra = extra or {}
        # The override (HANDWHEEL_QEMU_COMMAND, or the board's) replaces the runner, e.g. to
        # use a prebuilt image: "some-runner --can-port {can_port} --stim-port {stim_port}".
        template = os.environ.get(override)
        if template:
            command = shlex.split(
                template.format(can_port=self.can_port, stim_port=self.stim_port, **extra)
            )
        else:
            command = [
                os.environ.get("CARGO", "cargo"),
                "xtask",
                task,
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
            start_new_session=True,  # its own process group: cargo, xtask, QEMU, defmt-print
        )

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            tail = "\n".join(self.log().splitlines()[-40:])
            raise RuntimeError(f"`cargo xtask {self.task}` exited with {code}:\n{tail}")

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

    def stop(self) -> None:
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
    """The stimulus port: one command line out, one reply line back."""

    def __init__(self, port: int, qemu: Qemu) -> None:
        deadline = time.monotonic() + FRAME_TIMEOUT
        while True:
            qemu.check_alive()
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


def connect_bus(qemu: Qemu, **bus_kwargs) -> can.BusABC:
    """python-can's slcan bus on the CAN port, as docs/QEMU.md connects (extra
    `bus_kwargs` such as `bitrate` go to `can.Bus`). QEMU listens (and waits for this
    client) only once it is up: retry while the connection is refused, and only then. Never
    probe the port with a throw-away connection: QEMU would take it as its client."""
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        qemu.check_alive()
        try:
            return can.Bus(
                interface="slcan",
                channel=f"socket://127.0.0.1:{qemu.can_port}",
                sleep_after_open=0,
                **bus_kwargs,
            )
        except can.CanError as e:
            if not _refused(e) or time.monotonic() > deadline:
                raise
            time.sleep(0.1)
