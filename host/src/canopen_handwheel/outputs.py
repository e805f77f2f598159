"""The outputs the CNC drives on the device (host/README.md, "Outputs"): the byte of RPDO1
(0x6A00:1: CiA 401's "write output 8-bit" 0x6200 moved by +0x800) from the input pins
(`output_byte`), whether the device may get it now (`outputs_allowed`), and when it goes on
the bus (`OutputSchedule`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

from .record import OPERATIONAL

# RPDO1 of the device: 0x200 + node-ID, one byte, mapped by default to 0x6A00:1.
RPDO1 = 0x200
# The component's pins of the integrator's outputs, `out-1` .. `out-6`: bits 1..6 of the byte;
# bit 0 is `machine-on`, bit 7 has no pin (always 0).
MACHINE_ON_BIT = 0
OUT_PINS = 6
# The board's outputs by number: 1 is the device's own jog-live LED, 2 follows bit 0
# (`machine-on`), N + 2 follows bit N (`out-N`).
OUT_BOARD_OFFSET = 2
# Two frames of RPDO1 are never closer than this: a pin toggled at any rate costs the bus at
# most 100 frames a second (well under 1 % at 1 Mbit/s, about 5 % at 125 kbit/s), and a change
# waits for it at most this long. The frame ranks below the device's feed record on the bus
# (0x210 after 0x190), so it never delays a record in arbitration.
OUTPUT_INHIBIT = 0.010
# The byte again at this period while nothing changes (`--output-period-ms`): a frame lost, or
# a device that started afresh in Operational, is corrected within it.
DEFAULT_OUTPUT_PERIOD_MS = 100
OUTPUT_PERIOD_MS_RANGE = (20, 1000)


def output_period(period_ms: int) -> float:
    """`--output-period-ms` in seconds, checked."""
    low, high = OUTPUT_PERIOD_MS_RANGE
    if not low <= period_ms <= high:
        raise ValueError(f"--output-period-ms must be {low}..{high}")
    return period_ms / 1000


def output_byte(machine_on: bool, outs: Sequence[bool]) -> int:
    """The byte of 0x6A00:1: bit 0 `machine-on`, bit N `out-N` (N = 1..6)."""
    if len(outs) != OUT_PINS:
        raise ValueError(f"{OUT_PINS} outputs, not {len(outs)}")
    byte = int(bool(machine_on)) << MACHINE_ON_BIT
    for n, on in enumerate(outs, start=1):
        byte |= int(bool(on)) << n
    return byte


def describe_outputs(byte: int) -> str:
    """The byte in the pins' words, for a capture's decoding."""
    on = (["machine on"] if byte >> MACHINE_ON_BIT & 1 else []) + [
        f"out-{n}" for n in range(1, OUT_PINS + 1) if byte >> n & 1
    ]
    if byte >> 7 & 1:
        on.append("bit 7")
    return "outputs: " + (", ".join(on) if on else "all off")


def outputs_allowed(
    session: Optional[int], fresh: bool, state: Optional[int], foreign_newest: bool
) -> bool:
    """The device may get its outputs: it is in the component's session (configured by this
    component since it last booted, and not lost since), its records of that session arrive
    (it sends them only while Operational, so it was started after the configuration) and
    the newest is not another session's, and its last heartbeat says Operational. A device
    Stopped, Pre-operational, booted, silent, showing another session or in its loader gets
    nothing: it applies its own error values (0x6A06 / 0x6A07) on master loss and NMT stop."""
    return session is not None and fresh and state in (None, OPERATIONAL) and not foreign_newest


@dataclass
class OutputSchedule:
    """When RPDO1 goes out. While `allowed`: at once when the byte differs from the one last
    sent in this stretch of being allowed (the first frame of a stretch too), else `period`
    after the last frame; never within `inhibit` of the last frame (a change then goes out
    at its end). While not allowed: nothing, and the next stretch begins with a frame."""

    period: float = DEFAULT_OUTPUT_PERIOD_MS / 1000
    inhibit: float = OUTPUT_INHIBIT
    sent_at: Optional[float] = None  # the last frame, across stretches (the inhibit holds)
    sent: Optional[int] = None  # its byte, None outside a stretch or after a failed send

    def due(self, now: float, byte: int, allowed: bool) -> Optional[int]:
        """The byte to send now (the schedule counts it as sent), or None."""
        if self.wake_at(now, byte, allowed) > now:
            if not allowed:
                self.sent = None
            return None
        self.sent, self.sent_at = byte, now
        return byte

    def wake_at(self, now: float, byte: int, allowed: bool) -> float:
        """When `due` sends next if the inputs stay as they are (`now` or earlier: at once;
        infinity: never)."""
        if not allowed:
            return math.inf
        if self.sent_at is None:
            return now
        free = self.sent_at + self.inhibit
        if self.sent is None or byte != self.sent:
            return free
        return max(free, self.sent_at + self.period)

    def unsent(self) -> None:
        """The frame `due` returned did not reach the bus (the send failed): it goes again
        once the inhibit allows."""
        self.sent = None
