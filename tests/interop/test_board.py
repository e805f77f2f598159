"""The board itself: the DIP switch, the flash page, the watchdog, the bxCAN error states and
the LEDs of the release image on the emulated board (`cargo xtask board`).

The board's control line (`Board.control`) sets the DIP switch, power-cycles, injects bus
errors, holds the bus and reads the LED history; see tools/board-emu/server.py.
"""

from __future__ import annotations

import time

import can
from canopen.lss import LssMaster

from conftest import raw_bus, stopped_after
from emulated_clock import frame_times, gaps
from rig import (
    BOOTUP,
    EMCY,
    HEARTBEAT,
    NMT_STOP,
    OPERATIONAL,
    SDO_RX,
    SDO_TX,
    STOPPED,
    TPDO1,
    Board,
    feed_record,
)

SAVE = 0x65766173  # "save", little-endian (CiA 301 0x1010)
# README "Node-ID and bit rate": code -> kbit/s.
RATES = [1000, 800, 500, 250, 125, 50, 20, 10]


def send(bus, cob_id: int, data: bytes) -> None:
    bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))


def sdo_upload(bus, frames, node_id: int, index: int, sub: int) -> int:
    mark = frames.mark()
    send(bus, 0x600 + node_id, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))
    reply = frames.wait_id(0x580 + node_id, since=mark).data
    assert reply[0] & 0xE0 == 0x40, f"upload {index:04X}:{sub} aborted: {reply.hex(' ')}"
    return int.from_bytes(reply[4:8], "little")


def expected_btr_rate(btr: int) -> tuple[float, float]:
    """Bit rate and sample point of a BTR value (RM0008 24.7.7), APB1 at 36 MHz."""
    brp, ts1, ts2 = btr & 0x3FF, (btr >> 16) & 0xF, (btr >> 20) & 0x7
    quanta = 3 + ts1 + ts2
    return 36e6 / ((brp + 1) * quanta), (2 + ts1) / quanta


def test_every_dip_code_gives_the_tables_node_id_and_bit_rate(board):
    """DIP switches 1-5 = node-ID bits, 6-8 = the README's bit-rate code; the host side of
    the bus runs at the table's rate, so the boot-up arrives only if BTR agrees."""
    with raw_bus(board) as (bus, frames):
        frames.wait_id(HEARTBEAT, bytes([BOOTUP]))  # factory state: node 16 at 1 Mbit/s
        for code, kbit in enumerate(RATES):
            node_id = [1, 2, 5, 10, 17, 31, 20, 3][code]
            board.control(f"dip {node_id | code << 5}")
            board.control(f"rate {kbit}")
            mark = frames.mark()
            board.control("reset")
            frames.wait_id(0x700 + node_id, bytes([BOOTUP]), since=mark, timeout=5)
            status = board.status()
            rate, sample = expected_btr_rate(int(status["btr"], 16))
            assert round(rate) == kbit * 1000, f"code {code}: BTR {status['btr']} gives {rate}"
            assert 0.85 <= sample <= 0.90, f"code {code}: sample point {sample:.3f}"
            assert sdo_upload(bus, frames, node_id, 0x1017, 0) == 1000
        # A wrong host rate: the node is off the bus (no boot-up reaches the host).
        board.control("dip 33")  # node 1, code 1 = 800 kbit/s
        board.control("rate 500")
        mark = frames.mark()
        board.control("reset")
        frames.assert_none(lambda f: f.id == 0x701, 1.0, since=mark, what="boot-up at 500 kbit/s")
        assert board.status()["online"] == "0"


def test_stored_settings_survive_a_power_cycle(rig):
    board = rig.board
    rig.write(0x1017, 0, 250, 2)  # heartbeat 250 ms
    rig.write(0x1800, 5, 40, 2)  # TPDO1 event timer 40 ms
    rig.write(0x1010, 1, SAVE, 4)
    lss = rig.network.lss
    lss.RESPONSE_TIMEOUT = 0.5
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    lss.configure_node_id(7)
    lss.store_configuration()
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    # Two records appended to the erased page (0x1010's, then LSS's): no erase needed.
    status = board.status()
    assert (status["erases"], status["programs"]) == ("0", "154"), status

    mark = rig.frames.mark()
    board.control("power")
    rig.frames.wait_id(0x707, bytes([BOOTUP]), since=mark)
    node = rig.network.add_node(7, rig.node.object_dictionary)
    node.sdo.RESPONSE_TIMEOUT = 2
    assert int.from_bytes(node.sdo.upload(0x1017, 0), "little") == 250
    assert int.from_bytes(node.sdo.upload(0x1800, 5), "little") == 40
    board.wait_for_log(r"node-ID 7, 1000 kbit/s \(Stored")
    board.wait_for_log(r"reset cause PowerOn")
    # The heartbeat runs at the stored period.
    beats = gaps(frame_times(rig, 0x707, 4, since=rig.frames.mark(), timeout=3)[1:])
    assert all(0.15 < g < 0.35 for g in beats), beats


def test_a_corrupt_parameter_page_means_defaults(rig):
    board = rig.board
    rig.write(0x1017, 0, 300, 2)
    rig.write(0x1010, 1, SAVE, 4)
    board.control("corrupt")  # one bit of the stored record flips: its CRC fails
    mark = rig.frames.mark()
    board.control("power")
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.read(0x1017) == 1000, "the default heartbeat, not the stored 300 ms"
    board.wait_for_log(r"node-ID 16, 1000 kbit/s \(Default")


def test_a_stalled_canopen_loop_is_reset_by_the_watchdog(rig):
    board = rig.board
    feeds = int(board.status()["feeds"])
    assert feeds > 0, "the loop feeds the watchdog"
    mark = rig.frames.mark()
    board.control("storm 2000")  # the CAN task (priority 2) never runs again
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark, timeout=5)
    status = board.status()
    assert status["boot"] == "IndependentWatchdog"
    # IWDG reload for 500 ms (the HAL's choice: RLR 2500 at 40 kHz / 8, 500.2 ms), counted in
    # emulated time from the last feed, at most one loop round (5 ms) before the storm began.
    after = float(status["reset_ms"]) - float(status["storm_ms"])
    assert 495 < after < 502, f"reset {after:.1f} ms after the loop stalled"
    board.wait_for_log(r"reset cause IndependentWatchdog")


def flashes(history, led, since_ms):
    """(on, off) durations in ms of `led` after `since_ms`, from its change history."""
    changes = [(ms, on) for ms, name, on in history if name == led and ms >= since_ms]
    spans = []
    for (t0, on), (t1, _) in zip(changes, changes[1:]):
        spans.append((on, t1 - t0))
    return spans


def state_at(history, led, ms):
    """Whether `led` was on at emulated time `ms` (None before its first change)."""
    state = None
    for t, name, on in history:
        if name == led and t <= ms:
            state = on
    return state


def near(value, want, tolerance=0.10):
    return abs(value - want) <= tolerance * want


def test_run_led_follows_the_nmt_state(rig):
    """CiA 303-3: Pre-operational blinking (200 ms on / 200 ms off), Operational on,
    Stopped single flash (200 ms on, 1 s off), within 10 %."""
    board = rig.board
    time.sleep(1.5)
    pre = flashes(board.leds(), "run", 0)[1:]
    assert len(pre) >= 4, pre
    assert all(near(d, 200) for _, d in pre), f"blinking: {pre}"

    rig.start()
    t_start = float(board.status()["ms"])
    time.sleep(1.0)
    history = board.leds()
    on_after = [(ms, on) for ms, name, on in history if name == "run" and ms > t_start + 60]
    assert not on_after, f"Operational: RUN stays on, changes {on_after}"
    assert [on for ms, name, on in history if name == "run"][-1] is True

    rig.nmt_and_heartbeat(NMT_STOP, STOPPED)
    t_stop = float(board.status()["ms"])
    time.sleep(3.0)
    spans = flashes(board.leds(), "run", t_stop + 100)[1:]
    ons = [d for on, d in spans if on]
    offs = [d for on, d in spans if not on]
    assert ons and offs, spans
    assert all(near(d, 200) for d in ons), f"single flash on: {spans}"
    assert all(near(d, 1000) for d in offs), f"single flash off: {spans}"


def test_bus_errors_give_emcys_err_led_codes_and_bus_off_recovers(rig):
    board = rig.board
    # Pre-operational: only the heartbeat is sent, each success lowers TEC by one.
    t0 = float(board.status()["ms"])
    mark = rig.frames.mark()
    board.control("buserr 13 0")  # TEC 104: warning limit
    time.sleep(2.0)
    spans = flashes(board.leds(), "err", t0)[1:]  # the first flash may start mid-pattern
    ons = [d for on, d in spans if on]
    offs = [d for on, d in spans if not on]
    assert ons and all(near(d, 200) for d in ons), f"ERR single flash: {spans}"
    assert offs and all(near(d, 1000) for d in offs), f"ERR single flash: {spans}"

    board.control("buserr 5 0")  # TEC 136: error passive
    emcy = rig.frames.wait_id(EMCY, since=mark, timeout=3)
    assert emcy.data[:2] == bytes([0x20, 0x81]), f"EMCY 0x8120 error passive: {emcy}"

    mark = rig.frames.mark()
    t_off = float(board.status()["ms"])
    board.control("busoff 600")  # bus-off, the bus stays faulty for 600 ms
    time.sleep(0.3)
    assert board.status()["boff"] == "1"
    recovered = rig.frames.wait_for(
        lambda f: f.id == EMCY and f.data[:2] == bytes([0x40, 0x81]),
        since=mark,
        timeout=5,
        what="EMCY 0x8140 bus-off recovered",
    )
    assert recovered
    assert board.status()["boff"] == "0"
    history = board.leds()
    # ERR is on, steadily, from the next LED update (50 ms) to the recovery (600 ms).
    assert state_at(history, "err", t_off + 100) is True, "ERR on in bus-off"
    changes = [ms for ms, name, on in history if name == "err" and t_off + 100 < ms < t_off + 550]
    assert not changes, f"ERR steady while bus-off, changed at {changes}"
    # The node is healthy again: it answers and sends heartbeats.
    assert rig.read(0x1017) == 1000


def test_burst_during_a_flash_erase_overruns_and_the_node_recovers(rig):
    """A store that finds the parameter page full erases it: the CPU stalls about 20 ms,
    during which a burst of frames fills FIFO 0 (three frames) and overruns: EMCY 0x8110, no
    crash. The burst (400 frames, about 20 ms of bus time) spans the erase whatever the
    store does first (it reads the page's records)."""
    board = rig.board
    # Six changed stores fill the page (six 154-byte records); the seventh must erase.
    for i in range(6):
        rig.write(0x1017, 0, 1001 + i, 2)
        rig.write(0x1010, 1, SAVE, 4)
    assert board.status()["erases"] == "0"
    rig.write(0x1017, 0, 1100, 2)
    mark = rig.frames.mark()
    save = bytes([0x23, 0x10, 0x10, 0x01]) + SAVE.to_bytes(4, "little")
    rig.network.send_message(SDO_RX, save)
    for _ in range(400):
        rig.network.send_message(0x701, bytes([0x7F]))  # heartbeats of node 1: accepted
    reply = rig.frames.wait_id(SDO_TX, since=mark, timeout=5)
    assert reply.data[0] == 0x60, f"store confirmed: {reply}"
    emcy = rig.frames.wait_id(EMCY, since=mark, timeout=5)
    assert emcy.data[:2] == bytes([0x10, 0x81]), f"EMCY 0x8110 overrun: {emcy}"
    status = board.status()
    assert status["erases"] == "1", status
    assert int(status["overruns"]) > 0
    assert status["locked"] == "0" and status["resets"] == "1", status
    assert rig.read(0x1017) == 1100, "the node still answers"


def feed_quiet(rig, quiet: float = 0.1, timeout: float = 3.0) -> None:
    """Waits until the records the enable and the selection made are out: `quiet` s without a
    feed record and the mailboxes empty. (A record still waiting when a test holds the bus
    waits past the transmit stall limit and changes what the test sees.)"""
    deadline = time.monotonic() + timeout
    while True:
        mark = rig.frames.mark()
        time.sleep(quiet)
        if not rig.frames.frames(TPDO1, since=mark) and rig.board.status()["pending"] == "-":
            return
        assert time.monotonic() < deadline, "the feed records do not stop"


def wait_pending(board, ids: set[str], timeout: float = 3.0) -> None:
    """Waits until the transmit mailboxes hold exactly the identifiers `ids` (hex)."""
    deadline = time.monotonic() + timeout
    while True:
        pending = set(board.status()["pending"].split(",")) - {"-"}
        if pending == ids:
            return
        assert time.monotonic() < deadline, f"mailboxes hold {pending}, wanted {ids}"
        time.sleep(0.002)


# The device's transmit stall limit (handwheel_device::TRANSMIT_STALL_MS): frames that wait
# this long without the path once running empty are discarded and the feed is stopped.
TRANSMIT_STALL_MS = 100


def test_a_full_transmit_side_never_loses_a_frame(rig):
    """The bus is taken by other traffic, so the node's frames wait. The heartbeat (0x710),
    an SDO reply (0x590) and a feed record (0x190) fill the three mailboxes, each more urgent
    than the last; then the EMCY of error passive (0x090) finds no free mailbox and
    displaces the least urgent (an abort, RM0008 24.7.1), which goes back to the head of
    the queue. Once the bus is free every frame goes out, most urgent first. All of it
    within the transmit stall limit of the heartbeat's entering its mailbox (the test checks
    it in emulated time; the wheel is turned by single edges, quicker than `turn`): frames
    that wait longer are discarded, by design (test_outage.py's long hold)."""
    board = rig.board
    rig.write(0x1800, 5, 0, 2)  # no event timer: feed records only on motion
    rig.feed_on("x")
    feed_quiet(rig)
    board.control("hold on")
    held = rig.frames.mark()
    wait_pending(board, {"710"})  # the next heartbeat (within 1 s)
    waiting_since = float(board.status()["ms"])
    rig.network.send_message(SDO_RX, bytes([0x40, 0x17, 0x10, 0, 0, 0, 0, 0]))
    wait_pending(board, {"710", "590"})
    for levels in (1, 3, 2, 0):  # one detent forward
        rig.stim.ab(levels)
    wait_pending(board, {"710", "590", "190"})
    board.control("buserr 16 0")  # TEC 128: error passive, EMCY 0x8120
    wait_pending(board, {"090", "590", "190"})
    status = board.status()
    assert int(status["aborted"]) == 1, "the heartbeat was taken out of its mailbox"
    assert not rig.frames.frames(since=held), "nothing gets through a held bus"
    waited = float(status["ms"]) - waiting_since
    assert waited < TRANSMIT_STALL_MS - 10, f"the frames waited {waited:.1f} ms"
    board.control("hold off")
    beat = rig.frames.wait_id(HEARTBEAT, since=held)
    # Two frames out, the error counter is below 128 again: the EMCY of "error active
    # again" (code 0x0000) may then be queued before the heartbeat leaves and, more urgent,
    # go first. It is not one of the frames that waited.
    out = [
        f.id for f in rig.frames.frames(since=held) if not (f.id == EMCY and f.data[:2] == bytes(2))
    ][:4]
    assert out == [EMCY, TPDO1, SDO_TX, HEARTBEAT], f"by priority, none lost: {out}"
    assert beat.data == bytes([OPERATIONAL])
    emcy = rig.frames.frames(EMCY, since=held)[0]
    assert emcy.data[:2] == bytes([0x20, 0x81])
    assert feed_record(rig.frames.frames(TPDO1, since=held)[0]).position == 1


def test_a_turn_after_a_timed_hold_is_answered_and_the_held_frames_go_out(rig):
    """`hold <ms>` ends by itself: what waited in the mailboxes goes out then, and the board
    runs on at its pace (a `turn` after the hold gets its `ok`, its feed record goes out).
    The hold (90 ms) is shorter than the transmit stall limit: a reply that waits longer is
    discarded, by design (this test held 400 ms before the limit)."""
    board = rig.board
    rig.write(0x1800, 5, 0, 2)  # no event timer: feed records only on motion
    rig.feed_on("x")
    feed_quiet(rig)
    start = float(board.status()["ms"])
    board.control("hold 90")
    held = rig.frames.mark()
    rig.network.send_message(SDO_RX, bytes([0x40, 0x17, 0x10, 0, 0, 0, 0, 0]))
    deadline = time.monotonic() + 3
    while "590" not in (status := board.status())["pending"]:  # the reply waits in a mailbox
        assert time.monotonic() < deadline, "no SDO reply in the mailboxes"
        time.sleep(0.002)
    assert float(status["ms"]) < start + 90, f"the reply queued after the hold: {status}"
    assert not rig.frames.frames(SDO_TX, since=held), "a reply while held"
    reply = rig.frames.wait_id(SDO_TX, since=held, timeout=3)
    assert reply.data[4:6] == (1000).to_bytes(2, "little")
    mark = rig.frames.mark()
    started = time.monotonic()
    board.control("turn 2", timeout=10)
    # 27.4 ms of emulated time, paced to the wall clock; an emulator stuck on the expired
    # hold moves one cycle per step and needs tens of seconds.
    assert time.monotonic() - started < 3.0, "the turn's ok comes in emulated real time"
    record = rig.frames.wait_for(
        lambda f: f.id == TPDO1 and feed_record(f).position == 2, since=mark, what="position 2"
    )
    assert record


def test_a_bit_rate_switch_on_a_dominant_bus_recovers_without_a_reset(rig):
    """LSS activate bit timing while the bus is stuck dominant: the controller cannot
    synchronise at the new rate. The node stays off the bus and keeps running (no watchdog
    reset), with the ERR LED on, and joins at the new rate by itself once the bus is free,
    with EMCY 0x8140."""
    board = rig.board
    lss = rig.network.lss
    lss.RESPONSE_TIMEOUT = 0.5
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    lss.configure_bit_timing(3)  # 250 kbit/s
    mark = rig.frames.mark()
    delivered = int(board.status()["delivered"])
    lss.activate_bit_timing(1000)  # the switch comes 1 s later
    deadline = time.monotonic() + 0.8
    while int(board.status()["delivered"]) == delivered:  # the request is in before the bus
        assert time.monotonic() < deadline, "activate bit timing not received"  # goes dominant
    board.control("dominant 2500")
    before = board.status()
    t0 = float(before["ms"])
    time.sleep(1.7)  # the switch has come; the watchdog (500 ms) would have reset a hung loop
    status = board.status()
    assert status["resets"] == "1" and status["boot"] == "PowerOn", status
    rounds = (float(status["ms"]) - t0) / 10  # the loop's rounds at RECOVERY_POLL_MS or faster
    assert int(status["feeds"]) - int(before["feeds"]) >= rounds, "the CAN-side loop ran on"
    assert status["mode"] == "init" and status["online"] == "0", status
    assert status["bitrate"] == "250000", status
    assert state_at(board.leds(), "err", float(status["ms"])) is True, "ERR on"
    board.wait_for_log(r"CAN: no 11 recessive bits at 250 kbit/s within 50 ms")
    emcy = rig.frames.wait_for(
        lambda f: f.id == EMCY and f.data[:2] == bytes([0x40, 0x81]),
        since=mark,
        timeout=5,
        what="EMCY 0x8140 once the bus is free",
    )
    assert emcy
    status = board.status()
    assert float(status["ms"]) > t0 + 2500, "not before the bus was free"
    assert status["resets"] == "1" and status["boot"] == "PowerOn", status
    assert status["mode"] == "normal" and status["bitrate"] == "250000", status
    assert rig.read(0x1017) == 1000, "the node answers at 250 kbit/s"


def test_boot_on_a_dominant_bus_shows_bus_off_and_joins_once_the_bus_is_free(board):
    """No transceiver or a shorted bus at power-on: bxCAN never sees the 11 recessive bits it
    needs to join. The node must not hang in its start-up: it keeps running (the watchdog is
    fed, no reset), shows bus-off (CiA 303-3: ERR on, RUN dark before the boot-up), sends
    nothing, and boots up by itself once the bus is free."""
    board.control("dominant on")  # before the CPU starts: it starts with the SLCAN client
    with raw_bus(board) as (_bus, frames):
        time.sleep(1.5)  # three watchdog periods
        status = board.status()
        assert status["resets"] == "1" and status["boot"] == "PowerOn", status
        assert int(status["feeds"]) >= 100, f"the watchdog is fed while waiting: {status}"
        assert status["online"] == "0", status
        now = float(status["ms"])
        history = board.leds()
        assert state_at(history, "err", now) is True, f"ERR on (bus-off): {history}"
        assert state_at(history, "run", now) is not True, f"RUN dark: {history}"
        err_on = [ms for ms, name, on in history if name == "err" and on]
        assert err_on and err_on[0] < 200, f"ERR on within 200 ms of power-on: {history}"
        assert not frames.frames(), "nothing passes a dominant bus"
        board.wait_for_log(r"no 11 recessive bits at 1000 kbit/s within 50 ms of boot")

        mark = frames.mark()
        board.control("dominant off")
        frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark, timeout=3)
        assert frames.frames(since=mark)[0].data == bytes([BOOTUP]), "the boot-up comes first"
        board.wait_for_log(r"CAN: on the bus")
        time.sleep(0.3)
        status = board.status()
        assert status["resets"] == "1" and status["online"] == "1", status
        assert state_at(board.leds(), "err", float(status["ms"])) is False, "ERR off again"
        assert sdo_upload(_bus, frames, 16, 0x1017, 0) == 1000, "the node answers"


def test_a_stack_overflow_faults_and_resets_instead_of_overwriting_statics(request, tmp_path):
    """The test build `--image stack-overflow` digs 19 KiB into its stack right after boot,
    more than its stack region, less than all of RAM. Linked by flip-link, the stack lies
    below static RAM, so the dig runs off the start of RAM: the push below 0x20000000 faults
    (HardFault), nothing comes back from the dig, and the watchdog resets the MCU, which
    then does the same again. (Linked the classic way, the same dig stays inside RAM and
    overwrites the statics instead: no fault, and the log says it came back.)"""
    board = Board(tmp_path / "board.log", tmp_path / "flash.bin", image="stack-overflow")
    with stopped_after(request, board), raw_bus(board):
        board.wait_for_log(r"stack overflow test: digging 19456 bytes")
        deadline = time.monotonic() + 10
        while int(board.status()["resets"]) < 3:
            assert time.monotonic() < deadline, f"no second reset: {board.status()}"
            time.sleep(0.1)
        status = board.status()
        assert status["boot"] == "IndependentWatchdog", status
        assert int(status["faults"]) >= 2, f"a fault per boot: {status}"
        address = int(status["fault_addr"], 16)
        # The first access below RAM: within one level of the dig (256 bytes and its frame).
        assert 0x2000_0000 - 512 <= address < 0x2000_0000, f"just below RAM: {status}"
        assert "back without a fault" not in board.log()
