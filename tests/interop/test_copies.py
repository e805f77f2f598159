"""Copies of genuine records, a stale Y record, a missed boot-up, a quick power cycle and a
blocked transmit path (findings 1-5 below): the host component (`host/src`, LinuxCNC's `hal`
replaced by host/tests/fake_hal.py, which logs every pin change with its time) against the
release image on the emulated board, through the SLCAN relay of tools/rig/relay.py, which
drops frames, re-sends exact copies of genuine feed records and speaks as another node.

Each test asserts the feed contract as feed record v2 and its session rule make it hold (the
README's "lost, duplicated and replayed frames never move an axis"), and each failed on the
code before them, with the failure its docstring names:

1. copies of genuine X records of any age (k records back, k around every wrap of the
   sequence byte and beyond it) never move X backwards, never credit more than was turned,
   and never leave the wheel dead (the next detent is credited at once);
2. a Y record 255 records and 7 selector moves old, re-sent while X is selected, never moves Y;
3. after a power cycle whose boot-up the component missed, started by another node's NMT
   start, the component configures the device (0x1016 written and read back) before it
   enables the feed again, and a stopped component then makes the device stop the feed;
4. a quick power cycle costs no more than the component's configuration: every detent turned
   after the feed is enabled again is credited, the first one soon after the configuration,
   and no frame counts as bad;
5. a feed stop by a blocked transmit path is reported: the device's EMCY 0x8100 once its
   frames get out, the component's `feed stopped by the device` log line naming the transmit
   path, its `feed-stops` pin counting 1 and `stop-reason` showing 2.

A later test covers a hole the feed checker found after these: a bus that takes a frame now
and then, never idle for the stall watch's 100 ms, delivers the records ever later.

Names the fixes introduced (the `feed-stops` and `stop-reason` pins, the log line, EMCY 0x8100)
are those of README.md and host/README.md. The records are read with the component's own
decoder (`canopen_handwheel.core.Record`), whatever their layout; the relay decodes none.

`power` and `hold` are commands of the board's control line; its `turn` turns a detent in
2.4 ms (four edges 600 us apart), so at the default 2 ms inhibit time every detent of a
`turn` is a feed record of its own, about 400 a second of the board's time (which runs
slower than the host's on a busy machine).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, List, Optional

import pytest

from canopen_handwheel.core import GATE_HOLD, Record, own_sdo_ids
from rig import (
    AXES,
    BOOTUP,
    EMCY,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NMT,
    NMT_START,
    OPERATIONAL,
    ROOT,
    SDO_RX,
    START_TIMEOUT,
    TPDO1,
    Board,
    Frame,
    Stimulus,
)
from rig.component import HalLog, capture_problems, end_component
from rig.relay import Relay, is_bootup
from test_host_component import COMPONENT_RUN

CONSUMER_TIMEOUT = 0.5  # what the component tells the device: 5 x its 100 ms heartbeat
EMCY_MASTER_LOST = 0x8130
EMCY_TRANSMIT_BLOCKED = 0x8100  # README's Emergency codes
STOP_TRANSMIT_BLOCKED = 2  # `stop-reason` for it


def decode(frame: Frame) -> Record:
    return Record.decode(bytes(frame.data))


class Host:
    """The emulated board, the relay on its CAN port, the stimulus line and the component
    on the relay's channel (`enable` true)."""

    def __init__(self, board: Board, tmp: Path, args: tuple = ()) -> None:
        self.board = board
        self.relay = Relay(board)
        self.relay.device.wait_id(HEARTBEAT, bytes([BOOTUP]), timeout=START_TIMEOUT)
        self.stim = Stimulus(board.stim_port, board)
        self.hal = HalLog(tmp / "hal.log")
        self.log_path = tmp / "component.log"
        self.err = open(self.log_path, "w")
        script = COMPONENT_RUN.format(
            tests=str(ROOT / "host" / "tests"), src=str(ROOT / "host" / "src")
        )
        env = dict(os.environ, FAKE_HAL_LOG=str(self.hal.path), FAKE_HAL_SET="enable=1")
        self.capture = tmp / "capture.log"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", script, "--interface", "slcan", "--channel"]
            + [self.relay.channel, "--axes", "xyz", "--capture", str(self.capture)]
            + list(args),
            env=env,
            stderr=self.err,
        )

    # Waiting ---------------------------------------------------------------------------------

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait(self, pred: Callable[[], bool], timeout: float) -> bool:
        """Polls `pred` (the pins' log, the relay's records) until true or `timeout`."""
        deadline = time.monotonic() + timeout
        while True:
            if pred():
                return True
            assert self.proc.poll() is None, f"the component ended:\n{self.log()[-3000:]}"
            self.relay.check()
            if time.monotonic() > deadline:
                return False
            time.sleep(0.005)

    def must(self, pred: Callable[[], bool], timeout: float, what: str) -> None:
        assert self.wait(pred, timeout), f"no {what} within {timeout} s:\n{self.log()[-3000:]}"

    def counts(self, axis: str) -> int:
        return self.hal.number(f"axis.{axis}.jog-counts")

    def counts_written(self) -> bool:
        """X's counts last changed more than a few pin steps ago (`core.GATE_HOLD`: a
        record's position can show a step before its counts)."""
        changes = self.hal.history("axis.x.jog-counts")
        return not changes or time.monotonic() - changes[-1][0] > 4 * GATE_HOLD

    def enabled(self, axis: str = "x") -> bool:
        return self.hal.value(f"axis.{axis}.jog-enable") == "True"

    def newest(self) -> Frame:
        newest = self.relay.newest_record()
        assert newest is not None, "no feed record yet"
        return newest

    def caught_up(self) -> bool:
        """The component shows the newest genuine record's position (it took it)."""
        newest = self.relay.newest_record()
        return newest is not None and self.hal.number("position") == decode(newest).position

    def detent_x100(self, at: int, what: str) -> tuple:
        """(X's counts before, the record, credited): one detent turned at x100 from
        position `at`, the device's record of it, and whether X was credited its 100 counts
        within LIVELY of that record passing the relay."""
        counts, mark = self.counts("x"), self.relay.device.mark()
        self.stim.turn(1)
        record = self.relay.device.wait_for(
            lambda f: f.id == TPDO1 and decode(f).position == at + 100, since=mark, what=what
        )
        return counts, record, self.wait(lambda: self.counts("x") == counts + 100, LIVELY)

    def verdicts(self) -> tuple:
        """({a feed record's bytes: the rule's last verdict on it}, the rule's staleness
        time), by a replay of the component's capture so far (the component flushes it every
        round); an empty map if it does not read yet."""
        from canopen_handwheel import capture as captures
        from canopen_handwheel import decode

        try:
            replay = decode.replay([captures.read(p) for p in captures.files_of(self.capture)])
        except (OSError, ValueError):  # a line cut off by the component's next write
            return {}, 0.0
        judged = {
            line.frame.data: line.verdict
            for line in replay.lines
            if line.verdict is not None and line.frame.id == TPDO1
        }
        return judged, replay.core.stale_after

    def verdict_of(self, record: Frame) -> str:
        """What the host's rule made of `record` (`verdicts`)."""
        verdict = self.verdicts()[0].get(bytes(record.data))
        return verdict.text if verdict is not None else "not in the capture (yet)"

    def busy_host_drop(self, record: Frame) -> Optional[str]:
        """The rule's verdict on `record` if it dropped the record because the component was
        held up, else None: a record from a backlog (its receive path not found empty for
        over BACKLOG_LIMIT), one its probes could not date (they came late), or one the rule
        found stale although the device's record before
        it passed the relay less than the staleness time before it and the rule took that
        one (had it refused it, the staleness could be the rule's own doing)."""
        from canopen_handwheel import decode as rule

        judged, stale_after = self.verdicts()
        verdict = judged.get(bytes(record.data))
        if verdict is None:
            return None
        if "from a backlog" in verdict.text:
            return verdict.text
        if "not dated" in verdict.text:
            # The relay here holds nothing: a record the probes could not date came after
            # the component's own probes were late (its SDO worker held up).
            return verdict.text
        if verdict.kind == rule.BASELINE and "nothing of the session" in verdict.text:
            before = [f for f in self.relay.records_since(0) if f.t < record.t]
            taken = (rule.CREDITED, rule.AT_REST, rule.BASELINE, rule.NOT_CREDITED)
            previous = judged.get(bytes(before[-1].data)) if before else None
            if previous is not None and previous.kind in taken:
                gap = record.t - before[-1].t
                if gap < stale_after:
                    return f"{verdict.text} (at the relay: {gap:.3f} s after one it took)"
        return None

    def select(self, axis: str) -> int:
        """Moves the switch; returns the index (in `relay.records`) of the first record that
        shows the new axis."""
        mark = self.relay.record_count()
        self.stim.axis(axis)
        found: List[Frame] = []

        def shown() -> bool:
            found[:] = [f for f in self.relay.records_since(mark) if decode(f).axis == AXES[axis]]
            return bool(found)

        self.must(shown, FRAME_TIMEOUT, f"feed record showing axis {axis}")
        return found[0].seq

    def first_enabled(
        self, since: int = 0, after: float = 0.0, timeout: float = FRAME_TIMEOUT
    ) -> Frame:
        """The first record with the feed enabled at index `since` or later, received
        after the time `after`."""
        found: List[Frame] = []

        def shown() -> bool:
            found[:] = [
                f for f in self.relay.records_since(since) if f.t > after and decode(f).enabled
            ]
            return bool(found)

        self.must(shown, timeout, "enabled feed record")
        return found[0]

    def close(self) -> None:
        end_component(self.proc)
        self.err.close()
        self.stim.close()
        self.relay.close()


@contextmanager
def started(board: Board, tmp: Path, mult: int = 1, args: tuple = ()) -> Iterator[Host]:
    """The component (with the options `args`) on X at `mult`, the feed enabled; closed
    (with the relay) on exit."""
    host = Host(board, tmp, args)
    try:
        host.stim.axis("x")
        host.stim.mult(mult)
        host.must(host.enabled, 60, "jog-enable of X (configured, started, feed enabled)")
        yield host
    finally:
        host.close()
        # Shown with a failure (pytest prints a failed test's output).
        tail = "\n".join(host.log().splitlines()[-40:])
        print(f"--- last lines of {host.log_path} ---\n{tail}")
    # The session's capture replays to the pins the component wrote.
    assert capture_problems(host.capture, host.hal) == []


@pytest.fixture
def host(board, tmp_path):
    with started(board, tmp_path) as h:
        yield h


@pytest.fixture
def host100(board, tmp_path):
    with started(board, tmp_path, mult=100) as h:
        yield h


# Finding 1 ------------------------------------------------------------------------------------

# How far back the copies are: around every wrap of an 8-bit sequence (128, 256, 512), the
# 249..255 that read as "a few ahead", and far beyond it (1000 records: 2.5 s of turning).
COPY_AGES = (1000, 129, 200, 249, 250, 255, 256, 257, 511, 512)
TURN = 40  # detents turned fast before each copy (more come before the first)
# The detent after a copy must be credited this soon after its record passed the relay.
LIVELY = 0.5
# The component's view of the newest record once it has passed the relay (a busy host).
CATCH_UP = 3.0
# Detents in a row a busy host may drop after a copy (`Host.busy_host_drop`) before the
# wheel counts as dead.
BUSY_RETRIES = 3


def test_copies_of_any_age_never_move_x_backwards_nor_deaden_the_wheel(host100):
    """Finding 1: X turned fast at x100 (a record a detent at the 2 ms inhibit time); for
    every k of COPY_AGES, with X at rest, the genuine record from k records back is re-sent
    once, right after a genuine record, and then one detent is turned. Per k, X's counts
    never step back, never exceed what the records since the k's start say was turned, and
    the detent after the copy is credited (exactly its 100 counts) within LIVELY of its record
    passing the relay: the wheel is not dead. A detent the rule dropped because the component
    was held up (`Host.busy_host_drop`, from a replay of its capture) is excused, and the
    next one must count, up to BUSY_RETRIES in a row. Over all, X is credited at most what
    was turned while enabled (exactly that unless a busy host made the component take a
    record from a backlog, a baseline). Before the fix a copy 249-255 (or 511) back read as
    a few records ahead and was credited backwards, 129-248 (and 1000) back became the
    reference and left the wheel dead for up to 2 s, 256 (512) back had the newest's
    sequence number, a bad record that made the next one a baseline."""
    h = host100
    relay = h.relay
    first = h.first_enabled().seq  # copies only of records of the feed enabled
    report = []
    h.wait(h.caught_up, CATCH_UP)
    total_counts, total_position = h.counts("x"), decode(h.newest()).position
    for k in COPY_AGES:
        # In step: the component took the newest record (a copy before may have left it
        # waiting out its order reference).
        h.wait(h.caught_up, CATCH_UP)
        start_counts = h.counts("x")
        start_position = decode(h.newest()).position
        since = time.monotonic()
        # Fast turning: at least k records of the enabled feed, and some motion each time.
        h.stim.turn(TURN)
        while relay.record_count() - first <= k + 2:
            h.stim.turn(min(300, k + 3 - (relay.record_count() - first)))
        h.must(h.caught_up, CATCH_UP, "the component at the newest record after the turn")
        copy = relay.replay(k, since=first)
        assert copy.wait(FRAME_TIMEOUT), f"the copy {k} back was never sent"
        # The copy follows a genuine record: X's counts are read once the component took
        # that record and wrote its counts, or the detent's +100 would be measured from
        # counts one record behind (and read +200).
        h.wait(h.caught_up, CATCH_UP)
        h.wait(h.counts_written, CATCH_UP)
        before = decode(h.newest()).position
        counts, detent, lively = h.detent_x100(before, "the record of the detent after the copy")
        late = time.monotonic() - detent.t
        busy = []  # the detents a busy host dropped, by the rule
        while not lively and len(busy) < BUSY_RETRIES:
            verdict = h.busy_host_drop(detent)
            if verdict is None:
                break
            # The component was held up: the record is only a baseline, by design (nothing
            # moves late). The next detent must count.
            busy.append(verdict)
            h.must(h.caught_up, CATCH_UP, "the component at the dropped detent's record")
            before += 100
            counts, detent, lively = h.detent_x100(before, "the detent after a dropped one")
            late = time.monotonic() - detent.t
        if busy:
            print(f"k={k}: {len(busy)} detent(s) dropped by a busy host: {busy}")
        truth = before + 100 - start_position
        values = [start_counts] + [int(v) for _, v in h.hal.history("axis.x.jog-counts", since)]
        backwards = [b - a for a, b in zip(values, values[1:]) if b < a]
        over = [v - start_counts for v in values if v - start_counts > truth]
        problems = []
        if backwards:
            problems.append(f"stepped back {backwards}")
        if over:
            problems.append(f"credited {max(over)} of {truth} turned")
        if not lively:
            problems.append(
                f"the detent after the copy not credited {late:.2f} s after its record "
                f"(X {h.counts('x') - counts:+d}; the rule: {h.verdict_of(detent)})"
            )
        if problems:
            copied, newest = decode(copy.copy), decode(copy.newest)
            report.append(
                f"k={k} (copy: position {copied.position} sequence {copied.sequence}, after "
                f"position {newest.position} sequence {newest.sequence}): " + "; ".join(problems)
            )
    h.wait(h.caught_up, CATCH_UP)
    turned = decode(h.newest()).position - total_position
    credited = h.counts("x") - total_counts
    print(f"X credited {credited} of {turned} turned, {len(COPY_AGES)} copies")
    assert not report, "copies moved X:\n" + "\n".join(report)
    assert credited <= turned


# Finding 2 ------------------------------------------------------------------------------------

# Copies of records of the first Y selection, this many records back: 255 brought the 8-bit
# sequence round to "the next one"; the others are its neighbours.
Y_COPY_AGES = (255, 254, 256, 253, 257)
SWITCH_MOVES = "xyxyxyx"  # from Y: seven moves, ending on X


def test_a_y_record_seven_moves_and_255_records_old_never_moves_y(host):
    """Finding 2: Y selected and turned 3 detents (credited), a few records at rest; then 7
    switch moves (X, Y, ... X: the 3-bit epoch comes round) and X turned fast; a record of
    that first Y selection is re-sent while X is selected, exactly 255 records after it
    (then 254, 256, 253 and 257). Y's counts must not change, X's never step back. Before
    the fix the 255-back copy read as the previous epoch's final record, the one right
    after the newest, and Y was credited minus all the motion since."""
    h = host
    relay = h.relay
    y_first = h.select("y")
    h.stim.turn(3)
    h.must(lambda: h.counts("y") == 3, FRAME_TIMEOUT, "Y +3")
    # A few more records of this selection at rest (the event timer's).
    h.must(lambda: relay.record_count() - y_first >= 8, FRAME_TIMEOUT, "8 records of Y")
    y_last = relay.record_count() - 1
    y_records = relay.records_since(y_first)[: y_last - y_first + 1]
    assert all(decode(f).axis == AXES["y"] for f in y_records)
    y_counts = h.counts("y")
    x_counts = h.counts("x")
    moves_at = time.monotonic()
    for axis in SWITCH_MOVES:
        h.select(axis)
    h.must(lambda: h.enabled("x"), FRAME_TIMEOUT, "jog-enable of X after the moves")

    def of_y(copy: Frame, newest: Frame) -> bool:
        return y_first <= copy.seq <= y_last

    copies = [relay.replay(k, source=of_y) for k in Y_COPY_AGES]
    for _ in range(20):
        if copies[-1].fired.is_set():
            break
        h.stim.turn(50)
    assert all(c.fired.is_set() for c in copies), f"copies not sent: {copies}"
    h.must(h.caught_up, CATCH_UP, "the component at the newest record")
    y_changes = h.hal.history("axis.y.jog-counts", moves_at)
    x_values = [x_counts] + [int(v) for _, v in h.hal.history("axis.x.jog-counts", moves_at)]
    x_back = [b - a for a, b in zip(x_values, x_values[1:]) if b < a]
    sent = [
        f"{c.back} back: sequence {decode(c.copy).sequence} after {decode(c.newest).sequence}"
        for c in copies
    ]
    assert y_changes == [] and h.counts("y") == y_counts, (
        f"Y moved while X was selected: {y_counts} -> {h.counts('y')} "
        f"(changes {y_changes}); copies {sent}"
    )
    assert not x_back, f"X stepped back {x_back}; copies {sent}"


# Finding 3 ------------------------------------------------------------------------------------

UPLOAD = 0x40
DOWNLOAD = 0x20


# The component's own SDO channel to the device (the second SDO server, master node 1:
# `core.own_sdo_ids`), where its feed writes and probes go.
OWN_SDO_RX = own_sdo_ids(1)[0]


def sdo_requests(frames: List[Frame]) -> List[tuple]:
    """(time, "up"/"down", index, sub, data bytes 4-7) of the SDO initiate requests sent to
    the device, on the default channel or the component's own."""
    out = []
    for f in frames:
        if f.id not in (SDO_RX, OWN_SDO_RX) or len(f.data) != 8:
            continue
        kind = {UPLOAD: "up", DOWNLOAD: "down"}.get(f.data[0] & 0xE0)
        if kind is not None:
            out.append((f.t, kind, f.data[1] | f.data[2] << 8, f.data[3], f.data[4:8]))
    return out


def configuration_before_enable(frames: List[Frame]) -> Optional[str]:
    """Why the requests in `frames` do not configure the device before the first 0x2000 = 1
    (a 0x1016 entry written, then read back), or None."""
    requests = sdo_requests(frames)
    enable = next(
        (i for i, r in enumerate(requests) if r[1:4] == ("down", 0x2000, 0) and r[4][0] == 1),
        None,
    )
    if enable is None:
        return "no 0x2000 = 1 written"
    before = requests[:enable]
    written = [(i, r[3]) for i, r in enumerate(before) if r[1:3] == ("down", 0x1016)]
    read_back = [
        sub for i, sub in written if any(r[1:4] == ("up", 0x1016, sub) for r in before[i + 1 :])
    ]
    if read_back:
        return None
    shown = [f"{r[1]} {r[2]:04X}:{r[3]}" for r in before[-12:]] or ["nothing"]
    return (
        f"0x2000 = 1 written with no 0x1016 entry written and read back before it since the "
        f"power cycle (requests before it: {', '.join(shown)})"
    )


FREEZE = 1.5  # s the component is stopped
FROZEN_DETENTS = 6  # one every 50 ms while frozen
STOP_SLACK = 0.3  # s beyond the consumer timeout: reading the board's clock


def board_ms(board: Board) -> float:
    """The board's emulated time, ms since its power-on."""
    return float(board.status()["ms"])


def test_a_device_started_by_another_node_after_a_lost_boot_up_is_configured(host, board):
    """Finding 3: board `power`, the boot-up dropped by the relay, then an NMT "start all"
    from another node (the test, on the bus): the component must configure the device
    (0x1016 written and read back) before it writes 0x2000 = 1, and say so in its log. Then
    the component is stopped (SIGSTOP, 1.5 s) while X turns a detent every 50 ms for 0.3 s:
    the device must stop the feed (a record with status bit 3, EMCY 0x8130) within the
    consumer timeout of the freeze on the board's clock (plus STOP_SLACK: the clock is read
    over the control line). Before the fix the component only wrote 0x2000 = 1 and the
    device, with no consumer entry, kept feeding."""
    h = host
    relay = h.relay
    boot = relay.drop(is_bootup())
    device_mark, host_mark = relay.device.mark(), relay.host.mark()
    records_mark = relay.record_count()
    log_start = len(h.log())
    board.control("power")
    assert boot.wait(FRAME_TIMEOUT), "no boot-up after the power cycle"
    relay.send(NMT, bytes([NMT_START, 0]))
    relay.device.wait_id(HEARTBEAT, bytes([OPERATIONAL]), since=device_mark)
    # The feed enabled again (only the component writes 0x2000 = 1).
    enabled = h.first_enabled(records_mark, after=boot.frames[0].t, timeout=10)
    problems = []
    why = configuration_before_enable(relay.host.frames(since=host_mark))
    if why is not None:
        problems.append(why)
    if not re.search(r"configured", h.log()[log_start:]):
        problems.append("the component's log says nothing configured after the power cycle")
    # Frozen while turning (the stop comes at the earliest 0.4 s on: the turning is over).
    stop_mark = relay.device.mark()
    h.proc.send_signal(signal.SIGSTOP)
    frozen = time.monotonic()
    try:
        frozen_ms = board_ms(board)
        for i in range(FROZEN_DETENTS):
            h.stim.turn(1)
            time.sleep(max(0.0, frozen + 0.05 * (i + 1) - time.monotonic()))
        stopped = h.wait(
            lambda: any(decode(f).master_lost for f in relay.device.frames(TPDO1, stop_mark)),
            frozen + FREEZE - time.monotonic(),
        )
        stopped_ms = board_ms(board)
        time.sleep(max(0.0, frozen + FREEZE - time.monotonic()))
    finally:
        h.proc.send_signal(signal.SIGCONT)
    after = relay.device.frames(since=stop_mark)
    records = [f for f in after if f.id == TPDO1]
    master_lost = EMCY_MASTER_LOST.to_bytes(2, "little")
    emcy = [f for f in after if f.id == EMCY and f.data[:2] == master_lost]
    if not stopped or not emcy:
        fed = sum(1 for f in records if decode(f).enabled)
        problems.append(
            f"the device kept feeding with the component stopped {FREEZE} s: {fed} enabled "
            f"records of {len(records)}, {'one' if stopped else 'none'} with status bit 3, "
            f"{'no' if not emcy else 'an'} EMCY 0x8130"
        )
    else:
        # On the board's clock: from the freeze (the last heartbeat was before it) to a
        # moment after the record showed the stop.
        delay = (stopped_ms - frozen_ms) / 1000
        print(f"feed stopped within {delay:.3f} s of the board's time after the freeze")
        if delay > CONSUMER_TIMEOUT + STOP_SLACK:
            problems.append(f"the feed stopped {delay:.3f} s after the freeze (board's time)")
    print(f"power cycle: feed enabled again {enabled.t - boot.frames[0].t:.3f} s after the boot-up")
    assert not problems, "\n".join(problems)


# Finding 4 ------------------------------------------------------------------------------------

DETENT_PERIOD = 0.05  # one detent per 50 ms from the power-on
DETENTS = 60
# From the end of the configuration (the component's NMT start) to the first credit: the
# record that shows the device started, 0x2000 = 1 and its record, the next detent (50 ms).
CREDIT_SLACK = 0.4


def test_a_quick_power_cycle_costs_only_the_configuration(host, board):
    """Finding 4: the sequence brought to 100..130 records (the last record before the
    cut), then board `power` while X turns a detent every 50 ms from the power-on for 3 s.
    After the component reconfigured the device, every detent turned after the feed is
    enabled again is credited, the first credit comes at most CREDIT_SLACK after the end of
    the configuration (its NMT start), every detent turned from then on is credited, and
    `frames-bad` does not rise. Before the fix the
    new life's records (sequence 8 on) lay 1..128 behind the old reference, which outlived
    the boot-up for 2 s: the wheel was dead for 2 s and every such record counted bad."""
    h = host
    relay = h.relay
    while decode(h.newest()).sequence < 100:
        h.stim.turn(min(10, 100 - decode(h.newest()).sequence))
        h.must(h.caught_up, CATCH_UP, "the component at the newest record")
    last_sequence = decode(h.newest()).sequence
    bad_before = h.hal.number("frames-bad")
    device_mark, host_mark = relay.device.mark(), relay.host.mark()
    records_mark = relay.record_count()
    board.control("power")
    powered = time.monotonic()
    turned: List[float] = []  # when each detent's `turn` was answered (its edges were before)
    for i in range(DETENTS):
        h.stim.turn(1)
        turned.append(time.monotonic())
        time.sleep(max(0.0, powered + DETENT_PERIOD * (i + 1) - time.monotonic()))
    boot = relay.device.wait_id(HEARTBEAT, bytes([BOOTUP]), since=device_mark)
    h.must(h.caught_up, CATCH_UP, "the component at the newest record after the turning")
    start = relay.host.wait_for(
        lambda f: f.id == NMT and f.data[:1] == bytes([NMT_START]) and f.t > boot.t,
        since=host_mark,
        what="the component's NMT start after the boot-up",
    )
    enabled = h.first_enabled(records_mark, after=boot.t)
    truth = decode(h.newest()).position - decode(enabled).position
    counts_at_boot = int(h.hal.at("axis.x.jog-counts", boot.t) or 0)
    credited = h.counts("x") - counts_at_boot
    credits = h.hal.history("axis.x.jog-counts", boot.t)
    configured = start.t - boot.t
    first_credit = credits[0][0] - boot.t if credits else None
    bad = h.hal.number("frames-bad") - bad_before
    # Detents turned well after the configuration ended: the feed was enabled by then.
    due = sum(1 for t in turned if t > start.t + CREDIT_SLACK)
    print(
        f"power cycle after sequence {last_sequence}: configured {configured:.3f} s after the "
        f"boot-up, feed enabled {enabled.t - boot.t:.3f} s, first credit "
        f"{'never' if first_credit is None else f'{first_credit:.3f} s'}; credited "
        f"{credited} of {truth} (of {due} turned from {CREDIT_SLACK} s after the configuration "
        f"on); frames-bad +{bad}"
    )
    problems = []
    if first_credit is None or first_credit > configured + CREDIT_SLACK:
        problems.append(
            f"first credit {'never' if first_credit is None else f'{first_credit:.3f} s'} "
            f"after the boot-up, the configuration took {configured:.3f} s"
        )
    if credited != truth:
        problems.append(f"credited {credited} of {truth} turned with the feed enabled")
    if credited < due:
        problems.append(
            f"credited {credited} of the {due} detents turned from {CREDIT_SLACK} s after the "
            "configuration on"
        )
    if bad:
        problems.append(f"frames-bad +{bad} for a healthy device")
    assert not problems, f"after sequence {last_sequence}: " + "; ".join(problems)


# Finding 5 ------------------------------------------------------------------------------------

HOLD_MS = 150


def test_a_feed_stop_by_a_blocked_transmit_path_is_reported(host, board):
    """Finding 5: a 150 ms bus hold (`hold`: the node's frames wait, the master's pass)
    while the feed is enabled and X turns: the device stops the feed after 100 ms and, once
    its frames get out again, sends EMCY 0x8100 (manufacturer byte 0 = 0x01); the component
    logs `feed stopped by the device: ...` naming the transmit path, its `feed-stops` pin
    counts 1 and `stop-reason` shows 2. Before the fix nothing told: no EMCY, no log line,
    no pin, and the component enabled the feed again within milliseconds."""
    h = host
    relay = h.relay
    counts = h.counts("x")
    h.stim.turn(1)
    h.must(lambda: h.counts("x") == counts + 1, FRAME_TIMEOUT, "X +1")
    device_mark = relay.device.mark()
    log_start = len(h.log())
    held = time.monotonic()
    board.control(f"hold {HOLD_MS}")
    for _ in range(4):
        h.stim.turn(1)  # 25 ms after its last edge on the board's clock
    problems = []
    try:
        emcy = relay.device.wait_for(
            lambda f: f.id == EMCY and f.data[:2] == EMCY_TRANSMIT_BLOCKED.to_bytes(2, "little"),
            since=device_mark,
            what="EMCY 0x8100",
        )
        if emcy.data[3] != 0x01:
            problems.append(f"EMCY 0x8100 with manufacturer byte {emcy.data[3]:#04x}: {emcy}")
    except AssertionError:
        emcies = relay.device.frames(EMCY, since=device_mark)
        problems.append(f"no EMCY 0x8100 after the hold (EMCYs: {emcies})")
    line = re.compile(r"^canopen-handwheel: feed stopped by the device\b.*transmit", re.M | re.I)
    if not h.wait(lambda: bool(line.search(h.log()[log_start:])), 2.0):
        problems.append(
            "no log line `feed stopped by the device: ...` naming the transmit path; since "
            f"the hold: {h.log()[log_start:].strip()!r}"
        )
    if not h.wait(lambda: h.hal.value("feed-stops") == "1", 2.0):
        problems.append(f"feed-stops is {h.hal.value('feed-stops')}, not 1")
    reasons = [v for _, v in h.hal.history("stop-reason", held)]
    if str(STOP_TRANSMIT_BLOCKED) not in reasons:
        problems.append(f"stop-reason never showed {STOP_TRANSMIT_BLOCKED} (changes {reasons})")
    assert not problems, "the stop by the held bus went unreported:\n" + "\n".join(problems)


# A trickling bus --------------------------------------------------------------------------------

TRICKLE_MS = 95  # just under the stall watch's 100 ms: a frame gets out before it runs out
TRICKLE_TURN = 20  # detents turned at once: 20 records, 48 ms of the board's time
LATE = 1.0  # s after the turn: no credit later (the old watch's queue took 1.9 s of board time)
TRICKLE_WATCH = 3.0  # s the bus trickles while the test watches


def test_a_trickling_bus_moves_nothing_late(host, board):
    """A bus that leaves the node one frame per 95 ms (`trickle`: other traffic takes the
    rest) while X turns 20 detents at once. The transmit path never runs empty, so the device
    counts it as blocked 100 ms after the turn: it stops the feed, drops the records that wait
    and reports EMCY 0x8100; X is credited at most the few records that got out meanwhile,
    none later than LATE after the turn. Before the fix the stall watch counted from the last
    frame that got out, never tripped, and the 20 records reached the component one per 95 ms,
    each credited, the last about 2 s after it was turned."""
    h = host
    relay = h.relay
    counts = h.counts("x")
    h.stim.turn(1)
    h.must(lambda: h.counts("x") == counts + 1, FRAME_TIMEOUT, "X +1")
    h.wait(h.caught_up, CATCH_UP)
    start = h.counts("x")
    device_mark = relay.device.mark()
    board.control(f"trickle {TRICKLE_MS}")
    try:
        h.stim.turn(TRICKLE_TURN)
        turned = time.monotonic()
        time.sleep(TRICKLE_WATCH)
        emcies = relay.device.frames(EMCY, since=device_mark)
    finally:
        board.control("trickle off")
    credits = [(t - turned, int(v) - start) for t, v in h.hal.history("axis.x.jog-counts", turned)]
    problems = []
    if not any(e.data[:2] == EMCY_TRANSMIT_BLOCKED.to_bytes(2, "little") for e in emcies):
        problems.append(f"no EMCY 0x8100 while the bus trickled (EMCYs: {emcies})")
    late = [(round(dt, 3), n) for dt, n in credits if dt > LATE]
    if late:
        problems.append(f"credited late (s after the turn, detents so far): {late}")
    credited = h.counts("x") - start
    if credited > 3:
        problems.append(f"{credited} of {TRICKLE_TURN} detents credited through a trickling bus")
    assert not problems, "; ".join(problems)
