"""The update's decisions (`update.Update`) and the file's checks (`image.UpdateImage`)
against a model of the device's program download (program_device.py), step by step: the
contract's sequence, refusals, the device's answers and aborts, lost answers and boot-ups."""

import dataclasses
import struct
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_handwheel import image, update
from canopen_handwheel.update import Aborted, NoAnswer, Ok
from program_device import (
    LOADER_DEVICE_TYPE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    PRODUCT,
    SILENT,
    TRIAL_FAILS,
    VENDOR,
    Abort,
    ProgramDevice,
    Silent,
    update_file,
)

OLD = update_file(3)
NEW = update_file(4, size=3000)
NEW_IMAGE = image.UpdateImage.parse(NEW)
FAST = update.Settings(
    node=16, boot_timeout=0.5, status_timeout=0.5, poll_interval=0.05, trial_timeout=2
)

LOSE_ANSWER = "lose answer"  # the device did it; its answer never arrived
LOSE_REQUEST = "lose request"  # the device never saw it
LOSE_BOOTUP = "lose boot-up"  # the boot-up after a reset never arrived
MASTER_STARTS = "master starts"  # another master sends NMT start before this step


class Driver:
    """Carries out the planner's steps on a `ProgramDevice`, with `faults(n, step)` naming
    what goes wrong with step n (None: nothing; an `Aborted`: a `Download`'s answer, the
    device doing nothing). `block`: the device's SDO server offers block download (without
    it, a block download's initiate is aborted with 0x05040001, as by the loader before it
    had block download and by python-canopen's LocalNode)."""

    def __init__(self, dev: ProgramDevice, faults=None, block=True):
        self.dev = dev
        self.faults = faults or (lambda n, step: None)
        self.block = block
        self.seen_bootups = 0
        self.armed = 0
        self.steps = []
        self.notes = []

    def run(self, plan: update.Update, limit: int = 5000) -> update.Result:
        while plan.step is not None:
            assert len(self.steps) < limit, "the update does not end"
            plan.answer(self.carry_out(plan.step))
        assert plan.result is not None
        return plan.result

    def carry_out(self, step):
        n = len(self.steps)
        self.steps.append(step)
        fault = self.faults(n, step)
        dev = self.dev
        if fault == MASTER_STARTS:
            dev.nmt(OPERATIONAL)
        if isinstance(step, update.Note):
            self.notes.append(step.text)
            return Ok()
        if isinstance(step, update.Pause):
            return Ok()
        if isinstance(step, update.PreOperational):
            if fault != LOSE_REQUEST:
                dev.nmt(PRE_OPERATIONAL)
            return Ok()
        if isinstance(step, update.WaitBootup):
            return Ok() if self.seen_bootups > self.armed else NoAnswer("no boot-up")
        if isinstance(step, update.HoldInLoader):
            # The operator switches the board off and on; the loader's window takes the
            # request.
            dev.rescue_pending = True
            dev.boot(power_on=True)
            self.seen_bootups += 1
            return Ok()
        if fault == LOSE_REQUEST:
            return NoAnswer("timeout")
        if isinstance(fault, Aborted):
            assert isinstance(step, update.Download)
            return fault
        if isinstance(step, update.Download) and step.transfer == update.BLOCK and not self.block:
            return Aborted(update.ABORT_NO_BLOCK, at_initiate=True)
        try:
            if isinstance(step, update.Read):
                out = Ok(dev.read(step.index, step.sub))
            elif isinstance(step, update.Write):
                if step.arm_bootup:
                    self.armed = self.seen_bootups
                dev.write(step.index, step.sub, step.value)
                out = Ok()
            elif isinstance(step, update.Download):
                assert step.size == len(NEW_IMAGE.data)
                assert step.transfer in (update.BLOCK, update.SEGMENTED)
                dev.download(self.data)
                out = Ok()
            else:
                raise AssertionError(step)
        except Abort as e:
            out = Aborted(e.code)
        except Silent:
            out = NoAnswer("timeout")
        if dev.take_reset():
            dev.boot()
            if fault != LOSE_BOOTUP and not dev.silent:
                self.seen_bootups += 1
        return NoAnswer("timeout") if fault == LOSE_ANSWER else out

    data = NEW


def run(dev, faults=None, settings=FAST, data=NEW, block=True):
    d = Driver(dev, faults, block)
    d.data = data
    plan = update.Update(image.UpdateImage.parse(NEW), settings)
    return d.run(plan), d


def writes(d):
    return [(s.index, s.value) for s in d.steps if isinstance(s, update.Write)]


def downloads(d):
    return [(s.attempt, s.transfer) for s in d.steps if isinstance(s, update.Download)]


BLOCK, SEGMENTED = update.BLOCK, update.SEGMENTED


def test_a_full_update_from_the_application_in_the_contracts_order():
    dev = ProgramDevice(OLD)
    result, d = run(dev)
    assert result.status == update.OK and result.exit_code == 0
    assert not dev.loader and dev.crc() == NEW_IMAGE.crc and dev.version() == 4
    assert (result.version, result.crc) == (4, NEW_IMAGE.crc)
    assert result.before.revision == 3 and result.before.program_crc == zlib.crc32(OLD[512:])
    assert result.message == (
        f"node 16 updated: version 3 -> 4, CRC 0x{zlib.crc32(OLD[512:]):08X} -> "
        f"0x{NEW_IMAGE.crc:08X}"
    )
    order = [
        type(s).__name__ + (f" {s.index:04X}:{s.sub}" if hasattr(s, "index") else "")
        for s in d.steps
        if not isinstance(s, (update.Note, update.Pause))
    ]
    assert order == [
        "Read 1000:0",
        "Read 1018:1",
        "Read 1018:2",
        "Read 1018:3",
        "Read 1F56:1",
        "Read 1F57:1",
        "Read 2000:0",
        "PreOperational",
        "Write 1F51:1",  # stop
        "WaitBootup",
        "Read 1000:0",  # the loader's BOOT
        "PreOperational",
        "Write 1F51:1",  # clear
        "Read 1F57:1",
        "Download",
        "Read 1F57:1",
        "Read 1F56:1",
        "PreOperational",
        "Write 1F51:1",  # start
        "WaitBootup",
        "Read 1000:0",
        "Read 1F56:1",
        "Read 1018:3",
    ]
    assert writes(d) == [(0x1F51, 0), (0x1F51, 3), (0x1F51, 1)]
    assert [s.arm_bootup for s in d.steps if isinstance(s, update.Write)] == [True, False, True]
    assert dev.bootups == 3  # power-on, the loader, the new application
    # By block download, which this device offers (`Settings.transfer` is AUTO).
    assert FAST.transfer == update.AUTO and downloads(d) == [(1, BLOCK)]
    assert not any("block" in n for n in d.notes)


def test_a_device_in_its_loader_is_updated_without_a_stop():
    dev = ProgramDevice(None)
    assert dev.loader
    result, d = run(dev)
    assert result.status == update.OK and dev.crc() == NEW_IMAGE.crc
    assert result.before.loader and result.before.program_crc == 0
    assert result.message == (
        f"node 16 updated from its loader (program CRC 0x00000000): now version 4, CRC "
        f"0x{NEW_IMAGE.crc:08X}"
    )
    assert writes(d) == [(0x1F51, 3), (0x1F51, 1)]
    assert not any(isinstance(s, update.Read) and s.index == 0x2000 for s in d.steps)


def test_the_feed_enabled_refuses_before_anything_is_written():
    dev = ProgramDevice(OLD, feed=1)
    result, d = run(dev)
    assert result.status == update.REFUSED and result.exit_code == update.EXIT_REFUSED
    assert "feed enabled (0x2000 = 1)" in result.message and "enable pin" in result.message
    assert writes(d) == [] and not any(isinstance(s, update.PreOperational) for s in d.steps)
    assert dev.crc() == zlib.crc32(OLD[512:]) and not dev.loader


@pytest.mark.parametrize("loader", [False, True])
def test_another_devices_file_is_refused(loader):
    dev = ProgramDevice(None if loader else OLD)
    other = update_file(4, product=PRODUCT + 1)
    d = Driver(dev)
    d.data = other
    result = d.run(update.Update(image.UpdateImage.parse(other), FAST))
    assert result.status == update.REFUSED
    assert f"product 0x{PRODUCT + 1:08X}" in result.message
    expected = PRODUCT | 0x8000_0000 if loader else PRODUCT
    assert f"is vendor 0x{VENDOR:08X} product 0x{expected:08X}" in result.message
    assert writes(d) == []


def test_an_application_without_program_download_is_refused():
    dev = ProgramDevice(OLD)
    real_read = dev.read

    def old_firmware(index, sub):
        if index in (0x1F56, 0x1F57):
            raise Abort(0x0602_0000)
        return real_read(index, sub)

    dev.read = old_firmware
    result, d = run(dev)
    assert result.status == update.REFUSED and "without program download" in result.message
    assert "SDO abort 0x06020000" in result.message and writes(d) == []


def test_a_device_without_a_loader_restarts_as_its_application():
    dev = ProgramDevice(OLD, has_loader=False)
    result, d = run(dev)
    assert result.status == update.FAILED
    assert "restarted as its application, not its loader" in result.message
    assert writes(d) == [(0x1F51, 0)]


def test_a_refused_stop_is_tried_again_after_pre_operational():
    """Another master started the node between the NMT pre-operational and the stop: the
    stop is refused (0x08000022) and tried again, each time after NMT pre-operational."""
    dev = ProgramDevice(OLD)
    stops = []

    def faults(n, step):
        if isinstance(step, update.Write) and step.value == 0:
            stops.append(n)
            return MASTER_STARTS if len(stops) == 1 else None
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK
    assert writes(d)[:2] == [(0x1F51, 0), (0x1F51, 0)]
    assert any("again after NMT pre-operational" in n for n in d.notes)


def test_a_stop_refused_every_time_is_refused_and_changes_nothing():
    dev = ProgramDevice(OLD)
    result, d = run(dev, lambda n, s: MASTER_STARTS if isinstance(s, update.Write) else None)
    assert result.status == update.REFUSED and "did not stop" in result.message
    assert "0x08000022" in result.message
    assert writes(d) == [(0x1F51, 0)] * 3 and not dev.loader


def test_a_stop_whose_answer_and_boot_up_were_lost_is_not_repeated():
    """The stop was done (the device reset into its loader) but neither its answer nor its
    boot-up arrived: the loader's 0x1000 says so; no second stop."""
    dev = ProgramDevice(OLD)

    def faults(n, step):
        if isinstance(step, update.Write) and step.value == 0:
            return LOSE_ANSWER
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK and writes(d).count((0x1F51, 0)) == 1


def test_a_clear_whose_answer_was_lost_is_read_back_not_repeated():
    """The go-canopen pitfall: the clear was done, its answer came too late. 0x1F51 reads
    3: the update goes on; the write is not repeated."""
    dev = ProgramDevice(OLD)

    def faults(n, step):
        if isinstance(step, update.Write) and step.value == 3:
            return LOSE_ANSWER
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK
    assert writes(d).count((0x1F51, 3)) == 1
    assert any("but 0x1F51 reads 3: done" in n for n in d.notes)
    reads = [(s.index, s.sub) for s in d.steps if isinstance(s, update.Read)]
    assert (0x1F51, 1) in reads


def test_a_clear_that_never_arrived_is_repeated():
    dev = ProgramDevice(OLD)
    clears = []

    def faults(n, step):
        if isinstance(step, update.Write) and step.value == 3:
            clears.append(n)
            return LOSE_REQUEST if len(clears) == 1 else None
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK and writes(d).count((0x1F51, 3)) == 2


def test_0x1f57_is_polled_until_not_in_progress():
    dev = ProgramDevice(OLD, status_polls=4)
    result, d = run(dev)
    assert result.status == update.OK
    polls = [s for s in d.steps if isinstance(s, update.Read) and s.index == 0x1F57]
    assert len(polls) == 1 + 5 + 5  # at start; after clear and after the download: 4 busy
    assert sum(isinstance(s, update.Pause) for s in d.steps) == 8


def test_0x1f57_in_progress_too_long_fails_with_the_state():
    dev = ProgramDevice(None, status_polls=1000)
    dev.busy = 0
    result, d = run(dev)
    assert result.status == update.FAILED
    assert "still shows the flash in progress after 0.5 s" in result.message
    assert "without a valid application" in result.message


@pytest.mark.parametrize(
    "damage, code, abort, words",
    [
        ("crc", 3, 0x0800_0020, "the CRC does not match"),
        ("product", 2, 0x0609_0030, "another device"),
    ],
)
def test_a_download_the_loader_refuses_is_retried_then_fails_with_both_codes(
    damage, code, abort, words
):
    """The loader refuses the stream (here: a damaged copy of what the host sends): each
    attempt goes again from clear, `retries` times; the message names the SDO abort and the
    0x1F57 code with their meanings, and where the device is."""
    data = bytearray(NEW)
    if damage == "crc":
        data[700] ^= 0xFF
    else:
        struct.pack_into("<I", data, 0x0C, PRODUCT + 1)
    dev = ProgramDevice(OLD)
    result, d = run(dev, data=bytes(data))
    assert result.status == update.FAILED and result.exit_code == 1
    assert writes(d).count((0x1F51, 3)) == 3
    assert sum(isinstance(s, update.Download) for s in d.steps) == 3
    assert [s.attempt for s in d.steps if isinstance(s, update.Download)] == [1, 2, 3]
    assert f"SDO abort 0x{abort:08X}" in result.message and words in result.message
    assert f"code {code}," in result.message
    assert "the download failed 3 times" in result.message
    assert "without a valid application" in result.message and "takes the next update" in (
        result.message
    )
    assert (0x1F51, 1) not in writes(d)
    assert sum("trying again from clear" in n for n in d.notes) == 2


def test_a_download_that_fails_once_succeeds_on_the_retry():
    dev = ProgramDevice(OLD)
    downloads = []

    def faults(n, step):
        if isinstance(step, update.Download):
            downloads.append(n)
            return LOSE_REQUEST if len(downloads) == 1 else None
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK and len(downloads) == 2
    assert writes(d) == [(0x1F51, 0), (0x1F51, 3), (0x1F51, 3), (0x1F51, 1)]


def test_no_retries_means_one_download():
    data = bytearray(NEW)
    data[800] ^= 1
    settings = update.Settings(node=16, retries=0, boot_timeout=0.5, status_timeout=0.5)
    result, d = run(ProgramDevice(OLD), settings=settings, data=bytes(data))
    assert result.status == update.FAILED
    assert sum(isinstance(s, update.Download) for s in d.steps) == 1


def test_auto_goes_segmented_at_once_where_block_is_not_offered_and_remembers_it():
    """A device without block download aborts the block download's initiate with
    0x05040001: one line says so, and the same attempt goes on segmented at once, without a
    clear again (nothing was written, the loader is still cleared). The attempt after a
    failed one goes segmented directly."""
    dev = ProgramDevice(OLD)
    segmented = []

    def faults(n, step):  # the first segmented download's request is lost
        if isinstance(step, update.Download) and step.transfer == SEGMENTED:
            segmented.append(n)
            return LOSE_REQUEST if len(segmented) == 1 else None
        return None

    result, d = run(dev, faults, block=False)
    assert result.status == update.OK and dev.crc() == NEW_IMAGE.crc
    assert downloads(d) == [(1, BLOCK), (1, SEGMENTED), (2, SEGMENTED)]
    first = next(i for i, s in enumerate(d.steps) if isinstance(s, update.Download))
    note, then = d.steps[first + 1], d.steps[first + 2]
    assert isinstance(note, update.Note) and note.text == (
        "node 16 does not offer SDO block download (its initiate answered SDO abort "
        "0x05040001 (command specifier not valid or unknown)): downloading segmented"
    )
    assert then == update.Download(len(NEW), 1, 3, SEGMENTED)
    assert writes(d) == [(0x1F51, 0), (0x1F51, 3), (0x1F51, 3), (0x1F51, 1)]  # a clear each
    assert sum("does not offer SDO block download" in n for n in d.notes) == 1
    assert sum("trying again from clear (2 of 3)" in n for n in d.notes) == 1


def test_block_only_fails_where_block_is_not_offered():
    settings = dataclasses.replace(FAST, transfer=BLOCK)
    result, d = run(ProgramDevice(OLD), settings=settings, block=False)
    assert result.status == update.FAILED and result.exit_code == update.EXIT_FAILED
    assert downloads(d) == [(1, BLOCK), (2, BLOCK), (3, BLOCK)]
    assert "the download failed 3 times; the last: download of 0x1F50:1: SDO abort " in (
        result.message
    )
    assert "0x05040001 (command specifier not valid or unknown) at the block download's " in (
        result.message
    )
    assert "does not offer SDO block download: --sdo-transfer auto or segmented" in (result.message)
    assert not any("downloading segmented" in n for n in d.notes)
    assert "without a valid application" in result.message


@pytest.mark.parametrize("block", [True, False])
def test_segmented_never_tries_block(block):
    settings = dataclasses.replace(FAST, transfer=SEGMENTED)
    dev = ProgramDevice(OLD)
    downloads_seen = []

    def faults(n, step):  # the first download fails: the retry is segmented too
        if isinstance(step, update.Download):
            downloads_seen.append(n)
            return LOSE_ANSWER if len(downloads_seen) == 1 else None
        return None

    result, d = run(dev, faults, settings=settings, block=block)
    assert result.status == update.OK and dev.crc() == NEW_IMAGE.crc
    assert downloads(d) == [(1, SEGMENTED), (2, SEGMENTED)]
    assert not any("block" in n for n in d.notes)


@pytest.mark.parametrize(
    "transfer, abort, words",
    [
        # Later in a block download: not the refusal of block download.
        (update.AUTO, Aborted(0x0504_0001), "0x05040001 (command specifier"),
        (update.AUTO, Aborted(0x0504_0004), "0x05040004 (CRC error)"),
        (update.AUTO, Aborted(0x0504_0003), "0x05040003 (invalid sequence number)"),
        # Another abort at the initiate: the device has block download, and refused this one.
        (update.AUTO, Aborted(0x0504_0005, at_initiate=True), "0x05040005 (out of memory)"),
        # The abort that refuses block download, at a segmented download's initiate.
        (SEGMENTED, Aborted(0x0504_0001, at_initiate=True), "0x05040001 (command specifier"),
    ],
)
def test_an_abort_other_than_block_refused_at_its_initiate_is_a_failed_attempt(
    transfer, abort, words
):
    """Only 0x05040001 answering a block download's initiate means "no block download";
    any other abort of a download is a failed attempt, tried again from clear with the same
    transfer."""
    settings = dataclasses.replace(FAST, transfer=transfer)
    dev = ProgramDevice(OLD)
    seen = []

    def faults(n, step):
        if isinstance(step, update.Download):
            seen.append(n)
            return abort if len(seen) == 1 else None
        return None

    result, d = run(dev, faults, settings=settings)
    assert result.status == update.OK and dev.crc() == NEW_IMAGE.crc
    first = BLOCK if transfer == update.AUTO else SEGMENTED
    assert downloads(d) == [(1, first), (2, first)]
    assert writes(d).count((0x1F51, 3)) == 2
    assert not any("does not offer SDO block download" in n for n in d.notes)
    (again,) = [n for n in d.notes if "trying again from clear" in n]
    assert again.startswith(f"download of 0x1F50:1: SDO abort {words}")
    assert "at the block download's initiate" not in again


def test_an_unknown_transfer_is_refused():
    with pytest.raises(ValueError, match="transfer 'fast' is not one of"):
        update.Update(NEW_IMAGE, dataclasses.replace(FAST, transfer="fast"))


def test_a_start_whose_boot_up_was_lost_is_seen_by_its_device_type():
    dev = ProgramDevice(OLD)

    def faults(n, step):
        if isinstance(step, update.Write) and step.value == 1:
            return LOSE_ANSWER if n % 2 else LOSE_BOOTUP
        return None

    result, d = run(dev, faults)
    assert result.status == update.OK and writes(d).count((0x1F51, 1)) == 1


def test_an_image_that_fails_its_trial_boot_is_unhealthy_and_not_sent_again():
    """The new image hangs or faults before it talks: the loader starts it 3 times under the
    watchdog, then stays with 0x1F57 code 64. The update says so and how to recover (a good
    image), and downloads nothing again."""
    dev = ProgramDevice(OLD, health={NEW_IMAGE.crc: TRIAL_FAILS})
    result, d = run(dev)
    assert result.status == update.UNHEALTHY and result.exit_code == update.EXIT_UNHEALTHY == 5
    assert dev.loader and dev.status == 64 << 1
    assert "the new image never became healthy: node 16 came back as its loader" in result.message
    assert "code 64" in result.message
    assert "Sending this image again would not help" in result.message
    assert "update GOOD.update" in result.message and "--rescue" not in result.message
    assert sum(isinstance(s, update.Download) for s in d.steps) == 1
    assert writes(d).count((0x1F51, 1)) == 1, "start is not repeated"


def test_an_image_that_never_answers_is_unhealthy_and_the_way_back_is_rescue():
    """The new image feeds its watchdog and never talks (or talks at another bit rate):
    nothing answers after the start, not even a loader after the trial's time."""
    dev = ProgramDevice(OLD, health={NEW_IMAGE.crc: SILENT})
    result, d = run(dev)
    assert result.status == update.UNHEALTHY and dev.silent
    assert "never answered after the start of the new image" in result.message
    assert "--rescue" in result.message
    waits = [s.timeout for s in d.steps if isinstance(s, update.WaitBootup)]
    assert waits[-1] == FAST.trial_timeout, "the trial's time was given"
    assert writes(d).count((0x1F51, 1)) == 1


def test_rescue_holds_a_silent_device_in_its_loader_then_updates_it():
    """`--rescue`: a device whose image never answers is held in its loader at the power-on
    the operator brings about, then updated with a good image."""
    dev = ProgramDevice(OLD, health={zlib.crc32(OLD[512:]): SILENT})
    assert dev.silent
    failed, _ = run(dev)
    assert failed.status == update.FAILED and "--rescue" in failed.message
    settings = update.Settings(node=16, boot_timeout=0.5, status_timeout=0.5, rescue=True)
    result, d = run(dev, settings=settings)
    assert result.status == update.OK, result.message
    assert not dev.loader and not dev.silent and dev.crc() == NEW_IMAGE.crc
    assert isinstance(d.steps[1], update.Note) and "switch node 16 off and on" in d.steps[1].text
    assert isinstance(d.steps[2], update.HoldInLoader)
    assert result.before.loader, "identified as the loader the window kept"


def test_a_rescue_nobody_answers_fails_with_a_hint():
    settings = update.Settings(node=16, rescue=True, rescue_timeout=3)
    plan = update.Update(NEW_IMAGE, settings)
    while not isinstance(plan.step, update.HoldInLoader):
        plan.answer(Ok())
    assert plan.step.timeout == 3
    plan.answer(NoAnswer("no answer within 3 s"))
    assert plan.step is None and plan.result.status == update.FAILED
    assert "rescue: no answer to the loader's request within 3 s" in plan.result.message


def test_a_node_that_never_answers_fails_with_a_hint():
    result, d = run(ProgramDevice(OLD), lambda n, s: LOSE_REQUEST)
    assert result.status == update.FAILED
    assert "no answer from node 16 reading the device type 0x1000 (3 times" in result.message
    assert "node-ID and bit rate" in result.message and "was not changed" in result.message


def test_texts():
    assert update.abort_text(0x0800_0020).startswith(
        "SDO abort 0x08000020 (data cannot be transferred or stored to the application): the "
        "CRC does not match"
    )
    assert update.abort_text(0x1234_5678) == "SDO abort 0x12345678 (unknown abort code)"
    assert update.status_text(3 << 1 | 1) == (
        "0x1F57 = 0x00000007: code 3, data format error (the CRC does not match, or the stream "
        "ended short or ran past its length), in progress"
    )
    assert update.status_text(99 << 1).endswith("code 99, unknown code")
    assert update.retry_command(["fw.bin", "--channel", "my can"]) == (
        "canopen-handwheel update fw.bin --channel 'my can'"
    )
    assert update.progress_text(0, 100, 0.0) == f"[{'.' * 30}]   0 % 0/100 B 0 s"
    assert update.progress_text(50, 100, 10.0) == (
        f"[{'#' * 15}{'.' * 15}]  50 % 50/100 B 10 s, about 10 s left"
    )
    assert update.progress_text(100, 100, 20.0) == f"[{'#' * 30}] 100 % 100/100 B 20 s"


FAULTS = st.sampled_from([None] * 6 + [LOSE_ANSWER, LOSE_REQUEST, LOSE_BOOTUP, MASTER_STARTS])


@settings(max_examples=300, deadline=None)
@given(
    st.lists(FAULTS, max_size=80),
    st.booleans(),
    st.integers(0, 3),
    st.sampled_from(update.TRANSFERS),
    st.booleans(),
)
def test_whatever_goes_wrong_the_update_ends_and_never_claims_what_is_not(
    faults, loader, polls, transfer, block
):
    """Lost answers, lost requests, lost boot-ups and another master's NMT start at any
    steps, with any transfer setting, on a device with block download or without: the
    update ends within a bounded number of steps, never raises, and reports success only
    when the device runs the new application; a download is never by a transfer the setting
    excludes, and never by block again once it went segmented; a device it leaves in its
    loader still answers and takes a clean update afterwards."""
    dev = ProgramDevice(None if loader else OLD, status_polls=polls)
    settings = dataclasses.replace(FAST, transfer=transfer)
    result, d = run(dev, lambda n, s: faults[n] if n < len(faults) else None, settings, block=block)
    assert result.status in (update.OK, update.FAILED, update.REFUSED)
    assert result.message
    if result.status == update.OK:
        assert not dev.loader and dev.crc() == NEW_IMAGE.crc
    used = [t for _, t in downloads(d)]
    if transfer != update.AUTO:
        assert set(used) <= {transfer}
    assert BLOCK not in used[used.index(SEGMENTED) :] if SEGMENTED in used else True
    if transfer == BLOCK and not block:
        assert result.status != update.OK
    # The device is never left unreachable, and a clean run afterwards updates it.
    again, _ = run(dev, block=block)
    assert again.status == update.OK and not dev.loader and dev.crc() == NEW_IMAGE.crc


# The file --------------------------------------------------------------------------------


def test_the_update_file_is_parsed():
    img = image.UpdateImage.parse(NEW)
    assert (img.vendor_id, img.product_code, img.version, img.length) == (
        VENDOR,
        PRODUCT,
        4,
        3000,
    )
    assert img.crc == zlib.crc32(NEW[512:]) and img.data == NEW
    assert NEW[:4] == b"HWIM" and len(NEW) == 512 + 3000
    assert NEW[0x20:0x200] == b"\xff" * 0x1E0
    assert img.describe() == (
        f"version 4, CRC 0x{img.crc:08X}, 3000 bytes, for vendor 0x{VENDOR:08X} product "
        f"0x{PRODUCT:08X}"
    )


def _patched(offset, fmt, value):
    data = bytearray(NEW)
    struct.pack_into(fmt, data, offset, value)
    return bytes(data)


@pytest.mark.parametrize(
    "data, why",
    [
        (NEW[:511], "shorter than the 512-byte header slot"),
        (b"\x7fELF" + NEW[4:], "not b'HWIM'"),
        (_patched(4, "<H", 2), "header format 2, size 32"),
        (_patched(6, "<H", 64), "header format 1, size 64"),
        (_patched(0x14, "<I", 0xFFFF_FFFF), "not sealed"),
        (_patched(0x14, "<I", image.SLOT_SIZE), "does not fit the 51200-byte"),
        (NEW + b"\xff", "the file has 3001"),
        (NEW[:-1], "the file has 2999"),
        (NEW[:-1] + bytes([NEW[-1] ^ 1]), "its header says"),
    ],
)
def test_a_bad_file_is_refused_with_its_reason(data, why):
    with pytest.raises(image.ImageError, match=why.replace("(", r"\(")):
        image.UpdateImage.parse(data)


def test_the_largest_image_that_fits_the_slot():
    body = bytes(image.SLOT_SIZE - image.SLOT_HEADER)
    assert image.UpdateImage.parse(image.build(body, VENDOR, PRODUCT, 1)).length == len(body)
    with pytest.raises(image.ImageError, match="does not fit"):
        image.UpdateImage.parse(image.build(body + b"\0", VENDOR, PRODUCT, 1))


@given(st.binary(max_size=600))
def test_any_bytes_parse_or_raise_image_error(data):
    try:
        img = image.UpdateImage.parse(data)
    except image.ImageError:
        return
    assert zlib.crc32(data[512:]) == img.crc and len(data) == 512 + img.length


def test_loader_device_type_is_the_contracts():
    assert LOADER_DEVICE_TYPE == update.LOADER_DEVICE_TYPE == 0x544F_4F42
    assert struct.pack("<I", LOADER_DEVICE_TYPE) == b"BOOT"
