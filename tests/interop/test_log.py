"""The decoded defmt log (the board's RTT buffer -> defmt-print -> stderr of `cargo xtask
board`) shows the engine's NMT transitions (`NMT {} -> {}` in crates/canopen-slave)."""

from rig import (
    BOOTUP,
    HEARTBEAT,
    NMT_PRE_OPERATIONAL,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STOPPED,
)


def test_log_shows_the_nmt_transitions_in_order(rig):
    log = rig.board
    # Power-on: the boot-up frame went out with the entry to Pre-operational.
    at = log.wait_for_log(r"NMT Initialising -> PreOperational").end()
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    at = log.wait_for_log(r"NMT PreOperational -> Operational", start=at).end()
    rig.nmt_and_heartbeat(NMT_STOP, STOPPED)
    at = log.wait_for_log(r"NMT Operational -> Stopped", start=at).end()
    rig.nmt_and_heartbeat(NMT_PRE_OPERATIONAL, PRE_OPERATIONAL)
    at = log.wait_for_log(r"NMT Stopped -> PreOperational", start=at).end()
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    at = log.wait_for_log(r"NMT PreOperational -> Initialising", start=at).end()
    log.wait_for_log(r"NMT Initialising -> PreOperational", start=at)


def test_log_lines_are_decoded_with_their_level(rig):
    """defmt-print decoded the stream: a readable line with the INFO level marker."""
    line = rig.board.wait_for_log(r"^.*NMT Initialising -> PreOperational.*$").group(0)
    assert " INFO " in f" {line} ", line
