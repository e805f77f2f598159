"""The host component as a process of the interop suite: its pins as fake_hal logs them, its
end, and the check of its capture. Shared by `test_host_component.py` and `test_copies.py`."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from typing import List, Optional

from .constants import ROOT, TPDO1

# The DBC `cargo xtask dbc` writes for the default node-ID.
DBC = ROOT / "eds" / "handwheel.dbc"


class HalLog:
    """The component's pin changes as fake_hal writes them (`<time> <pin> <value>`), read
    incrementally: `values` is the newest of every pin, `changes` all of them in order."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.path.write_text("")
        self._offset = 0
        self._rest = b""
        self.changes: List[tuple] = []  # (time, pin, value as written)
        self.values: dict = {}

    def poll(self) -> None:
        with open(self.path, "rb") as f:
            f.seek(self._offset)
            data = f.read()
        self._offset += len(data)
        *lines, self._rest = (self._rest + data).split(b"\n")
        for line in lines:
            t, pin, value = line.decode().split(" ")
            self.changes.append((float(t), pin, value))
            self.values[pin] = value

    def value(self, pin: str) -> Optional[str]:
        self.poll()
        return self.values.get(pin)

    def number(self, pin: str) -> int:
        """An integer pin's newest value (0 before any change is logged)."""
        return int(self.value(pin) or 0)

    def history(self, pin: str, since: float = 0.0) -> List[tuple]:
        """(time, value) of the pin's changes at or after `since`."""
        self.poll()
        return [(t, v) for t, p, v in self.changes if p == pin and t >= since]

    def at(self, pin: str, when: float) -> Optional[str]:
        """The pin's value as it was at `when`."""
        self.poll()
        value = None
        for t, p, v in self.changes:
            if t > when:
                break
            if p == pin:
                value = v
        return value


def end_component(proc: subprocess.Popen) -> None:
    """Ends the component (woken first if a test stopped it), killed if it does not exit."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def capture_problems(capture: Path, hal: HalLog) -> List[str]:
    """Where the component's capture (`--capture`, with its host notes) disagrees with its
    run: replayed through the core (`canopen_handwheel.decode.replay`) it must end on the pins
    fake_hal logged, every feed record must get the rule's verdict, and cantools, reading the
    capture's records with the DBC, must decode each to the values the host decodes. Empty:
    it agrees."""
    import cantools

    from canopen_handwheel import capture as captures
    from canopen_handwheel import decode
    from canopen_handwheel.core import Record

    hal.poll()
    files = [captures.read(p) for p in captures.files_of(capture)]
    replay = decode.replay(files)
    problems = replay.differences(hal.changes)
    problems += [f"the replay differs from the notes: {m}" for m in replay.mismatches]
    tpdo1 = cantools.database.load_file(str(DBC)).get_message_by_frame_id(TPDO1)
    records = 0
    for line in replay.lines:
        f = line.frame
        if f.id != TPDO1 or f.remote or len(f.data) != 8:
            continue
        records += 1
        if line.verdict is None:
            problems.append(f"no verdict for the record at {f.t:.6f}")
        signals = tpdo1.decode(f.data, decode_choices=False)
        if signals != decode.record_signals(Record.decode(f.data)):
            problems.append(f"the DBC reads {f.data.hex()} as {signals}")
    if not records:
        problems.append("no feed record in the capture")
    return problems
