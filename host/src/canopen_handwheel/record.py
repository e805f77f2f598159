"""The feed record (TPDO1, version 2) and what one record may follow: its layout, `Record`
(its one decoder in Python), and the continuity rule (`continuity`, `record_fault`,
`pair_fault`; host/README.md, "Feed bookkeeping" and "Continuity")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

# Device heartbeat states.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F


# The feed record (TPDO1, version 2), byte 4 (0x2011 "Feed selection"): bits 0-2 the axis
# (0 none, 1..5 these letters; 6 and 7 never sent), bits 3-4 the multiplier code (an index
# into MULTIPLIERS; 3 never sent), bits 5-7 the low three bits of the selection epoch (0x2010:3).
DEVICE_AXES = "xyzwv"
MULTIPLIERS = (1, 10, 100)
AXIS_MASK = 0x07
MULTIPLIER_SHIFT = 3
EPOCH_SHIFT = 5
EPOCH_MODULO = 8
# Byte 5 (0x2030 "Feed status"): bits 0-4 these flags, bits 5-7 the session (0 none, 1..7 the
# token a master wrote to 0x2002).
STATUS_ENABLED = 0x01
STATUS_ENCODER_ERROR = 0x02
STATUS_STEPS_DROPPED = 0x04
STATUS_MASTER_LOST = 0x08
STATUS_IGNORED_MOTION = 0x10
FLAGS_MASK = 0x1F
SESSION_SHIFT = 5
# Bytes 6-7 (0x2031 "Feed sequence", U16): +1 per record and per loss, +8 at a break.
SEQUENCE_MODULO = 65536


# The largest sequence gap still read as "the same epoch": each epoch takes at least one
# sequence number, so 6 missing numbers hide at most 6 epochs and the record after them is
# at most 7 epochs on, never the 8 that would bring the 3-bit epoch round.
SAME_EPOCH_MAX_GAP = 6


def wrap_s32(value: int) -> int:
    """`value` wrapped into the signed 32-bit range."""
    return ((value + 0x8000_0000) & 0xFFFF_FFFF) - 0x8000_0000


@dataclass(frozen=True)
class Record:
    """A feed record (TPDO1, 8 bytes, version 2) field by field: the one place the layout
    is written down in Python (README "Feed record"). `multiplier` is the factor (1, 10, 100;
    0 for code 3, which the device never sends), `flags` status bits 0-4, `session` the
    session the device was in, `sequence` the 16-bit feed sequence. Every 8 bytes decode,
    and `encode` gives them back."""

    position: int
    axis: int
    multiplier: int
    epoch: int
    flags: int
    session: int
    sequence: int

    @staticmethod
    def decode(data: bytes) -> "Record":
        """The record in `data`, which must be 8 bytes (`ValueError` otherwise)."""
        if len(data) != 8:
            raise ValueError(f"a feed record is 8 bytes, not {len(data)}")
        selection, status = data[4], data[5]
        code = (selection >> MULTIPLIER_SHIFT) & 0x03
        return Record(
            position=int.from_bytes(data[0:4], "little", signed=True),
            axis=selection & AXIS_MASK,
            multiplier=MULTIPLIERS[code] if code < len(MULTIPLIERS) else 0,
            epoch=selection >> EPOCH_SHIFT,
            flags=status & FLAGS_MASK,
            session=status >> SESSION_SHIFT,
            sequence=int.from_bytes(data[6:8], "little"),
        )

    def encode(self) -> bytes:
        """The 8 bytes. The position and the sequence wrap, the epoch is taken mod 8 (the
        record carries their low bits); another field out of its range is a mistake of the
        caller (`ValueError`), not something to wrap into a different record."""
        if not 0 <= self.axis <= AXIS_MASK:
            raise ValueError(f"axis {self.axis} does not fit 3 bits")
        if self.multiplier not in MULTIPLIERS + (0,):
            raise ValueError(f"multiplier {self.multiplier}: 1, 10, 100 (or 0 for code 3)")
        if not 0 <= self.flags <= FLAGS_MASK:
            raise ValueError(f"flags 0x{self.flags:X} do not fit 5 bits")
        if not 0 <= self.session <= 7:
            raise ValueError(f"session {self.session} does not fit 3 bits")
        code = MULTIPLIERS.index(self.multiplier) if self.multiplier else 3
        selection = (
            self.axis | code << MULTIPLIER_SHIFT | (self.epoch % EPOCH_MODULO) << EPOCH_SHIFT
        )
        status = self.flags | self.session << SESSION_SHIFT
        return (
            (self.position & 0xFFFF_FFFF).to_bytes(4, "little")
            + bytes([selection, status])
            + (self.sequence % SEQUENCE_MODULO).to_bytes(2, "little")
        )

    @property
    def enabled(self) -> bool:
        return bool(self.flags & STATUS_ENABLED)

    @property
    def master_lost(self) -> bool:
        return bool(self.flags & STATUS_MASTER_LOST)


def record_fault(rec: Record) -> Optional[str]:
    """Why the device can never send `rec` on its own, or None if it can."""
    if rec.axis > len(DEVICE_AXES):
        return f"axis {rec.axis}"
    if rec.multiplier not in MULTIPLIERS:
        return "multiplier code 3"
    if rec.enabled and rec.master_lost:
        return "feed enabled with master lost"
    return None


def sequence_gap(prev: Record, rec: Record) -> int:
    """The sequence numbers between `prev` and `rec` (records lost or dropped), mod 65536."""
    return (rec.sequence - prev.sequence - 1) % SEQUENCE_MODULO


def _link(prev: Record, rec: Record) -> Tuple[Optional[int], Optional[str]]:
    """(delta, fault): the delta `continuity` gives, and why the pair is impossible."""
    if record_fault(prev) is not None or record_fault(rec) is not None:
        return None, None
    gap = sequence_gap(prev, rec)
    epochs = (rec.epoch - prev.epoch) % EPOCH_MODULO
    delta = wrap_s32(rec.position - prev.position)
    if epochs == 0 and gap <= SAME_EPOCH_MAX_GAP:
        if (rec.axis, rec.multiplier, rec.enabled) != (prev.axis, prev.multiplier, prev.enabled):
            return None, "axis, multiplier or enable changed within an epoch"
    elif not (epochs == 1 and gap == 0):
        return None, None  # epochs the host did not see: a new baseline
    if delta != 0:
        if not rec.enabled:
            return None, "moved while disabled"
        if rec.axis == 0:
            return None, "moved without an axis"
        if delta % rec.multiplier != 0:
            return None, f"moved {delta}, no multiple of the multiplier {rec.multiplier}"
    return delta, None


def continuity(prev: Record, rec: Record) -> Optional[int]:
    """The motion `rec` adds to its axis after `prev` (the record received before it), or
    None: `rec` is a new baseline (it continues nothing). host/README.md's "Feed bookkeeping"
    gives the rule and why it never credits motion to another axis. 0 for a record that
    continues without motion (disabled, no axis, the wheel at rest). Records the device
    cannot send (`record_fault`, `pair_fault`) give None."""
    return _link(prev, rec)[0]


def pair_fault(prev: Record, rec: Record) -> Optional[str]:
    """Why `rec` cannot follow `prev` from the same device, or None. Only for records that
    each could be sent (`record_fault` is None for both)."""
    return _link(prev, rec)[1]
