"""Storing parameters under a hostile master: unchanged stores write nothing, changed ones
stop at the wear budget with a defined answer, and no store is made while the feed is
enabled, so a store never costs a detent.

The parameter page (`handwheel_storage::page`) is over the board's flash: the emulated board's
FPEC model counts erases and programmed half-words (`status`), and a page erase stalls the
CPU 20 ms.
"""

import itertools
import threading
import time

import canopen
import pytest
from canopen.lss import LssError, LssMaster

from rig import BOOTUP, HEARTBEAT, NMT_RESET_NODE

SAVE = b"save"
LOAD = b"load"
CANNOT_STORE = 0x08000020
DEVICE_STATE = 0x08000022
LSS_RESPONSE = 0x7E4
# docs/OBJECT-DICTIONARY.md "Storing parameters": a 154-byte record, six to the 1 KiB page;
# eight erases at once.
RECORDS_PER_PAGE = 6
ERASE_BURST = 8


def flash_counts(board) -> tuple[int, int]:
    status = board.status()
    return int(status["erases"]), int(status["programs"])


def attempt(rig, index: int, sub: int, signature: bytes) -> int | None:
    """An SDO store or restore: its abort code, or None when it was carried out."""
    try:
        rig.node.sdo.download(index, sub, signature)
    except canopen.SdoAbortedError as e:
        return e.code
    return None


def lss_store(rig) -> bytes:
    """LSS "store configuration" (Configuration state first); the answer's bytes."""
    mark = rig.frames.mark()
    rig.network.send_message(0x7E5, bytes([0x17, 0, 0, 0, 0, 0, 0, 0]))
    return rig.frames.wait_id(LSS_RESPONSE, since=mark).data


def test_unchanged_stores_write_nothing_and_changed_ones_stop_at_the_wear_budget(rig):
    board = rig.board
    # Nothing stored yet: "restore defaults" has nothing to write, however often.
    for _ in range(30):
        rig.node.sdo.download(0x1011, 1, LOAD)
    assert flash_counts(board) == (0, 0)
    # One store writes one record; the same parameters again write nothing.
    rig.node.sdo.download(0x1010, 1, SAVE)
    erases, programs = flash_counts(board)
    assert (erases, programs) == (0, 77), "one 154-byte record, no erase"
    for _ in range(50):
        rig.node.sdo.download(0x1010, 1, SAVE)
    assert flash_counts(board) == (0, 77)

    # A master that changes a parameter before every store: six records per erase, eight
    # erases, then 0x08000020 (the page already holds the first record).
    accepted = []
    code = None
    for i in range(200):
        value = 1001 + i % 2  # alternates, never the stored 1000
        rig.write(0x1017, 0, value, 2)
        code = attempt(rig, 0x1010, 1, SAVE)
        if code is not None:
            break
        accepted.append(value)
    assert code == CANNOT_STORE, f"after {len(accepted)} stores: {code}"
    assert len(accepted) == RECORDS_PER_PAGE * (ERASE_BURST + 1) - 1
    assert flash_counts(board)[0] == ERASE_BURST
    # What is stored can be stored again (nothing to write); a change cannot.
    rig.write(0x1017, 0, accepted[-1], 2)
    rig.node.sdo.download(0x1010, 1, SAVE)
    # LSS: the stored node-ID is no change; another one would need an erase: 255 / 1.
    lss = rig.network.lss
    lss.RESPONSE_TIMEOUT = 0.5
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    assert lss_store(rig) == bytes([0x17, 0, 0, 0, 0, 0, 0, 0])
    lss.configure_node_id(5)
    mark = rig.frames.mark()
    with pytest.raises(LssError, match="LSS Error: 255"):
        lss.store_configuration()
    answer = rig.frames.wait_id(LSS_RESPONSE, since=mark).data
    assert answer == bytes([0x17, 255, 1, 0, 0, 0, 0, 0]), answer.hex(" ")
    lss.configure_node_id(16)
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    assert flash_counts(board)[0] == ERASE_BURST

    # The last accepted store is what the device loads.
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.read(0x1017) == accepted[-1]

    # The budget is kept with the records: a power cycle does not refill it.
    mark = rig.frames.mark()
    board.control("power")
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.read(0x1017) == accepted[-1]
    rig.write(0x1017, 0, 1500, 2)
    assert rig.write_abort(0x1010, 1, SAVE) == CANNOT_STORE
    assert flash_counts(board)[0] == ERASE_BURST


def test_nothing_is_stored_while_the_feed_is_enabled_and_no_detent_is_lost(rig):
    """A store erases flash, which stalls the CPU and the wheel's edges with it: while the
    feed is enabled, 0x1010, 0x1011 and LSS store are refused (0x08000022, LSS 255 / 2).
    The wheel turns briskly all the while; every detent arrives."""
    board = rig.board
    # Give the stores something to write: a changed parameter, and a full page, so that a
    # store would have to erase.
    rig.write(0x1017, 0, 900, 2)
    for i in range(RECORDS_PER_PAGE):
        rig.write(0x1800, 5, 101 + i, 2)
        rig.node.sdo.download(0x1010, 1, SAVE)
    before = flash_counts(board)
    rig.write(0x1017, 0, 800, 2)

    mark = rig.feed_on("x", 10)
    lss = rig.network.lss
    lss.RESPONSE_TIMEOUT = 0.5
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    turned = []
    stop = threading.Event()
    failure = []

    def turn():
        try:
            while not stop.is_set():
                rig.stim.turn(10)
                turned.append(10)
        except Exception as e:  # noqa: BLE001 - reported by the main thread
            failure.append(e)

    turner = threading.Thread(target=turn)
    turner.start()
    codes, lss_answers = [], []
    deadline = time.monotonic() + 30
    try:
        # At least 15 rounds, and on until 200 detents have turned meanwhile.
        for i in itertools.count():
            if i >= 15 and (sum(turned) >= 200 or time.monotonic() > deadline):
                break
            # A changed parameter each round: every store would have something to write.
            rig.write(0x1017, 0, 800 + i % 2, 2)
            codes.append(attempt(rig, 0x1010, 1, SAVE))
            codes.append(attempt(rig, 0x1011, 1, LOAD))
            codes.append(attempt(rig, 0x1010, 3, SAVE))
            lss_answers.append(lss_store(rig))
    finally:
        stop.set()
        turner.join(60)
    assert not failure, failure
    assert sum(turned) >= 200, f"only {sum(turned)} detents turned during the stores"
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    rig.write(0x1017, 0, 800, 2)

    detents = sum(turned)
    position = rig.read_signed(0x6004)
    assert position == detents * 10, f"{detents} detents turned, position {position}"
    rig.wait_position(detents * 10, since=mark)  # and the master has it
    assert rig.read(0x2020, 2) == 0, "no illegal transition: no edge missed"
    assert set(codes) == {DEVICE_STATE}, codes
    assert set(lss_answers) == {bytes([0x17, 255, 2, 0, 0, 0, 0, 0])}, lss_answers
    assert flash_counts(board) == before, "nothing written while the feed was on"

    # Feed off: the store goes through (it erases the full page).
    rig.write(0x2000, 0, 0, 1)
    rig.node.sdo.download(0x1010, 1, SAVE)
    assert flash_counts(board)[0] == before[0] + 1
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.read(0x1017) == 800
