"""SLCAN, the ASCII line protocol of serial CAN adapters (Lawicel's CANUSB, a CANable with slcan
firmware, USBtin; python-can's `slcan` interface), as this repository speaks it everywhere:
the component's bulk reader, the emulated board's CAN port and the relays and hub of the
tests.

A line ends in `\\r`. Frames: `tIIIL<data>` (11-bit identifier), `TIIIIIIIIL<data>` (29-bit),
`rIIIL` and `RIIIIIIIIL` (remote frames, no data); L is the DLC 0..8, the data 2L hex digits,
and an adapter whose timestamps are on (`Z1`) appends 4 hex digits, its millisecond counter
(0..59999, it wraps at 60 000). Hex digits are read in either case and written upper-case, as
adapters write them. Every other line is a command (`O` open, `C` close, `S0`..`S8` bit rate,
...), answered `\\r` (done) or BEL (refused); a frame sent is answered `z\\r` (`t`, `r`) or
`Z\\r` (`T`, `R`).

`decode` and `encode` convert one line; `LineSplitter` cuts a byte stream into lines;
`to_message` makes python-can's `can.Message`. Standard library only (python-can is imported by
`to_message` alone), so that the emulated board's venv, which has no python-can, and scripts
with `host/src` on their path use it too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import List, Optional

OK = b"\r"
ERROR = b"\a"
# `S0`..`S8`: the bit rates the commands set, bit/s.
BITRATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)
# An adapter's timestamp counts milliseconds and wraps here.
TIMESTAMP_WRAP = 60_000

# The letter with its identifier, the DLC, then data and timestamp (hex, split by the DLC).
_FRAME_LINE = re.compile(
    rb"(?:([tr])([0-9A-Fa-f]{3})|([TR])([0-9A-Fa-f]{8}))([0-8])((?:[0-9A-Fa-f]{2})*)"
)


@dataclass(frozen=True)
class Frame:
    """One CAN frame of an SLCAN line."""

    id: int
    data: bytes = b""
    extended: bool = False
    remote: bool = False
    dlc: Optional[int] = None  # a remote frame's DLC; None: len(data)
    timestamp: Optional[int] = None  # the adapter's milliseconds, when its timestamps are on

    @property
    def length(self) -> int:
        return len(self.data) if self.dlc is None else self.dlc


def decode(line: bytes) -> Optional[Frame]:
    """The frame of one line (without its `\\r`), or None for anything else: a command, a
    reply, a line cut short or too long, a DLC over 8, an identifier beyond 11 (29) bits, a
    remote frame with data, a timestamp of 60 000 or more, a character that is not hex."""
    match = _FRAME_LINE.fullmatch(line)
    if match is None:
        return None
    letter, short_id, long_letter, long_id, dlc_digit, body = match.groups()
    extended = long_letter is not None
    remote = (long_letter or letter) in (b"r", b"R")
    can_id = int(long_id if extended else short_id, 16)
    dlc = int(dlc_digit)
    if can_id >= 1 << (29 if extended else 11):
        return None
    size = 0 if remote else 2 * dlc
    if len(body) == size:
        timestamp = None
    elif len(body) == size + 4:
        timestamp = int(body[size:], 16)
        if timestamp >= TIMESTAMP_WRAP:
            return None
    else:
        return None
    data = bytes.fromhex(body[:size].decode("ascii"))
    return Frame(can_id, data, extended, remote, dlc if remote else None, timestamp)


def encode(frame: Frame) -> bytes:
    """The line of `frame`, with its `\\r`. ValueError for a frame no line can carry (an
    identifier beyond 11 (29) bits, more than 8 bytes, a remote frame with data, a data
    frame whose DLC is not its length, a timestamp outside 0..59999)."""
    if not 0 <= frame.id < 1 << (29 if frame.extended else 11):
        raise ValueError(f"identifier {frame.id:#x} does not fit the frame's format")
    if not 0 <= frame.length <= 8:
        raise ValueError(f"DLC {frame.length}: SLCAN carries 0..8")
    if frame.remote and frame.data:
        raise ValueError("a remote frame carries no data")
    if not frame.remote and frame.dlc not in (None, len(frame.data)):
        raise ValueError(f"DLC {frame.dlc} for {len(frame.data)} bytes of data")
    letter = ("R" if frame.remote else "T") if frame.extended else ("r" if frame.remote else "t")
    width = 8 if frame.extended else 3
    line = f"{letter}{frame.id:0{width}X}{frame.length}{frame.data.hex().upper()}"
    if frame.timestamp is not None:
        if not 0 <= frame.timestamp < TIMESTAMP_WRAP:
            raise ValueError(f"timestamp {frame.timestamp}: an adapter counts 0..59999 ms")
        line += f"{frame.timestamp:04X}"
    return line.encode("ascii") + OK


def ack(frame: Frame) -> bytes:
    """An adapter's answer to a frame it put on the bus."""
    return b"Z\r" if frame.extended else b"z\r"


class LineSplitter:
    """Cuts a byte stream into lines, returned without their `\\r` and with leading BELs
    removed (an adapter's refusal is a BEL without `\\r`, so one sticks to the line after it);
    the unfinished rest waits for the next `feed`.

    With `longest`, a line that grows past `longest` bytes before its `\\r` is dropped, up to
    and with its `\\r` (its tail is no line of its own that could pass for a frame), and
    counted in `overflows`: a peer that never ends its lines cannot fill the memory. An
    overflow is always the last thing `feed` saw, after the lines it returned."""

    def __init__(self, longest: Optional[int] = None) -> None:
        self.longest = longest
        self.overflows = 0
        self._rest = b""
        self._dropping = False  # inside an overlong line, up to its `\r`

    def feed(self, data: bytes) -> List[bytes]:
        *lines, rest = (self._rest + data).split(b"\r")
        if self._dropping:
            if not lines:
                return []
            del lines[0]  # the overlong line's tail
            self._dropping = False
        if self.longest is not None and len(rest) > self.longest:
            rest = b""
            self._dropping = True
            self.overflows += 1
        self._rest = rest
        return [line.lstrip(ERROR) for line in lines]


def to_message(frame: Frame, timestamp: float):
    """`frame` as python-can's `can.Message` received at `timestamp` (its clock's seconds:
    an adapter's timestamp wraps every minute and tells no time of day)."""
    import can  # here, not with the module: the emulated board's venv has no python-can

    return can.Message(
        timestamp=timestamp,
        arbitration_id=frame.id,
        data=frame.data,
        dlc=frame.length,
        is_extended_id=frame.extended,
        is_remote_frame=frame.remote,
    )
