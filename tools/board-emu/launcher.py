"""Starts the emulated board for a test: `cargo xtask board` in its own process group, with
the same surface as the interop suite's `Qemu` (ports, `log()`, `check_alive()`,
`wait_for_log()`, `stop()`), plus `control()` for the board's own commands.

`HANDWHEEL_BOARD_COMMAND` overrides the runner, e.g. to skip cargo:
"python tools/board-emu/server.py --elf ELF --can-port {can_port} --stim-port {stim_port}
--flash {flash}" (the defmt stream then is not decoded).
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

# The rig library (tools/rig): the tests that use this launcher have it on their path.
from rig import Qemu  # noqa: E402


class BoardProcess(Qemu):
    """One emulated board (`cargo xtask board`); `flash` is its parameter page file (kept
    across `power`), `dip` its DIP switch, `image` the firmware (default: the release image).
    The process, its log and the stimulus port are the rig's; the board adds its control
    line."""

    kind = "board"

    def __init__(
        self, log_path: Path, flash: Path, dip: int | None = None, image: str | None = None
    ) -> None:
        extra = {"flash": str(flash)}
        if dip is not None:
            extra["dip"] = str(dip)
        if image is not None:
            extra["image"] = image  # `cargo xtask board --image`: release, stack-overflow
        super().__init__(log_path, "board", extra, "HANDWHEEL_BOARD_COMMAND")
        self.flash = flash
        self._control: socket.socket | None = None
        self._reader = None

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
        super().stop()
