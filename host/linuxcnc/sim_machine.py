"""Runs the sim machine of `sim/` under LinuxCNC, for the LinuxCNC test suite and
`cargo xtask linuxcnc`.

`SimMachine` copies the configuration to a fresh folder, points `[HANDWHEEL]` at the
component and its CAN channel, starts `linuxcnc` (as `user` when given: LinuxCNC's
`rtapi_app` refuses to run as root) under `script`, so that its output stays visible in the
log, and talks to the headless display's agent port (see `sim/handwheel-display`).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Dict, Optional

SIM = Path(__file__).resolve().parent / "sim"
INI = "handwheel-sim.ini"


def set_ini(text: str, values: Dict[str, Dict[str, str]]) -> str:
    """`text` with `NAME = value` replaced (or added) in the given sections."""
    lines = text.splitlines()
    out = []
    section = None
    pending: Dict[str, Dict[str, str]] = {s: dict(v) for s, v in values.items()}

    def flush(sec):
        for k, v in pending.pop(sec, {}).items():
            out.append(f"{k} = {v}")

    for line in lines:
        stripped = line.strip()
        if stripped.startswith("[") and stripped.endswith("]"):
            if section in pending:
                flush(section)
            section = stripped[1:-1]
        elif section in pending and "=" in stripped and not stripped.startswith("#"):
            key = stripped.split("=", 1)[0].strip()
            if key in pending[section]:
                out.append(f"{key} = {pending[section].pop(key)}")
                continue
        out.append(line)
    if section in pending:
        flush(section)
    for sec in list(pending):
        out.append(f"[{sec}]")
        flush(sec)
    return "\n".join(out) + "\n"


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class SimMachine:
    def __init__(
        self,
        component: str,
        channel: str,
        log_path: Path,
        interface: str = "slcan",
        user: Optional[str] = None,
        auto_on: bool = False,
        extra_args: str = "",
    ) -> None:
        self.user = user
        self.agent_port = free_port()
        self.dir = Path(tempfile.mkdtemp(prefix="handwheel-sim-"))
        for f in SIM.iterdir():
            if f.is_file():
                shutil.copy2(f, self.dir / f.name)
        ini = self.dir / INI
        ini.write_text(
            set_ini(
                ini.read_text(),
                {
                    "HANDWHEEL": {
                        "COMPONENT": component,
                        "INTERFACE": interface,
                        "CHANNEL": channel,
                    },
                    "HANDWHEEL_SIM": {
                        "AGENT_PORT": str(self.agent_port),
                        "AUTO_ON": "1" if auto_on else "0",
                    },
                },
            )
        )
        if extra_args:
            hal = self.dir / "handwheel.hal"
            hal.write_text(
                hal.read_text().replace(
                    "--scale [HANDWHEEL]SCALE", f"--scale [HANDWHEEL]SCALE {extra_args}"
                )
            )
        os.chmod(self.dir, 0o755)
        if user:
            shutil.chown(self.dir, user)
            for f in self.dir.iterdir():
                shutil.chown(f, user)
        inner = f"linuxcnc {shlex.quote(str(ini))}"
        shell = (
            f"cd {shlex.quote(str(self.dir))} && exec script -qfec {shlex.quote(inner)} /dev/null"
        )
        argv = ["su", user, "-s", "/bin/sh", "-c", shell] if user else ["sh", "-c", shell]
        self.log_path = log_path
        self._log = open(log_path, "wb")
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self._sock: Optional[socket.socket] = None
        self._reader = None

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def connect(self, timeout: float = 90) -> None:
        """Waits for the display's agent (LinuxCNC is up)."""
        deadline = time.monotonic() + timeout
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"linuxcnc exited ({self.proc.returncode}):\n{self.tail()}")
            try:
                self._sock = socket.create_connection(("127.0.0.1", self.agent_port), timeout=60)
                self._reader = self._sock.makefile("rb")
                return
            except OSError as e:
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"LinuxCNC's display did not answer in {timeout} s:\n{self.tail()}"
                    ) from e
                time.sleep(0.2)

    def tail(self, lines: int = 60) -> str:
        return "\n".join(self.log().splitlines()[-lines:])

    def call(self, line: str) -> dict:
        assert self._sock is not None, "connect() first"
        self._sock.sendall(line.encode() + b"\n")
        reply = self._reader.readline()
        if not reply:
            raise RuntimeError(f"the display closed the connection:\n{self.tail()}")
        return json.loads(reply)

    def must(self, line: str) -> dict:
        reply = self.call(line)
        assert reply.get("ok"), f"{line!r}: {reply}"
        return reply

    def stop(self, timeout: float = 30) -> None:
        """Asks the display to quit (LinuxCNC shuts down); forces it after `timeout`; then
        removes the configuration's folder."""
        self.shutdown(timeout)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self._log.close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def shutdown(self, timeout: float = 30) -> None:
        """Asks the display to quit, so that LinuxCNC shuts down as it does when its user
        quits; forces it after `timeout`. The configuration's folder (and what was written
        there) stays until `stop`."""
        if self.proc.poll() is None and self._sock is not None:
            try:
                self.call("quit")
            except Exception:
                pass
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            for sig in (signal.SIGTERM, signal.SIGKILL):
                try:
                    os.killpg(self.proc.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.proc.wait(10)
                    break
                except subprocess.TimeoutExpired:
                    continue
            # Whatever LinuxCNC left (rtapi_app, HAL shared memory) goes with `halrun -U`.
            unload = "halrun -U"
            argv = (
                ["su", self.user, "-s", "/bin/sh", "-c", unload]
                if self.user
                else ["sh", "-c", unload]
            )
            subprocess.run(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=self._log,
                stderr=subprocess.STDOUT,
                timeout=60,
            )
