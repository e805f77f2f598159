"""Bus outages against the feed contract: what the master receives after the node's frames
could not reach it, read with the host component's own rule.

The board's `hold` takes the bus with other traffic: the node's frames wait in its transmit
queue and mailboxes while the master's frames still reach it, so NMT commands and SDO writes
work inside the outage.

Every scenario turns the wheel forward only, so the safety property is: per axis, the motion
the host credits never decreases (no delta below zero) and never exceeds the motion turned on
that axis. The device stops the feed when its frames wait for the bus for more than
`TRANSMIT_STALL_MS` without its transmit path once running empty (a record that late carries
stale motion).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field, replace

import pytest

from canopen_handwheel.core import Record, continuity, record_fault
from rig import (
    AXES,
    BOOTUP,
    HEARTBEAT,
    NMT_PRE_OPERATIONAL,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    SDO_RX,
    SDO_TX,
    SELECT_TIMEOUT,
    TPDO1,
    feed_record,
)

ENABLED = 0x01
MASTER_LOST = 0x08

# The device's limit (handwheel_device::TRANSMIT_STALL_MS): frames that wait this long
# without the path once running empty stop the feed.
TRANSMIT_STALL_MS = 100

# SDO upload of 0x1000:0 (device type).
UPLOAD_DEVICE_TYPE = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
UPLOAD_REPLY = bytes([0x43, 0x00, 0x10, 0x00])
# SDO download of 0x2000:0 = 1 (one byte), sent without waiting for its reply.
ENABLE_REQUEST = bytes([0x2F, 0x00, 0x20, 0x00, 0x01, 0, 0, 0])


def hold_bus(rig, held: bool) -> None:
    """The node's frames stop reaching the master (`held`) or flow again: other traffic
    holds the bus, so the mailboxes wait (`hold on` / `hold off`)."""
    rig.board.control("hold on" if held else "hold off")


def emulated_ms(rig) -> float:
    """The board's emulated time (ms since its power-on)."""
    return float(rig.board.status()["ms"])


def let_pass(rig, ms: float) -> None:
    """Lets `ms` of the node's time pass: emulated time, read on the control line (it runs no
    faster than the wall clock, slower when the host is busy). Used where the node shows
    nothing to wait for: its frames are held."""
    until = emulated_ms(rig) + ms
    while emulated_ms(rig) < until:
        time.sleep(0.002)


def select_unseen(rig, axis: str) -> None:
    """Moves the axis switch and waits until the firmware's debouncing took the change: its
    log line `selection: axis N`, since `rig.select` cannot confirm over SDO while the
    node's frames are held."""
    start = len(rig.board.log())
    rig.stim.axis(axis)
    wait_log(rig, rf"selection: axis {AXES[axis]}, ", start)


def wait_log(rig, pattern: str, start: int) -> None:
    """Waits for the firmware's log line `pattern` after character `start` of its log
    (decoded from RTT): what the node did while its
    frames are held. Polled every millisecond: some waits must fit in a short hold."""
    line = re.compile(pattern)
    deadline = time.monotonic() + SELECT_TIMEOUT
    while not line.search(rig.board.log(), start):
        assert time.monotonic() < deadline, f"no log line /{pattern}/"
        time.sleep(0.001)


def turn_one_by_one(rig, detents: int) -> None:
    """One detent at a time. Each `turn` answers 25 ms after its last edge, so every detent
    is a record of its own (2 ms inhibit time)."""
    for _ in range(detents):
        rig.stim.turn(1)


def enabled_at_rest(rig, axis: str) -> int:
    """Feed on for `axis` (x1) with the wheel at rest; returns the recording mark of the
    first enabled record, at position 0: the host's baseline, so that every detent after it
    is credited."""
    rig.feed_on(axis)
    first = rig.frames.wait_for(
        lambda f: f.id == TPDO1 and feed_record(f).flags & ENABLED and feed_record(f).position == 0,
        what="the first enabled record",
    )
    return first.seq


def sequence_to(rig, target: int) -> int:
    """Brings the low byte of the feed record sequence (0x2031, the next record's) to `target`
    (at most 35 records ahead of 220), where the 8-bit sequence of the first record format
    wrapped (the 16-bit one carries on), and leaves the event timer off (records only on
    motion); returns the detents it turned. Records every 2 ms (the inhibit time) bring it
    near quickly, then one record a detent lands on it."""
    rig.write(0x1800, 5, 2, 2)
    deadline = time.monotonic() + 10
    while rig.read(0x2031) < 220:
        assert time.monotonic() < deadline, "the event timer sends no records"
    rig.write(0x1800, 5, 0, 2)
    turned = 0
    while (sequence := rig.read(0x2031)) % 256 != target:
        assert (target - sequence) % 256 <= 36, f"the sequence went past it: {sequence}"
        rig.stim.turn(1)
        turned += 1
    return turned


def settle(rig, since: int) -> None:
    """Waits until everything the node queued before now has reached the master: an SDO
    reply queues behind it (one transmit queue, first in first out), and the next feed
    record after the reply carries the present state. The request goes out raw and its reply
    is told by its content: a reply to an SDO request sent blind during the outage may still
    be on its way, and python-canopen's client would take it for the answer. Asked again
    while no reply comes (a queue still full refuses it)."""
    for attempt in range(10):
        mark = rig.frames.mark()
        rig.network.send_message(SDO_RX, UPLOAD_DEVICE_TYPE)
        try:
            reply = rig.frames.wait_for(
                lambda f: f.id == SDO_TX and f.data[:4] == UPLOAD_REPLY,
                timeout=0.5,
                since=mark,
                what="the reply to the upload of 0x1000",
            )
            break
        except AssertionError:
            # A transmit queue still full as the outage ends refuses the reply: ask again,
            # as a master does.
            if attempt == 9:
                raise
    # The feed is at rest once the event timer repeats a record unchanged.
    rig.frames.wait_for(
        lambda f: f.id == TPDO1 and repeats(rig.frames.frames(TPDO1, since=since), f),
        since=reply.seq + 1,
        what="a feed record repeated unchanged after the reply",
    )


def repeats(records, record) -> bool:
    """Whether `record` says what the feed record before it said (sequence aside)."""
    i = records.index(record)
    if i == 0:
        return False
    before, now = feed_record(records[i - 1]), feed_record(record)
    return replace(before, sequence=0) == replace(now, sequence=0)


@dataclass
class Credit:
    """What the host's rule credits to each axis byte from a stream of frames, delta by
    delta: `continuity` between consecutive feed records, a new baseline after a boot-up
    (as the component does) and after a record the device cannot send (`record_fault`).
    Without the component's staleness and speed bound, which only ever make a baseline or
    refuse a delta: it credits at least what the component would, so the safety check is the
    stricter for it."""

    totals: dict = field(default_factory=dict)
    steps: list = field(default_factory=list)  # (sequence, axis, delta, total after)

    @staticmethod
    def of(frames) -> "Credit":
        credit = Credit()
        prev = None
        for f in frames:
            if f.id == HEARTBEAT and f.data == bytes([BOOTUP]):
                prev = None
                continue
            if f.id != TPDO1:
                continue
            rec = Record.decode(bytes(f.data))
            if record_fault(rec) is not None:
                prev = None
                continue
            if prev is not None:
                delta = continuity(prev, rec)
                if delta:
                    total = credit.totals.get(rec.axis, 0) + delta
                    credit.totals[rec.axis] = total
                    credit.steps.append((rec.sequence, rec.axis, delta, total))
            prev = rec
        return credit

    def on(self, axis: str) -> int:
        return self.totals.get(AXES[axis], 0)

    def assert_safe(self, turned: dict, frames) -> None:
        """Forward turning only: no axis is ever moved back, and none gets more than was
        turned on it (so never another axis's turn)."""
        shown = stream(frames)
        backwards = [s for s in self.steps if s[2] < 0]
        assert not backwards, f"moved backwards (seq, axis, delta, total): {backwards}\n{shown}"
        for axis, total in self.totals.items():
            name = next(n for n, a in AXES.items() if a == axis)
            limit = turned.get(name, 0)
            assert total <= limit, (
                f"{name.upper()} credited {total}, turned {limit}: credits {self.named()}, "
                f"turned {turned}\n{shown}"
            )

    def named(self) -> dict:
        return {n: self.totals.get(a, 0) for n, a in AXES.items() if a}


def stream(frames) -> str:
    """The feed records and boot-ups as the master received them, for failure messages:
    (position, axis, multiplier, status flags, sequence), epoch and session; a run of records
    that repeat the one before (sequence aside) is shown once, with its length."""
    out = []
    last = None
    for f in frames:
        if f.id == TPDO1:
            r = feed_record(f)
            if last is not None and replace(r, sequence=0) == last and out[-1][1] >= 1:
                out[-1][1] += 1
                continue
            fields = (r.position, r.axis, r.multiplier, r.flags, r.sequence)
            out.append([f"{fields} e{r.epoch} s{r.session}", 1])
            last = replace(r, sequence=0)
        elif f.id == HEARTBEAT and f.data == bytes([BOOTUP]):
            out.append(["boot-up", 0])
            last = None
    shown = [text if n <= 1 else f"{text} x{n}" for text, n in out[-40:]]
    return f"records ({len(out)} runs, the last 40): " + ", ".join(shown)


# Quadrature levels, bit 0 = A, bit 1 = B; forward is A leading B: 0 -> 1 -> 3 -> 2 -> 0.
FORWARD = [1, 3, 2, 0]


def quick_detents(rig, detents: int) -> None:
    """Whole detents, quick enough for a hold shorter than the stall limit: as single edges
    (`ab`, about 2.5 ms of the board's time each), since `turn` answers only 25 ms after its
    last edge; the wheel rests at 00 before and after."""
    for _ in range(detents):
        for levels in FORWARD:
            rig.stim.ab(levels)


def fill_transmit_side(rig) -> int:
    """Fills the node's transmit side during a hold; returns how many SDO requests it sent:
    18, which get through the held bus, each answered with a reply that must wait (one
    mailbox and the 16-frame queue)."""
    for _ in range(18):
        rig.network.send_message(SDO_RX, UPLOAD_DEVICE_TYPE)
    return 18


# A hold shorter than the stall limit: the frames wait for less than that.
SHORT_HOLD_MS = 95


# NMT commands in an outage, as first reported -----------------------------------------------


@pytest.mark.parametrize("leave", [NMT_PRE_OPERATIONAL, NMT_STOP], ids=["preop", "stop"])
def test_nmt_stop_and_start_in_an_outage_never_give_y_turn_to_x(rig, leave):
    """The NMT stop and start as first reported: Operational, feed on X x1, turn 3; the bus
    held; 25 single detents (the transmit queue and mailboxes fill); NMT pre-operational (or
    stop) and start; a write of 0x2000 = 1 without waiting for its reply; Y, turn 7; then X, Y,
    X, Y, X (six switch changes in all); turn 2; the bus free. Truth: X 30, Y 7. Before the fix
    the start closed epochs without taking sequence numbers, so one missing number hid eight
    epochs and the host credited X 36, Y 0."""
    mark = enabled_at_rest(rig, "x")
    rig.stim.turn(3)
    rig.wait_position(3, since=mark)
    hold_bus(rig, True)
    turn_one_by_one(rig, 25)
    rig.nmt(leave)
    rig.nmt(NMT_START)
    rig.network.send_message(SDO_RX, ENABLE_REQUEST)
    select_unseen(rig, "y")
    rig.stim.turn(7)
    for axis in "xyxyx":
        select_unseen(rig, axis)
    rig.stim.turn(2)
    hold_bus(rig, False)
    settle(rig, mark)
    seen = rig.frames.frames(since=mark)
    credit = Credit.of(seen)
    print(f"credited {credit.named()}, steps {credit.steps}")
    credit.assert_safe({"x": 30, "y": 7}, seen)
    assert credit.on("x") >= 3, f"the 3 detents before the hold reach X: {stream(seen)}"


def test_reset_node_in_an_outage_never_moves_x_backwards(rig):
    """The reset node as first reported: the transmit queue full, NMT reset node, arranged
    so that the last record delivered before it has sequence 255 (the sequence at 239 when
    the bus is held, the heartbeat off: then one feed record waits in a mailbox and 16 in the
    queue); then start, a blind enable and 4 detents. Before the fix the full queue refused
    the boot-up, and the first record after the reset (sequence 0, the same epoch bits)
    continued sequence 255: the host moved X from where it was back to 4."""
    mark = enabled_at_rest(rig, "x")
    rig.write(0x1017, 0, 0, 2)  # no heartbeat: only feed records fill the transmit side
    turned = sequence_to(rig, 239)
    last = rig.frames.frames(TPDO1)[-1]
    assert feed_record(last).sequence == 238
    hold_bus(rig, True)
    turn_one_by_one(rig, 20)  # 17 of them fill the queue and the mailbox
    rig.nmt(NMT_RESET_NODE)
    rig.nmt(NMT_START)
    rig.network.send_message(SDO_RX, ENABLE_REQUEST)
    turn_one_by_one(rig, 4)
    hold_bus(rig, False)
    settle(rig, mark)
    seen = rig.frames.frames(since=mark)
    credit = Credit.of(seen)
    print(f"turned {turned} + 24, credited {credit.named()}, steps {credit.steps[-3:]}")
    credit.assert_safe({"x": turned + 24}, seen)
    assert credit.on("x") >= turned, f"the detents before the hold reach X: {stream(seen)}"


def test_reset_node_within_the_stall_limit_boots_up_first_and_breaks_the_sequence(rig):
    """The reset node above inside a hold shorter than the transmit stall limit, so that the
    reset's own handling is what is tested: the last record before the hold has sequence 255,
    SDO replies fill the transmit side, then NMT reset node, start, a blind enable and a
    detent; the hold ends by itself after 95 ms. Before the fix the full queue refused the
    boot-up and the first record after the reset (sequence 0, the same epoch bits) continued
    255: X moved back. The reset must discard what waits, so the boot-up is the first frame
    after the hold, and nothing after it continues what came before: X never moves back, and
    the detent after the enable is credited."""
    mark = enabled_at_rest(rig, "x")
    rig.write(0x1017, 0, 0, 2)  # no heartbeat: the last frame before the hold is a record
    turned = sequence_to(rig, 0)
    assert feed_record(rig.frames.frames(TPDO1)[-1]).sequence % 256 == 255
    held = rig.frames.mark()
    start = emulated_ms(rig)
    rig.board.control(f"hold {SHORT_HOLD_MS}")
    fill_transmit_side(rig)
    log = len(rig.board.log())
    rig.nmt(NMT_RESET_NODE)
    rig.nmt(NMT_START)
    rig.network.send_message(SDO_RX, ENABLE_REQUEST)
    wait_log(rig, r"SDO write 0x2000:0", log)  # the enable is in before the detent
    quick_detents(rig, 1)
    done = emulated_ms(rig) - start
    assert done < SHORT_HOLD_MS, f"the detent came {done:.1f} ms into the hold"
    settle(rig, mark)
    seen = rig.frames.frames(since=mark)
    credit = Credit.of(seen)
    print(f"turned {turned} + 1, credited {credit.named()}, steps {credit.steps[-3:]}")
    credit.assert_safe({"x": turned + 1}, seen)
    first = rig.frames.frames(since=held)[0]
    assert (first.id, first.data) == (HEARTBEAT, bytes([BOOTUP])), f"first after the hold: {first}"
    assert credit.on("x") == turned + 1, f"credited {credit.named()}: {stream(seen)}"


# Holds shorter and longer than the transmit stall limit ----------------------------------


def test_a_turn_on_another_axis_in_a_short_hold_reaches_that_axis(rig):
    """The outbox under a hold shorter than the transmit stall limit: X turned, Y selected,
    then the bus held and the transmit side filled with frames that wait, so records cannot
    be queued; Y turns, X is selected again and turns. Y's final state must reach the master
    before X's records, so that the host's rule credits each axis exactly its own turns, and
    the feed stays on. (This test held the bus for seconds before the stall limit, turning X
    30, Y 7 and X 2 in it; a hold that long now stops the feed: see `test_a_long_hold_stops_
    the_feed_and_credits_nothing_late`.) The hold is timed in the board's emulated
    time (`hold 95`; the test checks that the last detent came before it ended); 18 SDO
    requests fill the transmit side (a reply refused shows it was full). The selector change
    is awaited in the firmware's log."""
    rig.feed_on("x")
    rig.stim.turn(2)
    base = rig.wait_position(2, since=0)
    rig.select("y")
    start = emulated_ms(rig)
    rig.board.control(f"hold {SHORT_HOLD_MS}")
    replies = fill_transmit_side(rig)
    quick_detents(rig, 1)
    select_unseen(rig, "x")
    quick_detents(rig, 1)
    done = emulated_ms(rig) - start
    assert done < SHORT_HOLD_MS, f"the last detent came {done:.1f} ms into the hold"
    settle(rig, base.seq)
    seen = rig.frames.frames(since=base.seq)
    credit = Credit.of(seen)
    shown = stream(seen)
    assert credit.named() == {"x": 1, "y": 1, "z": 0, "w": 0, "v": 0}, f"{done:.1f} ms; {shown}"
    on_y = [
        feed_record(f).position for f in seen if f.id == TPDO1 and feed_record(f).axis == AXES["y"]
    ]
    assert on_y and on_y[-1] == 3, f"Y's final position reached the master: {on_y}"
    answered = [f for f in seen if f.id == SDO_TX and f.data[:4] == UPLOAD_REPLY]
    # The settle's reply among them; a full queue refuses a reply (the master would ask
    # again), and one refused shows the transmit side was full. The 17 places (a mailbox and
    # the queue) also hold the frames the device makes in the hold (the turns' records, and
    # the event timer's or a heartbeat when one falls due while the 18 requests are
    # answered): 15 to 17 replies fit.
    assert 15 <= len(answered) - 1 < replies, f"{len(answered) - 1} of {replies} replies"
    assert rig.read(0x2000) == 1, "the feed is still on: no stall"


def test_a_long_hold_stops_the_feed_and_credits_nothing_late(rig):
    """A hold longer than the transmit stall limit: whatever was turned during it reaches no
    axis after it (a record that waited that long carries stale motion), the feed is stopped
    (a record with status bit 3, feed disabled; 0x2000 reads 0), and the master can enable it
    again: the next turn is credited exactly."""
    mark = enabled_at_rest(rig, "x")
    rig.stim.turn(2)
    rig.wait_position(2, since=mark)
    hold_bus(rig, True)
    held = rig.frames.mark()
    turn_one_by_one(rig, 5)
    let_pass(rig, 3 * TRANSMIT_STALL_MS)
    turn_one_by_one(rig, 3)
    hold_bus(rig, False)
    settle(rig, held)
    seen = rig.frames.frames(since=mark)
    credit = Credit.of(seen)
    assert credit.named()["x"] == 2, f"credited {credit.named()}; {stream(seen)}"
    after = [feed_record(f) for f in rig.frames.frames(TPDO1, since=held)]
    stopped = [r for r in after if r.master_lost and not r.enabled]
    assert stopped, f"no record of the stopped feed after the hold: {after}"
    assert rig.read(0x2000) == 0, "the feed is off"
    position = after[-1].position
    again = rig.frames.mark()
    rig.write(0x2000, 0, 1, 1)
    rig.stim.turn(2)
    last = rig.frames.wait_for(
        lambda f: f.id == TPDO1 and feed_record(f).position == position + 2,
        since=again,
        what=f"X at {position + 2}",
    )
    assert feed_record(last).flags & (ENABLED | MASTER_LOST) == ENABLED, feed_record(last)
    seen = rig.frames.frames(since=mark)
    credit = Credit.of(seen)
    assert credit.named()["x"] == 4, f"credited {credit.named()}; {stream(seen)}"
