"""Another master on the bus while the host component jogs: the component (`host/src`,
LinuxCNC's `hal` replaced by host/tests/fake_hal.py) against the release image on the
emulated board, through the SLCAN relay of tools/rig/relay.py, with the test speaking as a
second master (a configuration tool or an HMI) on the relay's bus.

What the component configures must include everything that decides axis, sign and scale of
the motion it credits: a write of one of those by anyone ends the device's session (the
device's promise), and the component's next session sets them again and reads them back
before it enables the feed. Before that, the component opened its new session without
setting or reading the wheel's parameters: an HMI's write of 0x2020:4 = 1 (invert) made ten
detents forward move X by -10, a write of 0x2020:3 = 1 (one count per detent) by -40.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

from rig import FRAME_TIMEOUT, NODE_ID, SDO_RX, SDO_TX, TPDO1
from test_copies import decode, started

# An expedited SDO download of one byte: command specifier 0x2F.
DOWNLOAD_1 = 0x2F
DOWNLOAD_ANSWER = 0x60
# The wheel's parameters (README "Handwheel objects").
WHEEL = 0x2020
COUNTS_PER_DETENT = 3
INVERT = 4
# From the other master's write to the component's feed enabled again: the device's session
# ended, the component holds back while another master's SDO is under way (2 s), then
# configures the device again and enables the feed.
RECONFIGURED = 15.0
DETENTS = 10
STOP_SESSION_ENDED = 5  # `stop-reason`


def other_master_writes(h, sub: int, value: int) -> None:
    """The other master's expedited write of 0x2020:`sub` = `value` (one byte), sent on the
    relay's bus (the device and the component both see it), and the device's answer."""
    mark = h.relay.device.mark()
    request = bytes([DOWNLOAD_1, WHEEL & 0xFF, WHEEL >> 8, sub, value, 0, 0, 0])
    h.relay.send(SDO_RX, request)
    answer = h.relay.device.wait_for(
        lambda f: f.id == SDO_TX and f.data[1:4] == request[1:4],
        since=mark,
        what=f"the device's answer to 0x{WHEEL:04X}:{sub} = {value}",
    )
    assert answer.data[0] == DOWNLOAD_ANSWER, (
        f"node {NODE_ID} refused 0x{WHEEL:04X}:{sub} = {value}: {bytes(answer.data).hex()}"
    )


def forward_detents_after_a_write(h, sub: int, value: int) -> tuple:
    """Another master writes 0x2020:`sub` = `value` while X is live; once the component has
    the feed on again, DETENTS detents are turned forward. Returns (X's counts credited for
    them, what the device's records say the position moved)."""
    mark = h.relay.record_count()
    written = time.monotonic()
    other_master_writes(h, sub, value)
    # The session ends at the write: a record without the component's session comes first;
    # then the component's new session shows the feed on again.
    h.must(
        lambda: any(not decode(f).enabled for f in h.relay.records_since(mark)),
        FRAME_TIMEOUT,
        "a record of the feed off after the other master's write",
    )
    h.must(
        lambda: h.enabled() and any(decode(f).enabled for f in h.relay.records_since(mark)),
        RECONFIGURED,
        "jog-enable of X again after the other master's write",
    )
    h.must(h.caught_up, 3.0, "the component at the newest record")
    print(f"feed on again {time.monotonic() - written:.2f} s after the other master's write")
    # The stop is reported with its true reason: the session ended, not a 0x2000 write.
    assert h.hal.number("stop-reason") == STOP_SESSION_ENDED, h.log()[-2000:]
    assert "feed stopped by the device: the session ended" in h.log()
    counts, position = h.counts("x"), decode(h.newest()).position
    for _ in range(DETENTS):
        h.stim.turn(1)
        time.sleep(0.03)
    h.wait(lambda: h.caught_up() and h.counts("x") != counts, 3.0)
    h.wait(h.caught_up, 3.0)
    time.sleep(0.2)  # the last credits to the pins
    return h.counts("x") - counts, decode(h.newest()).position - position


def test_another_masters_wheel_parameters_never_reverse_or_scale_the_jog(board, tmp_path):
    """While the component jogs X at x1, another master writes 0x2020:4 = 1 (invert
    direction), later 0x2020:3 = 1 (one count per detent). After each, once the component
    has the feed on again, ten detents forward move X by exactly +10: the component set the
    wheel's parameters back (and read them back) before it enabled the feed. Before, the
    first write made them move X by -10, the second by -40."""
    with started(board, tmp_path) as h:
        moved, position = forward_detents_after_a_write(h, INVERT, 1)
        assert (moved, position) == (DETENTS, DETENTS), (
            f"after another master inverted the wheel, {DETENTS} detents forward moved X by "
            f"{moved} (the device's position by {position})"
        )
        moved, position = forward_detents_after_a_write(h, COUNTS_PER_DETENT, 1)
        assert (moved, position) == (DETENTS, DETENTS), (
            f"after another master set one count per detent, {DETENTS} detents forward moved "
            f"X by {moved} (the device's position by {position})"
        )


# An HMI's poll: an expedited upload of the error register 0x1001, once a second.
POLL = bytes([0x40, 0x01, 0x10, 0x00, 0, 0, 0, 0])
POLL_PERIOD = 1.0
# From the device's boot-up to the component's feed on again, with an HMI polling.
CONFIGURED_SOON = 3.0


@contextmanager
def polling(h, period: float = POLL_PERIOD):
    """Another master reads 0x1001 every `period` seconds (the relay's bus: the device and the
    component see it) until the block ends."""
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(period):
            h.relay.send(SDO_RX, POLL)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(2)


def test_a_polling_master_neither_starves_the_configuration_nor_the_wheel(board, tmp_path):
    """An HMI reads 0x1001 every second while the component runs. The board is power cycled:
    the component configures the device again and has the feed on within CONFIGURED_SOON of
    the boot-up, and ten detents turned then are credited exactly, the polls going on. Before,
    the component sent no SDO request while another master's were less than 2 s old: it never
    configured the device (0 of 10 detents 25 s later)."""
    with started(board, tmp_path) as h:
        polled_from = h.relay.device.mark()
        with polling(h):
            time.sleep(2 * POLL_PERIOD)
            mark = h.relay.device.mark()
            records = h.relay.record_count()
            board.control("power")
            boot = h.relay.device.wait_for(
                lambda f: f.id == 0x700 + NODE_ID and bytes(f.data) == b"\x00",
                since=mark,
                what="the boot-up after the power cycle",
            )
            h.must(
                lambda: (
                    h.enabled()
                    and any(
                        decode(f).enabled and f.t > boot.t for f in h.relay.records_since(records)
                    )
                ),
                CONFIGURED_SOON + 2.0,
                "the feed on again after the power cycle, an HMI polling",
            )
            on = next(
                f for f in h.relay.records_since(records) if decode(f).enabled and f.t > boot.t
            )
            print(f"feed on again {on.t - boot.t:.2f} s after the boot-up, an HMI polling")
            assert on.t - boot.t <= CONFIGURED_SOON, f"{on.t - boot.t:.2f} s after the boot-up"
            h.must(h.caught_up, 3.0, "the component at the newest record")
            counts, position = h.counts("x"), decode(h.newest()).position
            for _ in range(DETENTS):
                h.stim.turn(1)
                time.sleep(0.1)
            h.wait(lambda: h.caught_up() and h.counts("x") - counts == DETENTS, 3.0)
            moved = h.counts("x") - counts
            turned = decode(h.newest()).position - position
            polls = [
                f for f in h.relay.device.frames(SDO_TX, polled_from) if f.data[1:3] == POLL[1:3]
            ]
        assert turned == DETENTS and len(polls) >= 3, (turned, len(polls))
        assert moved == DETENTS, f"{moved} of {DETENTS} detents credited, an HMI polling"
        assert all(decode(f).session for f in h.relay.device.frames(TPDO1, mark)[-3:])
