"""Starts the emulated board for a test: `cargo xtask board` in its own process group, with
the same surface as the interop suite's `Qemu` (ports, `log()`, `check_alive()`,
`wait_for_log()`, `stop()`), plus `control()` for the board's own commands.

`HANDWHEEL_BOARD_COMMAND` overrides the runner, e.g. to skip cargo:
"python tools/board-emu/server.py --elf ELF --can-port {can_port} --stim-port {stim_port}
--flash {flash}" (the defmt stream then is not decoded).
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

# The rig library (tools/rig): the tests that use this launcher have it on their path.
from rig import ROOT, free_ports  # noqa: E402


class BoardProcess:
    """One emulated board; `flash` is its parameter page file (kept across `power`)."""

    kind = "board"

    def __init__(self, log_path: Path, flash: Path, dip: int | None = None) -> None:
        self.can_port, self.stim_port = free_ports(2)
        self.log_path = log_path
        self.flash = flash
        self._log_file = open(log_path, "wb")
        template = os.environ.get("HANDWHEEL_BOARD_COMMAND")
        if template:
            command = shlex.split(
                template.format(can_port=self.can_port, stim_port=self.stim_port, flash=flash)
            )
        else:
            command = [
                os.environ.get("CARGO", "cargo"),
                "xtask",
                "board",
                "--can-port",
                str(self.can_port),
                "--stim-port",
                str(self.stim_port),
                "--flash",
                str(flash),
            ]
        if dip is not None:
            command += ["--dip", str(dip)]
        self.proc = subprocess.Popen(
            command,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self._control: socket.socket | None = None
        self._reader = None

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            tail = "\n".join(self.log().splitlines()[-40:])
            raise RuntimeError(f"`cargo xtask board` exited with {code}:\n{tail}")

    def wait_for_log(self, pattern: str, timeout: float = 5.0, start: int = 0) -> re.Match:
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
