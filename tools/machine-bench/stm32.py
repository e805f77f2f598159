"""A small register model of the STM32F103's peripherals and the Cortex-M3 system block.

Registers read back what was written, starting from their reset values. On top of that the
model has the few behaviours the firmware waits for or the benchmark drives:

- RCC: HSE/PLL/HSI ready flags follow their enable bits, SWS follows SW.
- GPIO: IDR is the level of the pins (`Pins`); BSRR/BRR update ODR.
- EXTI: PR is write-one-to-clear.
- bxCAN: INAK/SLAK follow INRQ/SLEEP; receive FIFO 0 holds frames the benchmark puts in;
  a write of TXRQ to a transmit mailbox hands the frame to `on_transmit` and leaves the
  mailbox pending until `complete_transmissions`, which sets RQCP/TXOK and raises the
  transmit interrupt if enabled.
- NVIC, SCB, SysTick: pending bits and priorities for the benchmark's exception model;
  SysTick's COUNTFLAG is set by `tick` and cleared when read.

Everything else is plain memory. Addresses come from RM0008 and the ARMv7-M ARM.
"""

from __future__ import annotations

from dataclasses import dataclass, field

PERIPH_BASE = 0x4000_0000
PERIPH_SIZE = 0x0003_0000
# The bit-band alias of the peripheral region: one word per peripheral bit.
BITBAND_BASE = 0x4200_0000
BITBAND_SIZE = 0x0060_0000  # covers PERIPH_BASE .. PERIPH_BASE + PERIPH_SIZE
PPB_BASE = 0xE000_0000
PPB_SIZE = 0x0010_0000


def bitband_target(offset: int) -> tuple[int, int]:
    """The peripheral byte address and bit that a bit-band alias offset names."""
    return PERIPH_BASE + (offset >> 5), (offset >> 2) & 7


RCC = 0x4002_1000
GPIOA = 0x4001_0800
GPIOB = 0x4001_0C00
GPIOC = 0x4001_1000
EXTI = 0x4001_0400
CAN = 0x4000_6400

# bxCAN register offsets.
CAN_MCR = CAN + 0x000
CAN_MSR = CAN + 0x004
CAN_TSR = CAN + 0x008
CAN_RF0R = CAN + 0x00C
CAN_IER = CAN + 0x014
CAN_ESR = CAN + 0x018
CAN_TX_MAILBOX = CAN + 0x180  # TIxR, TDTxR, TDLxR, TDHxR, 0x10 apart
CAN_RX_FIFO0 = CAN + 0x1B0  # RI0R, RDT0R, RDL0R, RDH0R

SYST_CSR = 0xE000_E010
NVIC_ISER = 0xE000_E100
NVIC_ICER = 0xE000_E180
NVIC_ISPR = 0xE000_E200
NVIC_ICPR = 0xE000_E280
NVIC_IPR = 0xE000_E400
SCB_CPUID = 0xE000_ED00
SCB_ICSR = 0xE000_ED04
SCB_SHPR = 0xE000_ED18  # SHPR1..3: bytes for exceptions 4..15
NVIC_STIR = 0xE000_EF00

SYSTICK_EXCEPTION = 15
IRQ_BASE = 16
# bxCAN interrupt lines (RM0008 vector table).
IRQ_CAN_TX = 19
IRQ_CAN_RX0 = 20
IRQ_CAN_SCE = 22

RESET_VALUES = {
    RCC + 0x00: 0x0000_0083,  # CR: HSION, HSIRDY
    RCC + 0x24: 0x0C00_0000,  # CSR: PORRSTF, PINRSTF
    CAN_MCR: 0x0001_0002,
    CAN_MSR: 0x0000_0C02,
    CAN_TSR: 0x1C00_0000,
    CAN + 0x01C: 0x0123_0000,  # BTR
    CAN + 0x200: 0x2A1C_0E01,  # FMR: FINIT, CAN2SB = 14 (all banks to CAN1)
    0x4002_2010: 0x0000_0080,  # FLASH_CR: LOCK
    SCB_CPUID: 0x412F_C231,  # Cortex-M3 r2p1
}
for _port in (GPIOA, GPIOB, GPIOC):
    RESET_VALUES[_port + 0x00] = 0x4444_4444
    RESET_VALUES[_port + 0x04] = 0x4444_4444


@dataclass
class CanFrame:
    """A standard data frame."""

    cob_id: int
    data: bytes

    def __str__(self) -> str:
        return f"{self.cob_id:03X} [{self.data.hex(' ')}]"


@dataclass
class Pins:
    """Input levels of the GPIO ports (1 = high); pull-ups hold open lines high."""

    ports: dict[int, int] = field(
        default_factory=lambda: {GPIOA: 0xFFFF, GPIOB: 0xFFFF, GPIOC: 0xFFFF}
    )


class Peripherals:
    """The register file. `pend(exception)` is called when something raises an interrupt."""

    def __init__(self, pend, on_transmit) -> None:
        self.regs: dict[int, int] = dict(RESET_VALUES)
        self.pins = Pins()
        self.pend = pend
        self.on_transmit = on_transmit
        self.pending: set[int] = set()
        self.rx_fifo0: list[CanFrame] = []
        self.countflag = False
        self.transmitted: list[CanFrame] = []

    # -- plain registers -------------------------------------------------------------------

    def word(self, address: int) -> int:
        return self.regs.get(address, 0)

    def read(self, address: int, size: int) -> int:
        base = address & ~3
        shift = (address & 3) * 8
        value = self.read_word(base)
        mask = (1 << (size * 8)) - 1
        return (value >> shift) & mask

    def write(self, address: int, size: int, value: int) -> None:
        base = address & ~3
        shift = (address & 3) * 8
        if size == 4:
            self.write_word(base, value & 0xFFFF_FFFF, 0xFFFF_FFFF)
        else:
            mask = ((1 << (size * 8)) - 1) << shift
            self.write_word(base, (value << shift) & mask, mask)

    # -- behaviour -------------------------------------------------------------------------

    def read_word(self, address: int) -> int:
        value = self.word(address)
        if address == RCC:
            ready = value & ~((1 << 1) | (1 << 17) | (1 << 25))
            ready |= (value & 1) << 1  # HSIRDY
            ready |= ((value >> 16) & 1) << 17  # HSERDY
            ready |= ((value >> 24) & 1) << 25  # PLLRDY
            return ready
        if address == RCC + 0x04:  # CFGR: SWS = SW
            return (value & ~0xC) | ((value & 3) << 2)
        if address in (GPIOA + 0x08, GPIOB + 0x08, GPIOC + 0x08):  # IDR
            return self.pins.ports[address - 0x08]
        if address == CAN_MSR:
            mcr = self.word(CAN_MCR)
            value &= ~3
            value |= mcr & 1  # INAK follows INRQ
            value |= mcr & 2  # SLAK follows SLEEP
            return value
        if address == CAN_TSR:
            return self._tsr()
        if address == CAN_RF0R:
            pending = min(len(self.rx_fifo0), 3)
            return (value & ~0x3) | pending | (0x8 if pending == 3 else 0)
        if CAN_RX_FIFO0 <= address < CAN_RX_FIFO0 + 0x10:
            return self._fifo0_word(address - CAN_RX_FIFO0)
        if address == SYST_CSR:
            flag = self.countflag
            self.countflag = False
            return (value & ~(1 << 16)) | (int(flag) << 16)
        if NVIC_ISER <= address < NVIC_ISER + 0x20 or NVIC_ICER <= address < NVIC_ICER + 0x20:
            return self.word(NVIC_ISER + (address & 0x1F))
        if NVIC_ISPR <= address < NVIC_ISPR + 0x20 or NVIC_ICPR <= address < NVIC_ICPR + 0x20:
            first = (address & 0x1F) * 8
            return sum(1 << bit for bit in range(32) if IRQ_BASE + first + bit in self.pending)
        if address == SCB_ICSR:
            return int(SYSTICK_EXCEPTION in self.pending) << 26
        return value

    def write_word(self, address: int, value: int, mask: int) -> None:
        old = self.word(address)
        if address in (GPIOA + 0x10, GPIOB + 0x10, GPIOC + 0x10):  # BSRR
            odr = address - 0x10 + 0x0C
            self.regs[odr] = (self.word(odr) | (value & 0xFFFF)) & ~(value >> 16)
            return
        if address in (GPIOA + 0x14, GPIOB + 0x14, GPIOC + 0x14):  # BRR
            odr = address - 0x14 + 0x0C
            self.regs[odr] = self.word(odr) & ~(value & 0xFFFF)
            return
        if address == EXTI + 0x14:  # PR: write one to clear
            self.regs[address] = old & ~value
            return
        if address == CAN_MSR:  # ERRI, WKUI, SLAKI: write one to clear
            self.regs[address] = old & ~(value & 0x1C)
            return
        if address == CAN_TSR:
            self._write_tsr(value)
            return
        if address == CAN_RF0R:
            if value & (1 << 5) and self.rx_fifo0:  # RFOM0: release the output mailbox
                self.rx_fifo0.pop(0)
            if value & (1 << 4):  # FOVR0: write one to clear
                old &= ~(1 << 4)
            self.regs[address] = old & ~(1 << 5)
            return
        if CAN_TX_MAILBOX <= address < CAN_TX_MAILBOX + 0x30:
            self.regs[address] = (old & ~mask) | value
            if (address - CAN_TX_MAILBOX) % 0x10 == 0 and value & 1:
                self._request_transmission((address - CAN_TX_MAILBOX) // 0x10)
            return
        if address == SYST_CSR + 8:  # CVR: any write clears it and COUNTFLAG
            self.regs[address] = 0
            self.countflag = False
            return
        if NVIC_ISER <= address < NVIC_ISER + 0x20:
            self.regs[address] = old | value
            return
        if NVIC_ICER <= address < NVIC_ICER + 0x20:
            enable = NVIC_ISER + (address & 0x1F)
            self.regs[enable] = self.word(enable) & ~value
            return
        if NVIC_ISPR <= address < NVIC_ISPR + 0x20:
            first = (address & 0x1F) * 8
            for bit in range(32):
                if value & (1 << bit):
                    self.pend(IRQ_BASE + first + bit)
            return
        if NVIC_ICPR <= address < NVIC_ICPR + 0x20:
            first = (address & 0x1F) * 8
            for bit in range(32):
                if value & (1 << bit):
                    self.pending.discard(IRQ_BASE + first + bit)
            return
        if address == NVIC_STIR:
            self.pend(IRQ_BASE + (value & 0x1FF))
            return
        if address == SCB_ICSR:
            if value & (1 << 26):
                self.pend(SYSTICK_EXCEPTION)
            if value & (1 << 25):
                self.pending.discard(SYSTICK_EXCEPTION)
            return
        self.regs[address] = (old & ~mask) | value

    # -- NVIC view -------------------------------------------------------------------------

    def priority(self, exception: int) -> int:
        """The hardware priority byte of an exception (lower is more urgent)."""
        if exception >= IRQ_BASE:
            return self.read(NVIC_IPR + exception - IRQ_BASE, 1)
        return self.read(SCB_SHPR + exception - 4, 1)

    def enabled(self, exception: int) -> bool:
        if exception == SYSTICK_EXCEPTION:
            return bool(self.word(SYST_CSR) & 0b11 == 0b11)
        irq = exception - IRQ_BASE
        return bool(self.word(NVIC_ISER + 4 * (irq // 32)) & (1 << (irq % 32)))

    # -- SysTick ---------------------------------------------------------------------------

    def tick(self) -> None:
        """One SysTick wrap: COUNTFLAG set, the exception pended."""
        self.countflag = True
        self.pend(SYSTICK_EXCEPTION)

    # -- EXTI ------------------------------------------------------------------------------

    def set_exti_pending(self, lines: int) -> None:
        self.regs[EXTI + 0x14] = self.word(EXTI + 0x14) | lines

    # -- bxCAN -----------------------------------------------------------------------------

    def _tsr(self) -> int:
        value = self.word(CAN_TSR)
        free = [box for box in range(3) if value & (1 << (26 + box))]
        code = free[0] if free else 0
        return (value & ~(3 << 24)) | (code << 24)

    def _write_tsr(self, value: int) -> None:
        old = self.word(CAN_TSR)
        # RQCPx, TXOKx, ALSTx, TERRx are write-one-to-clear; clearing RQCP clears the rest.
        for box in range(3):
            if value & (1 << (8 * box)):
                old &= ~(0xF << (8 * box))
            old &= ~(value & (0xE << (8 * box)))
        self.regs[CAN_TSR] = old

    def _request_transmission(self, box: int) -> None:
        base = CAN_TX_MAILBOX + 0x10 * box
        tir = self.word(base)
        if tir & (1 << 2):
            raise AssertionError(f"extended-ID frame in mailbox {box}: not expected")
        length = self.word(base + 4) & 0xF
        payload = self.word(base + 8).to_bytes(4, "little") + self.word(base + 12).to_bytes(
            4, "little"
        )
        frame = CanFrame(tir >> 21, payload[:length])
        self.regs[CAN_TSR] = self.word(CAN_TSR) & ~(1 << (26 + box))
        self.transmitted.append(frame)
        self.on_transmit(box, frame)

    def complete_transmissions(self) -> int:
        """Every pending mailbox goes out: TME, RQCP, TXOK set, TXRQ cleared. Returns how many."""
        tsr = self.word(CAN_TSR)
        done = 0
        for box in range(3):
            if not tsr & (1 << (26 + box)):
                tsr |= (1 << (26 + box)) | (0b11 << (8 * box))
                base = CAN_TX_MAILBOX + 0x10 * box
                self.regs[base] = self.word(base) & ~1
                done += 1
        self.regs[CAN_TSR] = tsr
        if done and self.word(CAN_IER) & 1:  # TMEIE
            self.pend(IRQ_BASE + IRQ_CAN_TX)
        return done

    def receive(self, frame: CanFrame) -> None:
        """A frame that passed the filters arrives in FIFO 0."""
        if len(self.rx_fifo0) >= 3:
            raise AssertionError("receive FIFO 0 full: the benchmark sends too fast")
        self.rx_fifo0.append(frame)
        if self.word(CAN_IER) & (1 << 1):  # FMPIE0
            self.pend(IRQ_BASE + IRQ_CAN_RX0)

    def _fifo0_word(self, offset: int) -> int:
        if not self.rx_fifo0:
            return 0
        frame = self.rx_fifo0[0]
        payload = frame.data.ljust(8, b"\0")
        if offset == 0x0:
            return frame.cob_id << 21
        if offset == 0x4:
            return len(frame.data)
        if offset == 0x8:
            return int.from_bytes(payload[:4], "little")
        return int.from_bytes(payload[4:], "little")

    def set_error_state(self, esr: int) -> None:
        """CAN_ESR as the controller would set it, with ERRI and the SCE interrupt."""
        self.regs[CAN_ESR] = esr
        self.regs[CAN_MSR] = self.word(CAN_MSR) | (1 << 2)
        if self.word(CAN_IER) & (1 << 15):  # ERRIE
            self.pend(IRQ_BASE + IRQ_CAN_SCE)
