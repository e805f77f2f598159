"""The STM32F103's peripherals as the handwheel firmware uses them, with their behaviour.

Section numbers are those of RM0008 (STM32F101xx..F107xx reference manual, rev. 21) unless
another document is named; the flash program/erase controller (FPEC) is described in
PM0075 (STM32F10xxx Flash memory microcontrollers, programming manual), to which RM0008
3.3.3 refers. Each model takes word accesses (`read(offset)`, `write(offset, value, mask)`,
the mask holding the byte lanes written) relative to its base address, and time in core
cycles from the board (`now`).
"""

from __future__ import annotations

import random
from dataclasses import dataclass

CORE_HZ = 72_000_000
APB1_HZ = 36_000_000

RCC_BASE = 0x4002_1000
FLASH_IF_BASE = 0x4002_2000
GPIOA_BASE = 0x4001_0800
GPIOB_BASE = 0x4001_0C00
GPIOC_BASE = 0x4001_1000
AFIO_BASE = 0x4001_0000
EXTI_BASE = 0x4001_0400
IWDG_BASE = 0x4000_3000
CAN_BASE = 0x4000_6400

# Interrupt channels (RM0008 10.1.2, table 63).
IRQ_EXTI9_5 = 23
IRQ_CAN_TX = 19
IRQ_CAN_RX0 = 20
IRQ_CAN_RX1 = 21
IRQ_CAN_SCE = 22
IRQ_EXTI15_10 = 40
IRQ_EXTI0 = 6


def merge(old: int, value: int, mask: int) -> int:
    return (old & ~mask) | (value & mask)


# -- RCC ------------------------------------------------------------------------------------


class Rcc:
    """RM0008 7.3: the clock control registers the HAL's `freeze` polls, and CSR's reset
    flags."""

    PORRSTF = 1 << 27
    PINRSTF = 1 << 26
    SFTRSTF = 1 << 28
    IWDGRSTF = 1 << 29

    def __init__(self) -> None:
        self.regs: dict[int, int] = {}
        # 7.3.10 RCC_CSR: reset flags survive a system reset, a power-on sets PORRSTF.
        self.csr_flags = self.PORRSTF | self.PINRSTF
        self.reset()

    def reset(self) -> None:
        self.regs = {0x00: 0x0000_0083}  # 7.3.1 CR: HSION, HSIRDY, HSITRIM 16

    def read(self, offset: int) -> int:
        value = self.regs.get(offset, 0)
        if offset == 0x00:
            # 7.3.1: HSIRDY (1), HSERDY (17), PLLRDY (25) follow their ON bits at once.
            value &= ~((1 << 1) | (1 << 17) | (1 << 25))
            value |= (value & 1) << 1 | ((value >> 16) & 1) << 17 | ((value >> 24) & 1) << 25
        elif offset == 0x04:
            value = (value & ~0xC) | ((value & 3) << 2)  # 7.3.2 CFGR: SWS follows SW
        elif offset == 0x24:
            # 7.3.10 CSR: LSIRDY (1) follows LSION (0), which the IWDG forces on.
            value = (value & 0x1) | ((value & 1) << 1) | self.csr_flags
        return value

    def write(self, offset: int, value: int, mask: int) -> None:
        if offset == 0x24:
            if value & mask & (1 << 24):  # RMVF clears the reset flags
                self.csr_flags = 0
            self.regs[0x24] = merge(self.regs.get(0x24, 0), value, mask) & 1
            return
        self.regs[offset] = merge(self.regs.get(offset, 0), value, mask)


# -- GPIO, AFIO, EXTI -----------------------------------------------------------------------


class Gpio:
    """RM0008 9.2: one port. Inputs come from `levels` (what the board drives on the pins;
    pull-ups make unconnected pins read 1); a pin configured as an output (CRL/CRH MODE != 0)
    reads back its output latch (9.1.9). Output changes go to `on_output(port, odr)`."""

    def __init__(self, name: str, on_output) -> None:
        self.name = name
        self.on_output = on_output
        self.levels = 0xFFFF
        self.reset()

    def reset(self) -> None:
        self.crl = self.crh = 0x4444_4444  # 9.2.1/9.2.2: floating inputs
        self.odr = 0

    def output_mask(self) -> int:
        mask = 0
        for pin in range(16):
            cr = self.crl if pin < 8 else self.crh
            if (cr >> (4 * (pin % 8))) & 0b11:  # MODE != 00: output
                mask |= 1 << pin
        return mask

    def idr(self) -> int:
        out = self.output_mask()
        return (self.levels & ~out | self.odr & out) & 0xFFFF

    def read(self, offset: int) -> int:
        return {0x00: self.crl, 0x04: self.crh, 0x08: self.idr(), 0x0C: self.odr}.get(offset, 0)

    def _set_odr(self, odr: int) -> None:
        odr &= 0xFFFF
        if odr != self.odr:
            self.odr = odr
            self.on_output(self.name, odr)

    def write(self, offset: int, value: int, mask: int) -> None:
        value &= mask
        if offset == 0x00:
            self.crl = merge(self.crl, value, mask)
        elif offset == 0x04:
            self.crh = merge(self.crh, value, mask)
        elif offset == 0x0C:
            self._set_odr(merge(self.odr, value, mask))
        elif offset == 0x10:  # 9.2.5 BSRR: set bits 0-15, reset bits 16-31; set wins
            self._set_odr((self.odr & ~(value >> 16)) | (value & 0xFFFF))
        elif offset == 0x14:  # 9.2.6 BRR
            self._set_odr(self.odr & ~(value & 0xFFFF))


class Afio:
    """RM0008 9.4: EXTICR1..4 choose the port of each EXTI line (0 = A, 1 = B, 2 = C)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.regs = [0] * 7  # EVCR, MAPR, EXTICR1..4, (MAPR2 at 0x1C ignored)

    def read(self, offset: int) -> int:
        if offset == 0x04:  # MAPR's SWJ_CFG is write-only: it reads 0 (9.4.2)
            return self.regs[1] & ~(0b111 << 24)
        return self.regs[offset // 4] if offset < 0x18 else 0

    def write(self, offset: int, value: int, mask: int) -> None:
        if offset < 0x18:
            self.regs[offset // 4] = merge(self.regs[offset // 4], value, mask)

    def jtag_released(self) -> bool:
        """MAPR's SWJ_CFG (bits 24-26) frees PA15, PB3 and PB4 from JTAG: 0b010 (JTAG off,
        SW-DP on) or 0b100 (both off). Write-only on the chip; the model keeps the value."""
        return (self.regs[1] >> 24) & 0b111 in (0b010, 0b100)

    def port_of_line(self, line: int) -> int:
        return (self.regs[2 + line // 4] >> (4 * (line % 4))) & 0xF


class Exti:
    """RM0008 10.3: IMR, EMR, RTSR, FTSR, SWIER, PR. An edge on a line with its trigger
    enabled sets PR when IMR unmasks it (10.2.3, figure 20); PR is write-one-to-clear
    (10.3.6); the interrupt is asserted while PR and IMR are both set."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.imr = self.emr = self.rtsr = self.ftsr = self.pr = 0

    def read(self, offset: int) -> int:
        return (
            [self.imr, self.emr, self.rtsr, self.ftsr, 0, self.pr][offset // 4]
            if offset < 0x18
            else 0
        )

    def write(self, offset: int, value: int, mask: int) -> None:
        value &= mask & 0x7_FFFF
        if offset == 0x00:
            self.imr = merge(self.imr, value, mask)
        elif offset == 0x04:
            self.emr = merge(self.emr, value, mask)
        elif offset == 0x08:
            self.rtsr = merge(self.rtsr, value, mask)
        elif offset == 0x0C:
            self.ftsr = merge(self.ftsr, value, mask)
        elif offset == 0x10:  # 10.3.5 SWIER: a 1 sets PR (if unmasked)
            self.pr |= value & self.imr
        elif offset == 0x14:
            self.pr &= ~value

    def edge(self, line: int, rising: bool) -> None:
        trigger = self.rtsr if rising else self.ftsr
        if trigger >> line & 1 and self.imr >> line & 1:
            self.pr |= 1 << line

    def irqs(self) -> set[int]:
        active = self.pr & self.imr
        lines = set()
        for line in range(5):
            if active >> line & 1:
                lines.add(IRQ_EXTI0 + line)
        if active & 0x3E0:
            lines.add(IRQ_EXTI9_5)
        if active & 0xFC00:
            lines.add(IRQ_EXTI15_10)
        return lines


# -- IWDG -----------------------------------------------------------------------------------


class Iwdg:
    """RM0008 19.4: the independent watchdog. KR 0xCCCC starts it (it cannot be stopped),
    0xAAAA reloads the counter from RLR, 0x5555 opens PR and RLR for writing (19.3.2, any
    other key closes them); PR divides the 40 kHz LSI by 4 << PR (19.4.2); RLR is 12 bits
    (19.4.3); SR's PVU/RVU are set while an update crosses into the LSI domain, about five
    LSI periods (19.4.4). When the down-counter reaches 0 the MCU resets (19.3.1)."""

    LSI_HZ = 40_000
    UPDATE_CYCLES = 5 * CORE_HZ // LSI_HZ

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.running = False
        self.unlocked = False
        self.pr = 0
        self.rlr = 0xFFF
        self.reloaded_at = 0
        self.busy_until = 0
        self.feeds = 0

    def period_cycles(self) -> int:
        return CORE_HZ * (4 << self.pr) // self.LSI_HZ

    def expiry(self) -> int | None:
        """The cycle at which the counter reaches 0, or None while not started."""
        if not self.running:
            return None
        return self.reloaded_at + (self.rlr + 1) * self.period_cycles()

    def read(self, offset: int, now: int) -> int:
        if offset == 0x04:
            return self.pr
        if offset == 0x08:
            return self.rlr
        if offset == 0x0C:
            return 0b11 if now < self.busy_until else 0
        return 0

    def write(self, offset: int, value: int, mask: int, now: int) -> None:
        value &= mask
        if offset == 0x00:
            key = value & 0xFFFF
            self.unlocked = key == 0x5555
            if key == 0xCCCC:
                if not self.running:
                    self.running = True
                    self.reloaded_at = now
            elif key == 0xAAAA:
                self.reloaded_at = now
                self.feeds += 1
        elif offset == 0x04 and self.unlocked:
            self.pr = value & 7
            self.busy_until = now + self.UPDATE_CYCLES
        elif offset == 0x08 and self.unlocked:
            self.rlr = value & 0xFFF
            self.busy_until = now + self.UPDATE_CYCLES


# -- FPEC -----------------------------------------------------------------------------------

FLASH_KEY1 = 0x4567_0123
FLASH_KEY2 = 0xCDEF_89AB


class Fpec:
    """The flash program/erase controller (PM0075 3.2-3.4, registers 4.1-4.5) over the pages
    it manages (`memory`, a bytearray starting at `base`: on the board the whole 64 KiB main
    flash, loader, application slot and parameter pages alike).

    - KEYR: KEY1 then KEY2 clear LOCK (PM0075 3.1, 4.2); any other sequence locks the FPEC
      until the next reset.
    - CR.LOCK written 1 locks it again; PG, PER and STRT only act while unlocked.
    - Page erase (PM0075 2.3.4): PER, AR, STRT: BSY for the erase time, then the page reads
      0xFFFF, EOP is set and BSY clears.
    - Half-word programming (PM0075 2.3.3): with PG set, a half-word write to an erased
      location programs it (BSY for the programming time, then EOP); a location that is not
      0xFFFF takes only 0x0000, anything else gives PGERR and leaves it as it is; a byte or
      word write is not a half-word write: PGERR.
    - SR: BSY (0), PGERR (2), WRPRTERR (4), EOP (5); PGERR, WRPRTERR and EOP are
      write-one-to-clear (4.4).
    The CPU stalls while BSY is set if it fetches from flash (PM0075 2.3.1), which it always
    does here: the stall is charged to emulated time (`take_stall`).

    Power cuts (`cut(now)`, the board's power cycle): an operation still running is left
    half done, with choices drawn from `seed` and the operation's number: a page erase has
    a random half of its half-words erased and the rest unchanged, a half-word program only
    some of the bits it clears. `arm(n, inside)` cuts power at the `n`-th operation from
    now (1: the next), before it starts or inside it; the FPEC then does nothing more and
    `cut_requested` asks the board to cut the power. `on_change(offset, length)` is called
    whenever bytes of `memory` changed (the board copies them into the CPU's view of the
    flash and writes its flash file)."""

    ERASE_CYCLES = 20 * CORE_HZ // 1000  # 20 ms (datasheet t_ERASE 20-40 ms)
    PROGRAM_CYCLES = 52 * CORE_HZ // 1_000_000  # 52.5 us (datasheet t_prog 40-70 us)

    def __init__(self, base: int, memory: bytearray, seed: int = 1) -> None:
        self.base = base
        self.memory = memory
        self.seed = seed
        self.erases = 0
        self.programs = 0
        self.operations = 0  # started: erases and half-word programs, refused ones not
        self.cuts = 0  # power cuts that left an operation half done
        self.armed: tuple[int, bool] | None = None  # (operation number, inside)
        self.on_change = lambda _offset, _length: None
        # The running operation: (end cycle, offset, old bytes); its result is in `memory`.
        self.pending: tuple[int, int, bytes] | None = None
        self.reset()

    def reset(self) -> None:
        self.locked = True
        self.key_stage = 0
        self.locked_until_reset = False
        self.cr = 0
        self.ar = 0
        self.sr = 0
        self.busy_until = 0
        self.stall = 0
        self.dead = False  # power is being cut: nothing more happens
        self.cut_requested = False
        # A system reset other than a power cut lets a running operation finish.
        self.pending = None

    def read(self, offset: int, now: int) -> int:
        if offset == 0x0C:
            return self.sr | (1 if now < self.busy_until else 0)
        if offset == 0x10:
            return self.cr | (0x80 if self.locked else 0)
        if offset == 0x14:
            return self.ar
        if offset == 0x00:
            return 0x30  # ACR: prefetch buffer on and enabled
        return 0

    def write(self, offset: int, value: int, mask: int, now: int) -> None:
        value &= mask
        if offset == 0x04:  # KEYR
            if self.locked_until_reset or not self.locked:
                return
            if self.key_stage == 0 and value == FLASH_KEY1:
                self.key_stage = 1
            elif self.key_stage == 1 and value == FLASH_KEY2:
                self.locked = False
                self.key_stage = 0
            else:
                self.locked_until_reset = True
            return
        if offset == 0x0C:
            self.sr &= ~(value & 0x34)
            return
        if offset == 0x14:
            if not self.locked:
                self.ar = value
            return
        if offset == 0x10:
            if value & 0x80:
                self.locked = True
                self.key_stage = 0
            if self.locked:
                return
            self.cr = merge(self.cr, value, mask) & 0x1677
            if self.cr & 0x40 and self.cr & 0x02:  # STRT with PER: erase the page at AR
                self.cr &= ~0x40
                start = (self.ar - self.base) & ~0x3FF
                if not 0 <= start < len(self.memory):
                    self.sr |= 0x10  # outside the managed pages: treated as protected
                elif (cut_inside := self._begin()) is not None:
                    old = bytes(self.memory[start : start + 1024])
                    self.memory[start : start + 1024] = b"\xff" * 1024
                    self.erases += 1
                    self._started(now + self.ERASE_CYCLES, start, old, cut_inside)
                self._busy(now, self.ERASE_CYCLES)

    def _busy(self, now: int, cycles: int) -> None:
        # The CPU fetches from flash, so it stalls until the operation ends and never sees
        # BSY set: the board charges `stall` cycles after the slice.
        self.stall += cycles
        self.sr |= 0x20  # EOP

    def take_stall(self) -> int:
        stall, self.stall = self.stall, 0
        return stall

    def read_memory(self, offset: int, size: int) -> int:
        return int.from_bytes(self.memory[offset : offset + size], "little")

    def write_memory(self, offset: int, size: int, value: int, now: int) -> None:
        """A CPU write into the managed flash pages."""
        if self.locked or not self.cr & 0x01:
            self.sr |= 0x04  # PM0075: a write without PG is a programming error here
            return
        if size != 2:
            self.sr |= 0x04
            return
        old = self.read_memory(offset, 2)
        value &= 0xFFFF
        if old != 0xFFFF and value != 0:
            self.sr |= 0x04
        elif (cut_inside := self._begin()) is not None:
            self.memory[offset : offset + 2] = value.to_bytes(2, "little")
            self.programs += 1
            end = now + self.PROGRAM_CYCLES
            self._started(end, offset, old.to_bytes(2, "little"), cut_inside)
        self._busy(now, self.PROGRAM_CYCLES)

    # -- power cuts ---------------------------------------------------------------------------

    def arm(self, n: int, inside: bool) -> None:
        """Cut power at the `n`-th operation from now (1: the next), before or inside it."""
        self.armed = (self.operations + n, inside)

    def _begin(self) -> bool | None:
        """Counts an operation: None when it must not happen (power is being cut), else
        whether it is the armed one to cut inside."""
        if self.dead:
            return None
        # The CPU waits for an operation's end before it starts the next (it stalls while
        # BSY, `_busy`): one that begins means the one before is done, though its end was
        # not yet charged in emulated time (the stall comes after the slice).
        self.pending = None
        self.operations += 1
        if self.armed is None or self.armed[0] != self.operations:
            return False
        inside = self.armed[1]
        self.armed = None
        self.dead = True
        self.cut_requested = True
        if not inside:
            self.operations -= 1  # it never started
            return None
        return True

    def _started(self, end: int, offset: int, old: bytes, cut_inside: bool) -> None:
        self.pending = (end, offset, old)
        if cut_inside:
            self._half_done()
        self.on_change(offset, len(old))

    def cut(self, now: int) -> bool:
        """Power is lost at `now`: an operation still running is left half done. Returns
        whether one was."""
        half = self.pending is not None and now < self.pending[0]
        if half:
            _, offset, old = self.pending
            self._half_done()
            self.on_change(offset, len(old))
        self.pending = None
        return half

    def _half_done(self) -> None:
        _, offset, old = self.pending
        rng = random.Random(f"{self.seed}:{self.operations}")
        new = self.memory[offset : offset + len(old)]
        if len(old) == 2:
            o, n = int.from_bytes(old, "little"), int.from_bytes(new, "little")
            # Only some of the bits the program clears are cleared.
            cleared = (o & ~n) & rng.getrandbits(16)
            if o & ~n and cleared in (0, o & ~n):
                cleared = (o & ~n) & ~(1 << ((o & ~n).bit_length() - 1))
            half = o & ~cleared
            self.memory[offset : offset + 2] = half.to_bytes(2, "little")
        else:
            for i in range(0, len(old), 2):
                if rng.random() < 0.5:
                    self.memory[offset + i : offset + i + 2] = old[i : i + 2]
        self.pending = None
        self.cuts += 1


# -- bxCAN ----------------------------------------------------------------------------------


@dataclass
class Frame:
    """A CAN frame: 11- or 29-bit identifier, data or remote."""

    can_id: int
    data: bytes = b""
    extended: bool = False
    remote: bool = False
    dlc: int | None = None

    @property
    def length(self) -> int:
        return len(self.data) if self.dlc is None else self.dlc

    def bits(self) -> int:
        """Bits on the bus without stuffing: SOF to the end of intermission."""
        header = 67 if self.extended else 47
        return header + (0 if self.remote else 8 * len(self.data))

    def __str__(self) -> str:
        return f"{self.can_id:03X} [{self.data.hex(' ')}]"


def btr_bitrate(btr: int, clock: int = APB1_HZ) -> float:
    """RM0008 24.7.7: bit time = (1 + (TS1 + 1) + (TS2 + 1)) quanta of (BRP + 1) clocks."""
    brp = btr & 0x3FF
    ts1 = (btr >> 16) & 0xF
    ts2 = (btr >> 20) & 0x7
    return clock / ((brp + 1) * (3 + ts1 + ts2))


def btr_sample_point(btr: int) -> float:
    ts1 = (btr >> 16) & 0xF
    ts2 = (btr >> 20) & 0x7
    return (2 + ts1) / (3 + ts1 + ts2)


class Bxcan:
    """RM0008 24: the bxCAN controller as one node on a bus whose other side is the host.

    Modes (24.4, 24.9.1-2, figure 222): INRQ requests initialization (INAK), SLEEP requests
    sleep (SLAK); those acknowledges follow at once. Clearing both requests normal mode,
    which the controller enters once it has synchronised on 11 consecutive recessive bits:
    at once on a free bus, not while the bus is held dominant (`bus_dominant_until`), so
    INAK or SLAK stays set until it is free. Out of reset the controller sleeps. Only in
    normal mode (neither INAK nor SLAK) does it take part in the bus.
    A dominant bus (shorted lines, a babbling node) also carries no frame either way; the
    error frames an online node would see there are not modelled (TEC/REC stay).
    BTR (24.9.7) is writable only in initialization mode; a bus bit rate set on the board
    (`bus_bitrate`) that differs from BTR's keeps the node off the bus in both directions.
    Filters (24.7.4, 24.9.5): banks 0..13 as programmed, in 16- or 32-bit scale, mask or
    list mode, each to FIFO 0 or 1; the registers are writable only with FINIT set (FiRx also
    while the bank is inactive) and no frame is received while FINIT is set. A frame that no
    active filter accepts is dropped.
    FIFO 0/1 (24.7.5): three mailboxes; FMP counts them, FULL at three, a fourth frame sets
    FOVR and, with RFLM clear, replaces the last one (with RFLM set it is lost); RFOM
    releases the output mailbox.
    Transmission (24.7.1): three mailboxes; with TXFP clear the pending mailbox with the
    lowest identifier goes first (equal identifiers: the lower mailbox number), with TXFP set
    in request order. A frame occupies the bus for its bits at the bit rate; then RQCP, TXOK
    and TME are set. ABRQ aborts a pending mailbox that is not on the bus (RQCP set, TXOK
    clear, TME set); one on the bus finishes first. CODE is the lowest free mailbox, or with
    all three pending the one with the lowest priority, marked in LOW (24.9.3).
    Errors (24.7.6, 24.9.6): TEC/REC with the warning limit (96: EWGF), error passive (> 127:
    EPVF) and bus-off (TEC > 255: BOFF). With ABOM set, bus-off ends by itself after 128
    times 11 recessive bits, unless the bus is held faulty; without it, after the software
    leaves initialization mode. A successful transmission decrements TEC, a reception REC.
    ERRI is set when an error flag is set whose interrupt enable (EWGIE, EPVIE, BOFIE, LECIE
    for a new LEC) is set (24.9.2).
    Interrupts (24.8): TX while TMEIE and any RQCP; RX0 while FMPIE0 and FMP0, FFIE0 and
    FULL0, or FOVIE0 and FOVR0 (RX1 alike); SCE while ERRIE and ERRI, WKUIE and WKUI, SLKIE
    and SLAKI."""

    def __init__(self, on_transmit) -> None:
        self.on_transmit = on_transmit  # called with (Frame) when a frame has gone out
        self.on_request = lambda box: None  # called when TXRQ makes a mailbox pending
        self.bus_bitrate: int | None = None  # None: whatever BTR says
        self.bus_hold_until: int | None = 0  # frames wait while now < this (None: for ever)
        # Other traffic leaves the node one frame per this many cycles (0: the bus is free):
        # each frame it sends holds the bus this long after it.
        self.bus_trickle = 0
        # The bus is stuck dominant while now < this (None: for ever): nothing synchronises.
        self.bus_dominant_until: int | None = 0
        self.bus_faulty_until = 0  # bus-off recovery waits at least until then
        self.delivered = 0
        self.filtered = 0
        self.overruns = 0
        self.dropped_offline = 0
        self.aborted = 0
        self.btr_writes: list[int] = []
        self.reset()

    def reset(self) -> None:
        self.mcr = 0x0001_0002  # 24.9.1: SLEEP, DBF
        self.mode = "sleep"  # "sleep", "init" or "normal": what MSR's INAK/SLAK acknowledge
        self.msr_flags = 0  # ERRI (2), WKUI (3), SLAKI (4)
        self.ier = 0
        self.btr = 0x0123_0000  # 24.9.7 reset value
        self.esr_lec = 0
        self.tec = 0
        self.rec = 0
        self.bus_off = False
        self.bus_off_since = 0
        self.tsr_flags = 0  # RQCP/TXOK/ALST/TERR per mailbox (bits 0-3, 8-11, 16-19)
        self.mailboxes = [[0, 0, 0, 0] for _ in range(3)]  # TIR, TDTR, TDLR, TDHR
        self.pending_order: list[int] = []  # mailbox numbers in request order
        self.on_bus: int | None = None  # the mailbox being transmitted
        self.on_bus_until = 0
        self.fifo = [[], []]
        self.rfr = [0, 0]  # FOVR (4) / FULL (3) flags per FIFO
        self.fmr = 0x2A1C_0E01  # 24.9.8: FINIT, CAN2SB
        self.fm1r = self.fs1r = self.ffa1r = self.fa1r = 0
        self.banks = [[0, 0] for _ in range(28)]

    # -- state ------------------------------------------------------------------------------

    @property
    def inak(self) -> bool:
        return self.mode == "init"

    @property
    def slak(self) -> bool:
        return self.mode == "sleep"

    def dominant(self, now: int) -> bool:
        """Whether the bus is held dominant at cycle `now`."""
        return self.bus_dominant_until is None or now < self.bus_dominant_until

    def _update_mode(self, now: int) -> None:
        """Figure 222: INRQ (before SLEEP) and SLEEP are entered at once; with both clear the
        controller enters normal mode once synchronised (never while the bus is dominant)."""
        was_init = self.inak
        if self.mcr & 1:
            self.mode = "init"
        elif self.mcr & 2:
            self.mode = "sleep"
        elif not self.dominant(now):
            self.mode = "normal"
        if was_init and not self.inak and self.bus_off and not self.mcr & 0x40:
            # 24.7.6: without ABOM the software leaves initialization mode to recover.
            self._recover()

    def bitrate(self) -> float:
        return btr_bitrate(self.btr)

    def online(self) -> bool:
        """In normal mode, not bus-off, and at the bus's bit rate."""
        if self.inak or self.slak or self.bus_off:
            return False
        if self.bus_bitrate is not None and round(self.bitrate()) != self.bus_bitrate:
            return False
        return True

    def esr(self) -> int:
        value = self.esr_lec << 4 | min(self.tec, 255) << 16 | min(self.rec, 255) << 24
        if self.tec >= 96 or self.rec >= 96:
            value |= 1
        if self.tec > 127 or self.rec > 127:
            value |= 2
        if self.bus_off:
            value |= 4
        return value

    def tsr(self) -> int:
        value = self.tsr_flags
        free = [box for box in range(3) if not self.mailboxes[box][0] & 1]
        for box in free:
            value |= 1 << (26 + box)
        if free:
            code = free[0]
        else:
            code = self._lowest_priority()
            value |= 1 << (29 + code)
        return value | code << 24

    def _priority_key(self, box: int):
        if self.mcr & 0x4:  # TXFP: request order
            return (self.pending_order.index(box),)
        tir = self.mailboxes[box][0]
        return (self._arbitration_id(tir), box)

    @staticmethod
    def _arbitration_id(tir: int) -> int:
        # Standard identifiers compete on their 11 bits, extended ones on base + extension.
        if tir & 4:
            return (tir >> 3) & 0x1FFF_FFFF
        return ((tir >> 21) & 0x7FF) << 18

    def _lowest_priority(self) -> int:
        pending = [box for box in range(3) if self.mailboxes[box][0] & 1]
        return max(pending, key=self._priority_key)

    # -- registers --------------------------------------------------------------------------

    def read(self, offset: int) -> int:
        if offset == 0x00:
            return self.mcr
        if offset == 0x04:
            return (int(self.inak) | int(self.slak) << 1 | self.msr_flags) | 0x800
        if offset == 0x08:
            return self.tsr()
        if offset in (0x0C, 0x10):
            n = (offset - 0x0C) // 4
            count = len(self.fifo[n])
            return count | self.rfr[n] | (0x8 if count == 3 else 0)
        if offset == 0x14:
            return self.ier
        if offset == 0x18:
            return self.esr()
        if offset == 0x1C:
            return self.btr
        if 0x180 <= offset < 0x1B0:
            box, reg = divmod(offset - 0x180, 0x10)
            return self.mailboxes[box][reg // 4]
        if 0x1B0 <= offset < 0x1D0:
            n, reg = divmod(offset - 0x1B0, 0x10)
            return self._fifo_word(n, reg)
        if offset == 0x200:
            return self.fmr
        if offset == 0x204:
            return self.fm1r
        if offset == 0x20C:
            return self.fs1r
        if offset == 0x214:
            return self.ffa1r
        if offset == 0x21C:
            return self.fa1r
        if 0x240 <= offset < 0x320:
            bank, reg = divmod(offset - 0x240, 8)
            return self.banks[bank][reg // 4]
        return 0

    def write(self, offset: int, value: int, mask: int, now: int) -> None:
        value &= mask
        if offset == 0x00:
            self._write_mcr(merge(self.mcr, value, mask), now)
        elif offset == 0x04:
            self.msr_flags &= ~(value & 0x1C)  # ERRI, WKUI, SLAKI: write one to clear
        elif offset == 0x08:
            self._write_tsr(value, now)
        elif offset in (0x0C, 0x10):
            n = (offset - 0x0C) // 4
            if value & (1 << 3):  # FULL: write one to clear
                self.rfr[n] &= ~(1 << 3)
            if value & (1 << 4):  # FOVR: write one to clear
                self.rfr[n] &= ~(1 << 4)
            if value & (1 << 5) and self.fifo[n]:  # RFOM: release the output mailbox
                self.fifo[n].pop(0)
        elif offset == 0x14:
            self.ier = merge(self.ier, value, mask) & 0x3_8F7F
        elif offset == 0x18:
            self.esr_lec = (merge(self.esr_lec << 4, value, mask & 0x70) >> 4) & 7
        elif offset == 0x1C:
            if self.inak:  # 24.9.7: only in initialization mode
                self.btr = merge(self.btr, value, mask) & 0xC37F_03FF
                self.btr_writes.append(self.btr)
        elif 0x180 <= offset < 0x1B0:
            box, reg = divmod(offset - 0x180, 0x10)
            if self.mailboxes[box][0] & 1:
                return  # 24.9.10: write-protected while the mailbox is pending
            self.mailboxes[box][reg // 4] = merge(self.mailboxes[box][reg // 4], value, mask)
            if reg == 0 and value & 1:
                self.pending_order.append(box)
                self.tsr_flags &= ~(0xF << (8 * box))
                self.on_request(box)
        elif offset == 0x200:
            self.fmr = merge(self.fmr, value, mask) & 0x0000_3F01
        elif self.fmr & 1 and offset in (0x204, 0x20C, 0x214):
            if offset == 0x204:
                self.fm1r = merge(self.fm1r, value, mask) & 0x0FFF_FFFF
            elif offset == 0x20C:
                self.fs1r = merge(self.fs1r, value, mask) & 0x0FFF_FFFF
            else:
                self.ffa1r = merge(self.ffa1r, value, mask) & 0x0FFF_FFFF
        elif offset == 0x21C:
            self.fa1r = merge(self.fa1r, value, mask) & 0x0FFF_FFFF
        elif 0x240 <= offset < 0x320:
            bank, reg = divmod(offset - 0x240, 8)
            if self.fmr & 1 or not self.fa1r >> bank & 1:
                self.banks[bank][reg // 4] = merge(self.banks[bank][reg // 4], value, mask)

    def _write_mcr(self, mcr: int, now: int) -> None:
        if mcr & (1 << 15):  # RESET: master reset, back to sleep mode
            self.reset()
            return
        self.mcr = mcr & 0x0001_00FF
        self._update_mode(now)
        if self.mcr & 2 and not self.mcr & 1:
            self.msr_flags |= 1 << 4  # SLAKI on entering sleep

    def _write_tsr(self, value: int, now: int) -> None:
        for box in range(3):
            if value & (1 << (8 * box)):  # RQCP: clears RQCP, TXOK, ALST, TERR
                self.tsr_flags &= ~(0xF << (8 * box))
            self.tsr_flags &= ~(value & (0xE << (8 * box)))
            if value & (1 << (7 + 8 * box)) and self.mailboxes[box][0] & 1:  # ABRQ
                if self.on_bus != box:
                    self._finish(box, ok=False)
                    self.aborted += 1

    # -- FIFOs and filters ------------------------------------------------------------------

    def _fifo_word(self, n: int, reg: int) -> int:
        if not self.fifo[n]:
            return 0
        frame, fmi = self.fifo[n][0]
        payload = frame.data.ljust(8, b"\0")
        if reg == 0:
            if frame.extended:
                return frame.can_id << 3 | 4 | int(frame.remote) << 1
            return frame.can_id << 21 | int(frame.remote) << 1
        if reg == 4:
            return frame.length | fmi << 8
        if reg == 8:
            return int.from_bytes(payload[:4], "little")
        return int.from_bytes(payload[4:8], "little")

    def accept(self, frame: Frame) -> tuple[int, int] | None:
        """(FIFO, filter match index) for a frame, or None if no active filter takes it
        (24.7.4). The index counts filter numbers bank by bank, as 24.7.4 numbers them."""
        if self.fmr & 1:
            return None
        rtr = int(frame.remote)
        ide = int(frame.extended)
        if frame.extended:
            word32 = frame.can_id << 3 | ide << 2 | rtr << 1
            word16 = (
                ((frame.can_id >> 18) & 0x7FF) << 5 | rtr << 4 | ide << 3 | (frame.can_id >> 15) & 7
            )
        else:
            word32 = frame.can_id << 21 | rtr << 1
            word16 = frame.can_id << 5 | rtr << 4
        number = 0
        matches = []
        for bank in range(14):
            list_mode = self.fm1r >> bank & 1
            scale32 = self.fs1r >> bank & 1
            fifo = self.ffa1r >> bank & 1
            r1, r2 = self.banks[bank]
            active = self.fa1r >> bank & 1
            if scale32:
                if list_mode:
                    entries = [(r1, 0xFFFF_FFFF), (r2, 0xFFFF_FFFF)]
                else:
                    entries = [(r1, r2)]
                ours = [word32 & ~1 & m == i & ~1 & m for i, m in entries]
            else:
                lo1, hi1, lo2, hi2 = r1 & 0xFFFF, r1 >> 16, r2 & 0xFFFF, r2 >> 16
                if list_mode:
                    entries = [(lo1, 0xFFFF), (hi1, 0xFFFF), (lo2, 0xFFFF), (hi2, 0xFFFF)]
                else:
                    entries = [(lo1, hi1), (lo2, hi2)]
                ours = [word16 & m == i & m for i, m in entries]
            for hit in ours:
                if active and hit:
                    matches.append((fifo, number, scale32, list_mode))
                number += 1
        if not matches:
            return None
        # 24.7.4 "Filter match index": 32-bit before 16-bit, list before mask, then number.
        best = min(matches, key=lambda m: (-m[2], -m[3], m[1]))
        return best[0], best[1]

    def deliver(self, frame: Frame) -> str:
        """A frame from the bus. Returns what became of it."""
        if not self.online():
            self.dropped_offline += 1
            return "offline"
        where = self.accept(frame)
        if where is None:
            self.filtered += 1
            return "filtered"
        n, fmi = where
        self._received_ok()
        fifo = self.fifo[n]
        if len(fifo) >= 3:
            self.rfr[n] |= 1 << 4
            self.overruns += 1
            if not self.mcr & 0x8:  # RFLM clear: the newest replaces the last one
                fifo[-1] = (frame, fmi)
            return "overrun"
        fifo.append((frame, fmi))
        self.delivered += 1
        return f"fifo{n}"

    # -- transmission -----------------------------------------------------------------------

    def frame_in(self, box: int) -> Frame:
        tir, tdtr, tdlr, tdhr = self.mailboxes[box]
        length = min(tdtr & 0xF, 8)
        payload = (tdlr.to_bytes(4, "little") + tdhr.to_bytes(4, "little"))[:length]
        remote = bool(tir & 2)
        if tir & 4:
            return Frame(tir >> 3, b"" if remote else payload, True, remote, length)
        return Frame(tir >> 21, b"" if remote else payload, False, remote, length)

    def _finish(self, box: int, ok: bool) -> None:
        self.mailboxes[box][0] &= ~1
        if box in self.pending_order:
            self.pending_order.remove(box)
        flags = 0b1 | (0b10 if ok else 0)
        self.tsr_flags |= flags << (8 * box)
        if self.on_bus == box:
            self.on_bus = None

    def advance(self, now: int) -> None:
        """Moves the bus on to cycle `now`: finishes the frame on the bus, starts the next,
        ends bus-off when its recovery is due, enters normal mode once it can synchronise."""
        self._update_mode(now)
        if self.bus_off and self.mcr & 0x40 and not self.inak:
            recovery = int(128 * 11 * CORE_HZ / max(self.bitrate(), 1))
            if now >= max(self.bus_off_since + recovery, self.bus_faulty_until):
                self._recover()
        if self.on_bus is not None and now >= self.on_bus_until:
            box = self.on_bus
            frame = self.frame_in(box)
            self._finish(box, ok=True)
            if self.tec > 0:
                self.tec -= 1
            if self.bus_trickle and self.bus_hold_until is not None:
                self.bus_hold_until = max(self.bus_hold_until, now + self.bus_trickle)
            self.on_transmit(frame)
        if self.on_bus is None and self.online():
            if self.bus_hold_until is None or now < self.bus_hold_until or self.dominant(now):
                return
            pending = [box for box in range(3) if self.mailboxes[box][0] & 1]
            if pending:
                box = min(pending, key=self._priority_key)
                self.on_bus = box
                self.on_bus_until = now + int(self.frame_in(box).bits() * CORE_HZ / self.bitrate())

    def next_event(self, now: int) -> int | None:
        """The next cycle after `now` at which the bus changes by itself: the frame on it
        ends, a timed hold or dominant stretch ends. A time that has passed is no event (as
        an expired hold): the bus waits for nothing then."""
        times = [
            t
            for t in (
                self.on_bus_until if self.on_bus is not None else None,
                self.bus_hold_until,
                self.bus_dominant_until,
            )
            if t is not None and t > now
        ]
        return min(times, default=None)

    # -- errors -----------------------------------------------------------------------------

    def _received_ok(self) -> None:
        if 0 < self.rec <= 127:
            self.rec -= 1
        elif self.rec > 127:
            self.rec = 120

    def _set_lec(self, code: int) -> None:
        self.esr_lec = code & 7
        if code and self.ier & (1 << 11):
            self.msr_flags |= 1 << 2

    def inject(self, tx: int, rx: int, now: int, lec: int = 3) -> None:
        """Bus errors seen by this node: `tx` transmit errors (TEC += 8 each) and `rx`
        receive errors (REC += 1 each), with LEC (default 3: form error)."""
        before = self.esr()
        self.tec += 8 * tx
        self.rec = min(self.rec + rx, 255)
        if self.tec > 255:
            self.tec = 256
            if not self.bus_off:
                self.bus_off = True
                self.bus_off_since = now
                if self.on_bus is not None:
                    self.on_bus = None
        self._set_lec(lec)
        self._error_flags_set(before)

    def _error_flags_set(self, before: int) -> None:
        after = self.esr()
        rising = after & ~before
        if (
            (rising & 1 and self.ier & (1 << 8))
            or (rising & 2 and self.ier & (1 << 9))
            or (rising & 4 and self.ier & (1 << 10))
        ):
            self.msr_flags |= 1 << 2  # ERRI

    def _recover(self) -> None:
        self.bus_off = False
        self.tec = 0
        self.rec = 0

    # -- interrupt lines --------------------------------------------------------------------

    def irqs(self) -> set[int]:
        lines = set()
        ier = self.ier
        if ier & 1 and self.tsr_flags & 0x01_0101:
            lines.add(IRQ_CAN_TX)
        for n, irq, shift in ((0, IRQ_CAN_RX0, 1), (1, IRQ_CAN_RX1, 4)):
            count = len(self.fifo[n])
            if (
                (ier >> shift & 1 and count)
                or (ier >> (shift + 1) & 1 and count == 3)
                or (ier >> (shift + 2) & 1 and self.rfr[n] & 0x10)
            ):
                lines.add(irq)
        if (
            (ier & (1 << 15) and self.msr_flags & 4)
            or (ier & (1 << 16) and self.msr_flags & 8)
            or (ier & (1 << 17) and self.msr_flags & 0x10)
        ):
            lines.add(IRQ_CAN_SCE)
        return lines
