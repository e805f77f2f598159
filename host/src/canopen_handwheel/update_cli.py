"""`canopen-handwheel update FILE`: the firmware update over CAN (CiA 302-3 program
download, docs/FIRMWARE-UPDATE.md). The shell around `update.Update`: it reads and checks
the file (`image.UpdateImage`, before the bus is opened), opens the bus with the component's
options (`bus.py`), carries out each step over python-canopen, shows the download's progress
on stderr and prints the outcome. It decides nothing itself.

python-canopen's SDO client repeats no request here (`MAX_RETRIES`): whether a step that got
no answer is repeated is the planner's decision, since the device may have carried it out.
Likewise which transfer a download uses (`update.Download.transfer`): the shell only tells
the planner whether an abort answered the download's initiate (`update.Aborted.at_initiate`),
which python-canopen shows by raising it from `SdoClient.open` itself.
"""

from __future__ import annotations

import argparse
import io
import queue
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Optional, Sequence, TextIO

from . import bus as buses
from . import update
from .image import ImageError, UpdateImage

# Bytes handed to python-canopen's download stream per write (7 fit one segment, segmented
# or in a sub-block).
SEGMENT = 7
# The client's abort of a block download python-canopen cannot carry on (`write_segment`):
# CiA 301's general error.
ABORT_GENERAL = 0x0800_0000


def log(message: str) -> None:
    sys.stderr.write(f"canopen-handwheel update: {message}\n")
    sys.stderr.flush()


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="canopen-handwheel update",
        description="Update the handwheel's firmware over CAN (CiA 302-3 program download) "
        "with the update file `cargo xtask fw` writes (it prints `update image: PATH`). The "
        "device must not have its feed enabled. Exit status: 0 updated, 1 failed (the "
        "message says how to retry), 2 usage, 3 refused (nothing was changed), 4 not an "
        "update file (nothing was sent), 5 the new image went in but never became healthy "
        "(update with a good image; the message says how).",
    )
    p.add_argument("file", help="the update file")
    buses.add_bus_options(p)
    p.add_argument(
        "--retries",
        type=int,
        default=update.Settings.retries,
        help=f"download again from clear after a failed download this many times "
        f"({update.Settings.retries}, 0..10)",
    )
    p.add_argument(
        "--sdo-timeout",
        type=float,
        default=1.0,
        help="seconds to wait for each SDO answer (1.0, 0.05..10)",
    )
    p.add_argument(
        "--sdo-transfer",
        choices=update.TRANSFERS,
        default=update.Settings.transfer,
        help="how the file goes to 0x1F50:1: 'block', CiA 301 SDO block download (sub-blocks "
        "of up to 127 segments, each acknowledged once the device has it in flash; the "
        "CRC-16 of the whole checked at the end); 'segmented', every 7-byte segment "
        "answered; 'auto', block where the device offers it, else segmented: a device "
        "without block download aborts the block initiate (0x05040001), and the download "
        f"goes segmented at once and for the rest of the run ({update.Settings.transfer})",
    )
    p.add_argument(
        "--boot-timeout",
        type=float,
        default=update.Settings.boot_timeout,
        help=f"seconds to wait for the boot-up after stop and start "
        f"({update.Settings.boot_timeout:g}, 0.1..60)",
    )
    p.add_argument(
        "--status-timeout",
        type=float,
        default=update.Settings.status_timeout,
        help=f"seconds the flash status 0x1F57 may show 'in progress' "
        f"({update.Settings.status_timeout:g}, 0.1..600)",
    )
    p.add_argument(
        "--trial-timeout",
        type=float,
        default=update.Settings.trial_timeout,
        help=f"seconds to wait, after a start the new image does not answer, for the loader "
        f"that ends a failed trial boot ({update.Settings.trial_timeout:g}, 1..600)",
    )
    p.add_argument(
        "--rescue",
        action="store_true",
        help="first hold the device in its loader: asks you to switch the board off and on, "
        "and sends the loader's request (0x1F51:1 = 0) until the loader answers it in its "
        "window at power-on; for a device whose image never answers",
    )
    p.add_argument(
        "--rescue-timeout",
        type=float,
        default=update.Settings.rescue_timeout,
        help=f"seconds to wait for the power cycle with --rescue "
        f"({update.Settings.rescue_timeout:g}, 1..3600)",
    )
    args = p.parse_args(argv)
    for name, low, high in (
        ("node", 1, 127),
        ("retries", 0, 10),
        ("sdo_timeout", 0.05, 10),
        ("boot_timeout", 0.1, 60),
        ("status_timeout", 0.1, 600),
        ("trial_timeout", 1, 600),
        ("rescue_timeout", 1, 3600),
    ):
        value = getattr(args, name)
        if not low <= value <= high:  # also false for nan
            p.error(f"--{name.replace('_', '-')} must be {low}..{high}")
    return args


class Progress:
    """The download's progress on `out`: one line redrawn in place on a terminal, else a
    line every 10 %."""

    def __init__(self, total: int, out: TextIO, clock: Callable[[], float] = time.monotonic):
        self.total = total
        self.out = out
        self.clock = clock
        self.start = clock()
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.shown = -1  # percent (terminal: hundredths of a second too) last shown
        self.last_draw = 0.0

    def show(self, done: int) -> None:
        now = self.clock()
        percent = 100 * done // max(self.total, 1)
        text = update.progress_text(done, self.total, now - self.start)
        if self.tty:
            if done < self.total and now - self.last_draw < 0.1:
                return
            self.last_draw = now
            self.out.write(f"\r{text}")
            if done >= self.total:
                self.out.write("\n")
        elif percent // 10 > self.shown // 10 or (done >= self.total and percent != self.shown):
            self.shown = percent
            self.out.write(f"{text}\n")
        self.out.flush()

    def end(self) -> None:
        """A download that stopped short: the terminal's line is ended."""
        if self.tty:
            self.out.write("\n")
            self.out.flush()


class Bootups:
    """The node's boot-ups (0x700 + node, data 0x00) as python-canopen's notifier sees
    them."""

    def __init__(self) -> None:
        self.count = 0
        self.armed = 0
        self.cond = threading.Condition()

    def on_frame(self, can_id: int, data, timestamp) -> None:
        if bytes(data) == b"\x00":
            with self.cond:
                self.count += 1
                self.cond.notify_all()

    def arm(self) -> None:
        with self.cond:
            self.armed = self.count

    def wait(self, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: self.count > self.armed, timeout)


class Device:
    """python-canopen's view of the node: SDO client, NMT, boot-ups."""

    def __init__(self, network, node_id: int, sdo_timeout: float) -> None:
        import canopen

        self.network = network
        self.node = network.add_node(canopen.RemoteNode(node_id, canopen.ObjectDictionary()))
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout
        self.node.sdo.MAX_RETRIES = 1  # python-canopen's count includes the first request
        self.bootups = Bootups()
        network.subscribe(0x700 + node_id, self.bootups.on_frame)


def carry_out(
    device: Device,
    step,
    data: bytes,
    out: Optional[TextIO] = None,
    sleep: Callable[[float], None] = time.sleep,
):
    """One step of `update.Update` over python-canopen: its outcome."""
    import canopen

    sdo = device.node.sdo
    try:
        if isinstance(step, update.Read):
            return update.Ok(int.from_bytes(sdo.upload(step.index, step.sub), "little"))
        if isinstance(step, update.Write):
            if step.arm_bootup:
                device.bootups.arm()
            sdo.download(step.index, step.sub, step.value.to_bytes(step.size, "little"))
            return update.Ok()
        if isinstance(step, update.PreOperational):
            device.node.nmt.state = "PRE-OPERATIONAL"
            return update.Ok()
        if isinstance(step, update.WaitBootup):
            if device.bootups.wait(step.timeout):
                return update.Ok()
            return update.NoAnswer(f"no boot-up within {step.timeout:g} s")
        if isinstance(step, update.Pause):
            sleep(step.seconds)
            return update.Ok()
        if isinstance(step, update.Note):
            log(step.text)
            return update.Ok()
        if isinstance(step, update.Download):
            return download(device, step, data, out)
        if isinstance(step, update.HoldInLoader):
            return hold_in_loader(device, step, sleep)
    except canopen.SdoAbortedError as e:
        settle(device, sleep)
        return update.Aborted(e.code)
    except canopen.SdoCommunicationError as e:
        settle(device, sleep)
        return update.NoAnswer(str(e))
    raise TypeError(f"unknown step {step!r}")


def hold_in_loader(
    device: Device, step: update.HoldInLoader, sleep: Callable[[float], None] = time.sleep
):
    """`update.RESCUE_REQUEST` to the node every `step.interval` s until its answer comes:
    the loader's window at power-on is short (docs/FIRMWARE-UPDATE.md), so the request must
    be on the bus whenever it opens. Answers that arrive after the first go to python-canopen's
    SDO queue: they are dropped (`settle`) before the update goes on."""
    import can

    node = device.node.id
    answered = threading.Event()

    def on_answer(can_id: int, data, timestamp) -> None:
        if bytes(data[:4]) == update.RESCUE_ANSWER:
            answered.set()

    device.network.subscribe(0x580 + node, on_answer)
    deadline = time.monotonic() + step.timeout
    try:
        while not answered.is_set():
            if time.monotonic() > deadline:
                return update.NoAnswer(f"no answer within {step.timeout:g} s")
            try:
                device.network.send_message(0x600 + node, update.RESCUE_REQUEST)
            except can.CanError:
                pass  # a full transmit queue while nobody acknowledges: the next one goes
            answered.wait(step.interval)
    finally:
        device.network.unsubscribe(0x580 + node, on_answer)
    settle(device, sleep)
    return update.Ok()


# How long a failed SDO exchange may still bring answers in: the device answers a request
# that crossed its abort (a segment after a toggle error gets "unknown command"), and an
# answer the master gave up on may yet arrive.
SETTLE = 0.2


def settle(device: Device, sleep: Callable[[float], None] = time.sleep) -> None:
    """After a failed exchange: waits for late answers, then drops them, so that the next
    request reads its own answer and not one left over (python-canopen empties its queue
    only before a request, not of answers that arrive after it was sent)."""
    sleep(SETTLE)
    device.node.sdo.responses = queue.Queue()


def download(device: Device, step: update.Download, data: bytes, out: Optional[TextIO] = None):
    """0x1F50:1 = `data`, its size indicated, by `step.transfer`, the progress shown on `out`
    (stderr). Segmented: python-canopen's `WritableStream`, each `write` one segment and its
    answer. Block: its `BlockDownloadStream` with the CRC requested; `write` sends one segment
    of a sub-block, and after the sub-block's last (or the transfer's) waits for the
    acknowledgement, sending again what the device did not take; `close` sends the end with
    the CRC and waits for its answer. An abort raised by `open` answered the initiate."""
    import canopen

    out = sys.stderr if out is None else out
    log(
        f"downloading {len(data)} bytes by {update.TRANSFER_TEXT[step.transfer]} "
        f"(attempt {step.attempt} of {step.attempts})"
    )
    progress = Progress(len(data), out)
    stream = None
    sent = 0
    try:
        stream = device.node.sdo.open(
            0x1F50,
            1,
            "wb",
            buffering=0,
            size=len(data),
            block_transfer=step.transfer == update.BLOCK,
            request_crc_support=True,
        )
        progress.show(0)
        while sent < len(data):
            sent += write_segment(device, stream, data[sent : sent + SEGMENT])
            progress.show(sent)
        # Segmented: every byte went with its segment, nothing more is sent. Block: the end
        # request with the CRC, answered; only here, after the last segment was acknowledged.
        stream.close()
        return update.Ok()
    except (canopen.SdoAbortedError, canopen.SdoCommunicationError) as e:
        progress.end()
        if stream is not None:
            drop(stream)
        reason = (
            update.Aborted(e.code, at_initiate=stream is None)
            if isinstance(e, canopen.SdoAbortedError)
            else update.NoAnswer(f"{e} after {sent} of {len(data)} bytes")
        )
        settle(device)
        return reason


def write_segment(device: Device, stream, chunk: bytes) -> int:
    """`chunk` (up to 7 bytes) to `stream`: the bytes it took. python-canopen 2.4.1's block
    download cannot send again segments of the transfer's last sub-block that the device did
    not take: its `_retransmit` goes through `write`, which raises RuntimeError once the last
    segment has been sent. The transfer is then aborted (the device would wait for them until
    its SDO timeout) and fails as one without an answer would."""
    import canopen

    try:
        return stream.write(chunk)
    except RuntimeError as e:
        device.node.sdo.abort(ABORT_GENERAL)
        raise canopen.SdoCommunicationError(
            f"python-canopen could not send again the segments of the last sub-block the "
            f"device did not take ({e}); the client aborted the transfer"
        ) from e


def drop(stream) -> None:
    """A stream that failed is over (the device aborted it, or the client did): it is closed
    without what python-canopen's `close` would send, also when the garbage collector calls
    it: a segmented download's empty last segment (sent unless `_done`), a block download's
    end request with its CRC (sent unless `closed`)."""
    stream._done = True
    io.RawIOBase.close(stream)


def run(args: argparse.Namespace, argv: Sequence[str], out: Optional[TextIO] = None) -> int:
    """The update with parsed `args` (`argv`: the options as given, for the retry line)."""
    try:
        data = Path(args.file).read_bytes()
    except OSError as e:
        log(f"cannot read {args.file}: {e.strerror or e}")
        return update.EXIT_BAD_FILE
    try:
        image = UpdateImage.parse(data)
    except ImageError as e:
        log(f"{args.file} is not an update file this device takes: {e}. Nothing was sent.")
        return update.EXIT_BAD_FILE
    settings = update.Settings(
        node=args.node,
        retries=args.retries,
        boot_timeout=args.boot_timeout,
        status_timeout=args.status_timeout,
        trial_timeout=args.trial_timeout,
        rescue=args.rescue,
        rescue_timeout=args.rescue_timeout,
        transfer=args.sdo_transfer,
    )
    import canopen

    try:
        bus = buses.open_bus(args.interface, args.channel, args.bitrate)
    except Exception as e:
        log(
            f"cannot open the bus ({e!r}). Nothing was sent. To retry: {update.retry_command(argv)}"
        )
        return update.EXIT_FAILED
    network = canopen.Network(bus)
    try:
        network.connect()  # the bus is there: only python-canopen's notifier is started
        device = Device(network, args.node, args.sdo_timeout)
        plan = update.Update(image, settings)
        while plan.step is not None:
            plan.answer(carry_out(device, plan.step, image.data, out))
    finally:
        network.disconnect()
    result = plan.result
    assert result is not None
    if result.status == update.OK:
        print(result.message)
    else:
        log(f"{result.status}: {result.message}")
        if result.status == update.FAILED:
            log(f"to retry: {update.retry_command(argv)}")
    return result.exit_code


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[2:] if argv is None else argv)
    args = parse_args(argv)
    try:
        return run(args, argv)
    except KeyboardInterrupt:
        log(
            "interrupted: the device may be in its loader; it answers on the bus and takes "
            f"the next update. To retry: {update.retry_command(argv)}"
        )
        return update.EXIT_FAILED
