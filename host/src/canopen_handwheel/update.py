"""`canopen-handwheel update`'s decisions, free of CAN: the CiA 302-3 program download of
docs/FIRMWARE-UPDATE.md ("The host command") as a state machine that names the next step
from what the device answered.

`Update(image, settings)` holds the step to carry out (`step`); the shell carries it out and
hands back its outcome (`answer`), which gives the next step, until `step` is None and
`result` says how it ended. Steps: `Read`, `Write` (an expedited SDO download; `arm_bootup`:
forget the boot-ups seen so far first, so that `WaitBootup` waits for one after this write),
`PreOperational` (NMT to the node), `WaitBootup`, `Pause`, `Download` (0x1F50:1, the whole
update file, by SDO block download or segmented: its `transfer`), `HoldInLoader` (the rescue
request until it is answered) and `Note` (a line for the operator). Outcomes: `Ok` (with the
value of a `Read`), `Aborted` (the SDO abort code; for a `Download`, whether it answered the
transfer's initiate) and `NoAnswer` (a timeout, an unexpected frame, no boot-up in time).

The order, and why:
- read 0x1000 (application or loader), 0x1018 (the file must be for this device: a loader's
  product code is the application's with bit 31 set), 0x1F56 (the CRC that runs) and 0x1F57
  (polled until it is not "in progress": read once, a slow flash fails the update);
- in the application: refuse while the feed is enabled (0x2000 = 1: somebody jogs with it);
  NMT pre-operational; 0x1F51 = 0, which the application answers and then resets into its
  loader; wait for the boot-up and check 0x1000 = BOOT;
- in the loader: NMT pre-operational, 0x1F51 = 3 (clear), poll 0x1F57, download, poll
  0x1F57, read 0x1F56 (it must be the file's CRC before the loader is told to start it);
  a failure here is tried again from "clear", `Settings.retries` times;
- the download goes by SDO block download (CRC-16 checked, acknowledged per sub-block) where
  the device offers it (`Settings.transfer` `AUTO`): a server without block download aborts
  the block download's initiate with 0x05040001, before any data, so the same attempt goes
  on at once segmented (the device did nothing: no clear again), and so does every later
  attempt of the run. That abort later in a transfer, or any other abort, is a failed
  attempt. `BLOCK` or `SEGMENTED` use that transfer only;
- 0x1F51 = 1, wait for the application's boot-up, check 0x1000, read 0x1F56 and 0x1018:3.
  The loader starts a new image on trial: one that never becomes healthy on the bus (a hang,
  a fault) is reset by the watchdog until, after 3 starts, the loader stays and says so in
  0x1F57 (code 64): then the update ends `UNHEALTHY`, and the way on is an update with a good
  image, not this one again. A device that answers nothing after the start (an image that
  feeds the watchdog but never talks, or talks at the wrong bit rate) ends `UNHEALTHY` too:
  the way back is `--rescue`;
- with `Settings.rescue`, first `HoldInLoader`: the loader's request (0x1F51:1 = 0) sent
  again and again while the operator power-cycles the board, until the loader answers it in
  its listening window at power-on (docs/FIRMWARE-UPDATE.md, "The way back at power-on").
A write of 0x1F51 whose answer did not come is repeated only after reading 0x1F51 (or, for
stop and start, which reset the device, after looking for its boot-up and its 0x1000): the
device may have done it, and repeating a done step is refused (0x08000022) and misleads.

Pure: standard library and the package's pure modules only.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from typing import Generator, Optional, Sequence

from . import update_contract as contract
from .decode import SDO_ABORTS
from .image import UpdateImage

# The objects (CiA 301, CiA 302-3) and the application's feed enable.
DEVICE_TYPE = (0x1000, 0)
VENDOR_ID = (0x1018, 1)
PRODUCT_CODE = (0x1018, 2)
REVISION = (0x1018, 3)
PROGRAM_DATA = (0x1F50, 1)
PROGRAM_CONTROL = (0x1F51, 1)
PROGRAM_ID = (0x1F56, 1)
FLASH_STATUS = (0x1F57, 1)
FEED_ENABLE = (0x2000, 0)

# The loader's identity (crates/canopen-loader, through update_contract.py): its 0x1000, and
# its 0x1018:2 is the application's product code with this bit set.
LOADER_DEVICE_TYPE = contract.LOADER_DEVICE_TYPE
LOADER_PRODUCT_BIT = contract.LOADER_PRODUCT_BIT

# 0x1F51 values.
STOP = 0
START = 1
CLEAR = 3
CONTROL_NAMES = {STOP: "stop", START: "start", CLEAR: "clear"}

# 0x1F57: bit 0 in progress, bits 1-7 the code, and what each code means: the loader's codes
# with their meanings (crates/canopen-loader, through update_contract.py), and two of CiA
# 302-3's that this loader never reports.
IN_PROGRESS = contract.FLASH_IN_PROGRESS
CODE_SHIFT = contract.FLASH_CODE_SHIFT
NO_ERROR = contract.FLASH_STATUS_OK
NO_VALID_PROGRAM = contract.FLASH_STATUS_NO_VALID_PROGRAM
TRIAL_FAILED = contract.FLASH_STATUS_TRIAL_FAILED  # the first manufacturer-specific code
STATUS_CODES = {
    **contract.FLASH_STATUS_MEANINGS,
    7: "flash secured",
    63: "unspecified error",
}

# SDO aborts (CiA 301), and what the loader and the application mean by them here.
ABORT_NO_OBJECT = 0x0602_0000
ABORT_NO_SUBINDEX = 0x0609_0011
ABORT_DEVICE_STATE = 0x0800_0022
PROGRAM_ABORTS = {
    0x0609_0030: "the header is unknown or the image is for another device (or an invalid "
    "0x1F51 value)",
    0x0800_0020: "the CRC does not match, or the stream ended short or ran past its length",
    ABORT_DEVICE_STATE: "not in the state for it (not Pre-operational, the feed enabled, data "
    "before clear, or start without a valid program)",
    0x0606_0000: "flash erase or program failed",
    0x0504_0005: "the image does not fit the application slot",
}

# How the update file goes to 0x1F50:1 (`Settings.transfer`, `Download.transfer`): CiA 301
# SDO block download (sub-blocks of up to 127 segments, each acknowledged; the CRC-16 of the
# whole checked by the device at the end), segmented (every 7-byte segment answered), or
# block where the device offers it and segmented where it does not.
AUTO = "auto"
BLOCK = "block"
SEGMENTED = "segmented"
TRANSFERS = (AUTO, BLOCK, SEGMENTED)
TRANSFER_TEXT = {BLOCK: "SDO block download", SEGMENTED: "segmented SDO download"}
# The abort of a block download's initiate by a server without block download (CiA 301:
# client/server command specifier not valid or unknown).
ABORT_NO_BLOCK = 0x0504_0001

# Exit status of the command.
EXIT_OK = 0
EXIT_FAILED = 1  # the device did not take the update (see the message; retry)
EXIT_REFUSED = 3  # the device must not be updated now, or not with this file
EXIT_BAD_FILE = 4  # the file is not an update image (nothing was sent)
EXIT_UNHEALTHY = 5  # the image went in, but never became healthy: update with a good one

OK = "ok"
FAILED = "failed"
REFUSED = "refused"
UNHEALTHY = "unhealthy"
EXIT_CODES = {OK: EXIT_OK, FAILED: EXIT_FAILED, REFUSED: EXIT_REFUSED, UNHEALTHY: EXIT_UNHEALTHY}

# The request that keeps the loader in its listening window at power-on: an SDO expedited
# download of 0x1F51:1 = 0 ("stop"), and the loader's (or the application's) answer to it.
RESCUE_REQUEST = bytes([0x2F, 0x51, 0x1F, 0x01, 0x00, 0x00, 0x00, 0x00])
RESCUE_ANSWER = bytes([0x60, 0x51, 0x1F, 0x01])


def abort_text(code: int) -> str:
    """An SDO abort code in words: CiA 301's meaning, and the loader's where it has one."""
    text = f"SDO abort 0x{code:08X} ({SDO_ABORTS.get(code, 'unknown abort code')})"
    if code in PROGRAM_ABORTS:
        text += f": {PROGRAM_ABORTS[code]}"
    return text


def status_text(value: int) -> str:
    """0x1F57 in words."""
    code = (value >> CODE_SHIFT) & contract.FLASH_CODE_MASK
    text = f"0x1F57 = 0x{value:08X}: code {code}, {STATUS_CODES.get(code, 'unknown code')}"
    if value & IN_PROGRESS:
        text += ", in progress"
    return text


def retry_command(argv: Sequence[str]) -> str:
    """The command line that retries the update (the same options)."""
    return shlex.join(["canopen-handwheel", "update", *argv])


def progress_text(done: int, total: int, elapsed: float, width: int = 30) -> str:
    """The progress bar's text: bytes sent of all, a bar, percent, time and what is left."""
    total = max(total, 1)
    done = min(max(done, 0), total)
    filled = width * done // total
    text = (
        f"[{'#' * filled}{'.' * (width - filled)}] {100 * done // total:3d} % "
        f"{done}/{total} B {elapsed:.0f} s"
    )
    if 0 < done < total and elapsed > 0:
        text += f", about {elapsed * (total - done) / done:.0f} s left"
    return text


# Steps ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Read:
    index: int
    sub: int
    what: str


@dataclass(frozen=True)
class Write:
    index: int
    sub: int
    value: int
    size: int
    what: str
    arm_bootup: bool = False


@dataclass(frozen=True)
class PreOperational:
    """NMT enter pre-operational, to the node."""


@dataclass(frozen=True)
class WaitBootup:
    """Wait up to `timeout` s for the node's boot-up (0x700 + node, data 0x00) since the last
    `Write` with `arm_bootup`."""

    timeout: float


@dataclass(frozen=True)
class Pause:
    seconds: float


@dataclass(frozen=True)
class Download:
    """0x1F50:1 = the whole update file, its size indicated, by `transfer` (`BLOCK`: SDO block
    download with the CRC; `SEGMENTED`); `attempt` of `attempts`. An abort is `Aborted` with
    `at_initiate` true when it answered the initiate (no data went), false when it came later
    (a sub-block's acknowledgement, a segment's answer, the block download's end)."""

    size: int
    attempt: int
    attempts: int
    transfer: str = SEGMENTED


@dataclass(frozen=True)
class Note:
    text: str


@dataclass(frozen=True)
class HoldInLoader:
    """Send `RESCUE_REQUEST` to the node every `interval` s until `RESCUE_ANSWER` comes
    (`Ok`), at most `timeout` s (`NoAnswer`); an abort answer (a running application that
    refuses the stop) is no answer: the loader's window comes with the next power-on."""

    timeout: float
    interval: float = 0.01


Step = object  # Read | Write | PreOperational | WaitBootup | Pause | Download | HoldInLoader | Note


# Outcomes ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Ok:
    value: Optional[int] = None


@dataclass(frozen=True)
class Aborted:
    """The SDO abort `code`; `at_initiate`: a `Download`'s abort that answered its initiate
    (false for every other step)."""

    code: int
    at_initiate: bool = False


@dataclass(frozen=True)
class NoAnswer:
    why: str = "no answer"


Outcome = object  # Ok | Aborted | NoAnswer


@dataclass(frozen=True)
class Settings:
    node: int = 16
    retries: int = 2  # downloads again from "clear" after a failed one
    boot_timeout: float = 5.0  # s for a boot-up after stop and start
    status_timeout: float = 10.0  # s 0x1F57 may show "in progress"
    poll_interval: float = 0.05  # s between reads of 0x1F57
    read_attempts: int = 3  # a read without an answer is repeated (reads change nothing)
    control_attempts: int = 3  # a 0x1F51 write is tried at most this often
    # s to wait, after a start the application does not answer, for the loader that ends a
    # failed trial boot: 3 starts of up to 2 s each (the watchdog) and the loader's window.
    trial_timeout: float = 15.0
    rescue: bool = False  # first hold the device in its loader at a power-on (HoldInLoader)
    rescue_timeout: float = 60.0  # s the operator has for the power cycle
    transfer: str = AUTO  # how 0x1F50:1 goes: AUTO, BLOCK or SEGMENTED (`TRANSFERS`)


@dataclass(frozen=True)
class Identity:
    """What a device said about itself."""

    loader: bool
    vendor_id: int
    product_code: int
    revision: int
    program_crc: int  # 0x1F56
    flash_status: int  # 0x1F57

    def describe(self) -> str:
        kind = "loader" if self.loader else "application"
        return (
            f"{kind}, revision {self.revision}, program CRC 0x{self.program_crc:08X} "
            f"(vendor 0x{self.vendor_id:08X}, product 0x{self.product_code:08X}; "
            f"{status_text(self.flash_status)})"
        )


@dataclass(frozen=True)
class Result:
    status: str  # OK, FAILED or REFUSED
    message: str
    before: Optional[Identity] = None
    version: Optional[int] = None  # the application's 0x1018:3 after the update
    crc: Optional[int] = None  # its 0x1F56 after the update

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.status]


# Where the device is, for the failure messages: what it does now and what it takes.
UNTOUCHED = "The device was not changed."
STOPPED_VALID = (
    "The device waits in its loader; its application is unchanged (a power cycle starts it again)."
)
CLEARED = (
    "The device waits in its loader without a valid application; it answers on the bus and "
    "takes the next update."
)
STARTED = "The device was told to start the new application."
# What to do about an image that went in but never became healthy.
RECOVER = (
    "Sending this image again would not help: update with a good image, e.g. "
    "`canopen-handwheel update GOOD.update` (the one the device ran before)."
)
RESCUE = (
    "Update with a good image through the loader's window at power-on: "
    "`canopen-handwheel update GOOD.update --rescue`, then switch the board off and on."
)


class _End(Exception):
    def __init__(self, status: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


class Update:
    """The program download of `image` to `settings.node`: `step`, `answer`, `result`."""

    def __init__(self, image: UpdateImage, settings: Settings = Settings()) -> None:
        if settings.transfer not in TRANSFERS:
            raise ValueError(f"transfer {settings.transfer!r} is not one of {TRANSFERS}")
        self.image = image
        self.settings = settings
        # The next `Download`'s transfer: AUTO starts with block and, once the device has
        # refused it at the initiate, stays segmented for the rest of the run.
        self.transfer = SEGMENTED if settings.transfer == SEGMENTED else BLOCK
        self.place = UNTOUCHED
        self.before: Optional[Identity] = None
        self.result: Optional[Result] = None
        self._run = self._update()
        self.step: Optional[Step] = next(self._run)

    def answer(self, outcome: Outcome) -> Optional[Step]:
        """The outcome of `step`; returns the next step (None: `result` is set)."""
        if self.step is None:
            raise RuntimeError("the update has ended")
        try:
            self.step = self._run.send(outcome)
        except StopIteration as end:
            self.step = None
            self.result = end.value
        return self.step

    # The sequence ----------------------------------------------------------------------------

    def _update(self) -> Generator[Step, Outcome, Result]:
        try:
            return (yield from self._sequence())
        except _End as end:
            message = end.message
            if end.status == FAILED:
                message += " " + self.place
            return Result(end.status, message, self.before)

    def _sequence(self) -> Generator[Step, Outcome, Result]:
        img = self.image
        node = self.settings.node
        yield Note(f"update file: {img.describe()}")
        if self.settings.rescue:
            yield from self._rescue()
        before = self.before = yield from self._identify()
        yield Note(f"node {node}: {before.describe()}")
        if before.loader:
            no_program = before.flash_status >> CODE_SHIFT == NO_VALID_PROGRAM
            self.place = CLEARED if no_program else STOPPED_VALID
        else:
            yield from self._enter_loader()
        attempts = self.settings.retries + 1
        for attempt in range(1, attempts + 1):
            failure = yield from self._download(attempt, attempts)
            if failure is None:
                break
            if attempt < attempts:
                yield Note(f"{failure}; trying again from clear ({attempt + 1} of {attempts})")
        else:
            raise _End(FAILED, f"the download failed {attempts} times; the last: {failure}.")
        yield from self._start()
        crc = yield from self._u32(PROGRAM_ID, "the program identification 0x1F56")
        version = yield from self._u32(REVISION, "the revision number 0x1018:3")
        if crc != img.crc:
            raise _End(
                FAILED,
                f"the application started, but its 0x1F56 reads 0x{crc:08X}, not the file's "
                f"CRC 0x{img.crc:08X}.",
            )
        if before.loader:  # its revision was the loader's: the application's is not known
            summary = (
                f"node {node} updated from its loader (program CRC 0x{before.program_crc:08X}"
                f"): now version {version}, CRC 0x{crc:08X}"
            )
        else:
            summary = (
                f"node {node} updated: version {before.revision} -> {version}, CRC "
                f"0x{before.program_crc:08X} -> 0x{crc:08X}"
            )
        return Result(
            OK,
            summary,
            before,
            version,
            crc,
        )

    def _rescue(self) -> Generator[Step, Outcome, None]:
        """The loader's request, again and again, until the loader answers it in its window
        at the power-on the operator brings about (or a running application answers it and
        resets into its loader); then a pause for that reset and for late answers."""
        node = self.settings.node
        timeout = self.settings.rescue_timeout
        yield Note(
            f"rescue: switch node {node} off and on now (within {timeout:g} s); sending its "
            "loader's request (0x1F51:1 = 0) until it answers"
        )
        out = yield HoldInLoader(timeout)
        if not isinstance(out, Ok):
            raise _End(
                FAILED,
                f"rescue: no answer to the loader's request within {timeout:g} s "
                f"({self._what(out)}): was node {node} switched off and on, on this bus, at "
                "this node-ID and bit rate?",
            )
        yield Note(f"rescue: node {node} answered: its loader stays")
        yield Pause(0.5)

    def _identify(self) -> Generator[Step, Outcome, Identity]:
        """0x1000, 0x1018:1-3, 0x1F56, 0x1F57 (polled until not in progress); the file must
        be for this device; the application must have program download."""
        img = self.image
        node = self.settings.node
        device_type = yield from self._u32(
            DEVICE_TYPE, "the device type 0x1000", after_reset=self.settings.rescue
        )
        loader = device_type == LOADER_DEVICE_TYPE
        vendor = yield from self._u32(VENDOR_ID, "the vendor-ID 0x1018:1")
        product = yield from self._u32(PRODUCT_CODE, "the product code 0x1018:2")
        revision = yield from self._u32(REVISION, "the revision number 0x1018:3")
        expected = img.product_code | LOADER_PRODUCT_BIT if loader else img.product_code
        if vendor != img.vendor_id or product != expected:
            kind = "loader" if loader else "application"
            raise _End(
                REFUSED,
                f"the file is for vendor 0x{img.vendor_id:08X} product "
                f"0x{img.product_code:08X}; node {node} ({kind}) is vendor 0x{vendor:08X} "
                f"product 0x{product:08X}: another device's image (check --node and the file)",
            )
        out = yield from self._read(PROGRAM_ID, "the program identification 0x1F56")
        if isinstance(out, Aborted):
            if not loader and out.code in (ABORT_NO_OBJECT, ABORT_NO_SUBINDEX):
                raise _End(
                    REFUSED,
                    f"node {node} runs an application without program download (0x1F56: "
                    f"{abort_text(out.code)}): it needs the loader and this application "
                    "flashed once over SWD (host/README.md, Firmware update)",
                )
            raise _End(FAILED, f"reading 0x1F56: {abort_text(out.code)}.")
        assert isinstance(out, Ok) and out.value is not None
        status = yield from self._poll_status()
        return Identity(loader, vendor, product, revision, out.value, status)

    def _enter_loader(self) -> Generator[Step, Outcome, None]:
        """In the application: refuse with the feed enabled; pre-operational; 0x1F51 = 0;
        the loader's boot-up and its 0x1000. A refused stop (a master started the node
        again meanwhile) is tried again, each time after NMT pre-operational."""
        node = self.settings.node
        feed = yield from self._u32(FEED_ENABLE, "the feed enable 0x2000")
        if feed:
            raise _End(
                REFUSED,
                f"node {node} has its feed enabled (0x2000 = {feed}): a master jogs with it. "
                "Disable it first (turn the machine off, or set the component's enable pin "
                "false), then retry",
            )
        last = ""
        refused = False  # the last attempt was refused for the device's state
        for _ in range(self.settings.control_attempts):
            yield PreOperational()
            out = yield Write(*PROGRAM_CONTROL, STOP, 1, "stop (0x1F51 = 0)", arm_bootup=True)
            refused = isinstance(out, Aborted) and out.code == ABORT_DEVICE_STATE
            if isinstance(out, Aborted):
                last = f"stop (0x1F51 = 0): {abort_text(out.code)}"
                if out.code in (ABORT_NO_OBJECT, ABORT_NO_SUBINDEX):
                    raise _End(
                        REFUSED,
                        f"node {node} runs an application without program download ({last})",
                    )
                if out.code != ABORT_DEVICE_STATE:
                    raise _End(FAILED, f"{last}.")
                yield Note(f"{last}; again after NMT pre-operational")
                continue
            # Answered or not: the device may have done it (it answers, then resets).
            booted = yield WaitBootup(self.settings.boot_timeout)
            if isinstance(booted, Ok):
                self.place = STOPPED_VALID
            device_type = yield from self._device_type_after_reset()
            if device_type == LOADER_DEVICE_TYPE:
                self.place = STOPPED_VALID
                yield Note(f"node {node} is in its loader")
                return
            if isinstance(booted, Ok):
                raise _End(
                    FAILED,
                    f"node {node} restarted as its application, not its loader (0x1000 = "
                    f"0x{device_type:08X}): is the loader flashed (host/README.md)?",
                )
            last = f"stop (0x1F51 = 0): {self._what(out)}, no boot-up, still the application"
            yield Note(f"{last}; again")
        raise _End(REFUSED if refused else FAILED, f"the device did not stop: {last}.")

    def _download(self, attempt: int, attempts: int) -> Generator[Step, Outcome, Optional[str]]:
        """One attempt from clear to a checked image: None, or what went wrong."""
        yield PreOperational()
        failure = yield from self._control(CLEAR)
        if failure is not None:
            return failure
        self.place = CLEARED
        status = yield from self._poll_status()
        if status >> CODE_SHIFT not in (NO_ERROR, NO_VALID_PROGRAM):  # cleared
            return f"after clear, {status_text(status)}"
        size = len(self.image.data)
        out = yield Download(size, attempt, attempts, self.transfer)
        if self.settings.transfer == AUTO and self._block_not_offered(out):
            # Refused before any data: the loader is still cleared, the same attempt goes on
            # segmented, and so do the later ones.
            self.transfer = SEGMENTED
            yield Note(
                f"node {self.settings.node} does not offer SDO block download (its "
                f"initiate answered {abort_text(ABORT_NO_BLOCK)}): downloading segmented"
            )
            out = yield Download(size, attempt, attempts, self.transfer)
        if not isinstance(out, Ok):
            what = f"download of 0x1F50:1: {self._what(out)}"
            if self._block_not_offered(out):  # with --sdo-transfer block
                what += (
                    " at the block download's initiate (the device does not offer SDO block "
                    "download: --sdo-transfer auto or segmented)"
                )
            try:
                status = yield from self._poll_status()
            except _End as end:  # still the download's failure, with what 0x1F57 did
                return f"{what}; then {end.message.rstrip('.')}"
            return f"{what}; {status_text(status)}"
        status = yield from self._poll_status()
        if status >> CODE_SHIFT != NO_ERROR:
            return f"download of 0x1F50:1 answered, but {status_text(status)}"
        crc = yield from self._u32(PROGRAM_ID, "the program identification 0x1F56")
        if crc != self.image.crc:
            return (
                f"download done, but 0x1F56 reads 0x{crc:08X}, not the file's CRC "
                f"0x{self.image.crc:08X}"
            )
        return None

    def _control(self, value: int) -> Generator[Step, Outcome, Optional[str]]:
        """0x1F51 = `value` in the loader (clear), repeated without an answer only if
        reading 0x1F51 shows it not done: None, or what went wrong."""
        name = f"{CONTROL_NAMES[value]} (0x1F51 = {value})"
        last = ""
        for _ in range(self.settings.control_attempts):
            out = yield Write(*PROGRAM_CONTROL, value, 1, name)
            if isinstance(out, Ok):
                return None
            if isinstance(out, Aborted):
                status = yield from self._poll_status()
                return f"{name}: {abort_text(out.code)}; {status_text(status)}"
            last = f"{name}: {self._what(out)}"
            now = yield from self._read(PROGRAM_CONTROL, "the program control 0x1F51")
            if isinstance(now, Ok) and now.value == value:
                yield Note(f"{last}, but 0x1F51 reads {value}: done")
                return None
            yield Note(f"{last}; 0x1F51 reads {self._what(now)}: again")
        return f"{last} ({self.settings.control_attempts} times)"

    def _start(self) -> Generator[Step, Outcome, None]:
        """0x1F51 = 1, the application's boot-up and its 0x1000. Without an answer or a
        boot-up, the device's 0x1000 tells whether it started; only if it did not is start
        written again. A device that answers nothing after the start is given the time of a
        failed trial boot to come back as its loader; back in its loader with code 64, or
        never answering at all, the new image is `UNHEALTHY`."""
        node = self.settings.node
        last = ""
        for _ in range(self.settings.control_attempts):
            yield PreOperational()
            out = yield Write(*PROGRAM_CONTROL, START, 1, "start (0x1F51 = 1)", arm_bootup=True)
            if isinstance(out, Aborted):
                status = yield from self._poll_status()
                raise _End(
                    FAILED,
                    f"start (0x1F51 = 1): {abort_text(out.code)}; {status_text(status)}.",
                )
            self.place = STARTED
            booted = yield WaitBootup(self.settings.boot_timeout)
            answer = yield from self._try_read(
                DEVICE_TYPE, "the device type 0x1000", after_reset=True
            )
            if not isinstance(answer, Ok):
                trial = self.settings.trial_timeout
                yield Note(
                    f"node {node} does not answer after the start: waiting up to {trial:g} s "
                    "for its loader (it stays after 3 starts of an image that never becomes "
                    "healthy)"
                )
                booted = yield WaitBootup(trial)
                answer = yield from self._try_read(
                    DEVICE_TYPE, "the device type 0x1000", after_reset=True
                )
            if not isinstance(answer, Ok) or answer.value is None:
                raise _End(
                    UNHEALTHY,
                    f"node {node} never answered after the start of the new image "
                    f"({self._what(answer)}): it runs, but does not talk on the bus (it may "
                    "feed its watchdog and stay silent, or talk at another bit rate). " + RESCUE,
                )
            if answer.value != LOADER_DEVICE_TYPE:
                yield Note(f"node {node} runs its application")
                return
            status = yield from self._poll_status()
            if status >> CODE_SHIFT == TRIAL_FAILED:
                raise _End(
                    UNHEALTHY,
                    f"the new image never became healthy: node {node} came back as its loader "
                    f"({status_text(status)}). The device waits in its loader and answers on "
                    "the bus (a power-on gives the image 3 more starts). " + RECOVER,
                )
            if isinstance(booted, Ok):
                self.place = CLEARED
                raise _End(
                    FAILED,
                    f"node {node} came back in its loader, not the new application "
                    f"({status_text(status)}).",
                )
            last = f"start (0x1F51 = 1): {self._what(out)}, no boot-up, still the loader"
            now = yield from self._read(PROGRAM_CONTROL, "the program control 0x1F51")
            yield Note(f"{last} (0x1F51 reads {self._what(now)}): again")
        self.place = STOPPED_VALID
        raise _End(FAILED, f"the device did not start its application: {last}.")

    # Helpers ---------------------------------------------------------------------------------

    def _block_not_offered(self, out: Outcome) -> bool:
        """The outcome of a block `Download` (the next one's `transfer` is still `BLOCK`) that
        says the device has no block download: 0x05040001 answering its initiate (later in
        the transfer, or at a segmented download's initiate, it is a failed attempt)."""
        return (
            self.transfer == BLOCK
            and isinstance(out, Aborted)
            and out.at_initiate
            and out.code == ABORT_NO_BLOCK
        )

    def _device_type_after_reset(self) -> Generator[Step, Outcome, int]:
        """0x1000 after a reset: a device still booting may not answer the first read."""
        out = yield from self._read(DEVICE_TYPE, "the device type 0x1000", after_reset=True)
        if not isinstance(out, Ok) or out.value is None:
            raise _End(FAILED, f"reading 0x1000 after the reset: {self._what(out)}.")
        return out.value

    def _poll_status(self) -> Generator[Step, Outcome, int]:
        """0x1F57, read until it does not show "in progress"."""
        polls = max(1, round(self.settings.status_timeout / self.settings.poll_interval))
        value = 0
        for i in range(polls):
            if i:
                yield Pause(self.settings.poll_interval)
            value = yield from self._u32(FLASH_STATUS, "the flash status 0x1F57")
            if not value & IN_PROGRESS:
                return value
        raise _End(
            FAILED,
            f"0x1F57 still shows the flash in progress after {self.settings.status_timeout:g} "
            f"s ({status_text(value)}).",
        )

    def _try_read(
        self, obj, what: str, after_reset: bool = False
    ) -> Generator[Step, Outcome, Outcome]:
        """The outcome of reading `obj`: `Ok` or `Aborted`, or the last `NoAnswer` when
        none came; a read without an answer is repeated (after a reset, a pause first)."""
        index, sub = obj
        out: Outcome = NoAnswer()
        for i in range(self.settings.read_attempts):
            if i and after_reset:
                yield Pause(self.settings.boot_timeout / self.settings.read_attempts)
            out = yield Read(index, sub, what)
            if isinstance(out, (Ok, Aborted)):
                return out
        return out

    def _read(self, obj, what: str, after_reset: bool = False) -> Generator[Step, Outcome, Outcome]:
        """As `_try_read`, and `_End` when no answer comes."""
        out = yield from self._try_read(obj, what, after_reset)
        if isinstance(out, (Ok, Aborted)):
            return out
        raise _End(
            FAILED,
            f"no answer from node {self.settings.node} reading {what} "
            f"({self.settings.read_attempts} times; last: {self._what(out)}): is it on the "
            "bus at this node-ID and bit rate? (A device whose image never answers: add "
            "--rescue and switch it off and on.)",
        )

    def _u32(self, obj, what: str, after_reset: bool = False) -> Generator[Step, Outcome, int]:
        out = yield from self._read(obj, what, after_reset)
        if isinstance(out, Aborted):
            raise _End(FAILED, f"reading {what}: {abort_text(out.code)}.")
        assert isinstance(out, Ok) and out.value is not None
        return out.value

    @staticmethod
    def _what(out: Outcome) -> str:
        if isinstance(out, Ok):
            return "OK" if out.value is None else str(out.value)
        if isinstance(out, Aborted):
            return abort_text(out.code)
        assert isinstance(out, NoAnswer)
        return out.why
