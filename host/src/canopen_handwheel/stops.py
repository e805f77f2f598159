"""Feed stops the component did not ask for: their reasons (`STOP_REASONS`) and how the
core tells them apart (`stop_reason`)."""

from __future__ import annotations

from typing import Optional

# Feed stops the component did not ask for (`stop-reason`): why the device stopped the feed.
STOP_NONE = 0
STOP_MASTER_LOST = 1
STOP_TRANSMIT_BLOCKED = 2
STOP_MASTER_WRITE = 3
STOP_NOT_OPERATIONAL = 4
STOP_SESSION_ENDED = 5
STOP_REASONS = {
    STOP_MASTER_LOST: "master heartbeat lost (EMCY 0x8130)",
    STOP_TRANSMIT_BLOCKED: "transmit path blocked (EMCY 0x8100)",
    STOP_MASTER_WRITE: "disabled by a master write (0x2000 = 0)",
    STOP_NOT_OPERATIONAL: "the device left Operational",
    STOP_SESSION_ENDED: (
        "the session ended (a reset, a power cycle, another master's write, or the record "
        "sequence outran its pace)"
    ),
}
EMCY_MASTER_LOST = 0x8130
EMCY_TRANSMIT_BLOCKED = 0x8100
# Status bit 3 is set by both a lost master and a blocked transmit path; the EMCY that tells
# them apart may reach the host after the record (s to wait for it).
STOP_REASON_WAIT = 0.05


def stop_reason(master_lost: bool, emcy: Optional[int], left_operational: bool) -> int:
    """Why the device stopped the feed, from what the host saw since the feed was last on:
    the record's status bit 3 (a loss of communication), the last EMCY 0x8100 or 0x8130, a
    heartbeat other than Operational. Bit 3 without either EMCY: the master was lost (the
    device's own watch, whose EMCY a blocked path may have discarded). No bit 3: a master
    wrote 0x2000 = 0, unless the device left Operational, which disables the feed too."""
    if emcy == EMCY_TRANSMIT_BLOCKED:
        return STOP_TRANSMIT_BLOCKED
    if master_lost or emcy == EMCY_MASTER_LOST:
        return STOP_MASTER_LOST
    if left_operational:
        return STOP_NOT_OPERATIONAL
    return STOP_MASTER_WRITE
