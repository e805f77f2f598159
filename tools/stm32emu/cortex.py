"""A Cortex-M3 core for the emulated board: unicorn runs the instructions, this module is the
NVIC, the exception model and SysTick around it.

References: ARMv7-M Architecture Reference Manual (ARM DDI 0403E), "B1.5 ARMv7-M exception
model" and "B3.3 The system timer, SysTick"; the STM32F10xxx Cortex-M3 programming manual
PM0056 ("4.3 NVIC", "4.4 SCB", "4.5 SysTick") for the part's four priority bits.

Unicorn (2.1) in M-class mode is always in thread mode here: it does not take exceptions
itself, and a return through an EXC_RETURN value in thread mode makes it stop with
UC_ERR_EXCEPTION at PC 0xFFFFFFF8 (the address is in the execute-never system region).
That is how an exception return is recognised: the core catches it and unstacks (B1.5.8),
or tail-chains into the next pending exception. Any other UC_ERR_EXCEPTION (an undefined
instruction, as a Rust panic ends in) is a fault: the core then counts as locked in
HardFault, as the firmware's HardFault handler would loop forever, and only a reset (the
watchdog's) brings it back.

Time (`Core.cycles`): by default one executed instruction is one cycle of the 72 MHz core
clock. Instructions run in slices (`emu_start(count=N)`); an exception pended by a
peripheral or by a register write is taken at the end of the current slice, so its latency
is at most one slice. A slice that stops early (exception return, the idle loop) is charged
in full: emulated time can run ahead of the instructions by up to one slice per stop. This
is the real-time board's mode: no Python runs per instruction.

Precise mode (`Core.precise(cost)`, the machine benchmark's): a hook runs before every
instruction. It charges the instruction's cost (1 by default, or the caller's cycle
estimate), ends the slice exactly when its cycles are spent, and stops before the next
instruction as soon as a pending exception beats the execution priority (a pend by the
previous instruction's register write, or a PRIMASK/BASEPRI change), so that exception is
taken at that instruction boundary, as the NVIC does, nested or not. It never stops inside
an IT block: the exception frame here does not carry the IT state.

`Core.observer` is told of every exception entry and return (`Observer`): the benchmark
measures handlers through it.
"""

from __future__ import annotations

from unicorn import (
    UC_ARCH_ARM,
    UC_HOOK_CODE,
    UC_HOOK_MEM_INVALID,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    Uc,
    UcError,
)
from unicorn import arm_const as arm

CORE_HZ = 72_000_000
# The IT bits of the xPSR: IT[1:0] in bits 26:25, IT[7:2] in bits 15:10 (ARMv7-M ARM B1.4.2).
_IT_BITS = 0b11 << 25 | 0x3F << 10

SYST_CSR = 0xE000_E010
SYST_RVR = 0xE000_E014
SYST_CVR = 0xE000_E018
SYST_CALIB = 0xE000_E01C
NVIC_ISER = 0xE000_E100
NVIC_ICER = 0xE000_E180
NVIC_ISPR = 0xE000_E200
NVIC_ICPR = 0xE000_E280
NVIC_IABR = 0xE000_E300
NVIC_IPR = 0xE000_E400
SCB_CPUID = 0xE000_ED00
SCB_ICSR = 0xE000_ED04
SCB_VTOR = 0xE000_ED08
SCB_AIRCR = 0xE000_ED0C
SCB_CCR = 0xE000_ED14
SCB_SHPR = 0xE000_ED18
SCB_SHCSR = 0xE000_ED24
NVIC_STIR = 0xE000_EF00

SYSTICK = 15
PENDSV = 14
SVCALL = 11
HARDFAULT = 3
IRQ_BASE = 16
IRQ_COUNT = 68  # STM32F103: 68 maskable interrupt channels (RM0008 10.1.2)

# PM0056 4.3.7: the STM32F10xxx implements the upper four bits of each priority byte.
PRIORITY_MASK = 0xF0
THREAD_PRIORITY = 0x100

EXC_RETURN_HANDLER = 0xFFFF_FFF1
EXC_RETURN_THREAD = 0xFFFF_FFF9
EXC_RETURN_FAULT_PC = 0xFFFF_FFF8

_FRAME = [
    arm.UC_ARM_REG_R0,
    arm.UC_ARM_REG_R1,
    arm.UC_ARM_REG_R2,
    arm.UC_ARM_REG_R3,
    arm.UC_ARM_REG_R12,
    arm.UC_ARM_REG_LR,
]


class Nvic:
    """The NVIC and the system control block registers the firmware uses, with SysTick.

    `pending` and `active` are sets of exception numbers; `active_stack` is the nesting
    order. Peripheral interrupt lines call `set_pending`."""

    def __init__(self) -> None:
        # Called with an exception that has just become pending (an instrument's hook).
        self.on_pend = lambda exception: None
        self.reset()

    def reset(self) -> None:
        self.enabled = 0  # bit n: IRQ n
        self.pending: set[int] = set()
        self.active_stack: list[int] = []
        self.ipr = bytearray(IRQ_COUNT)
        self.shpr = bytearray(12)  # exceptions 4..15 (B3.2.10-12)
        self.vtor = 0
        self.aircr_prigroup = 0
        self.ccr = 0x200  # STKALIGN set out of reset on r2p1 (PM0056 4.4.7)
        self.reset_requested = False
        # Set by whatever may let a pending exception preempt (a pend, an enable, a priority);
        # the core's precise mode clears it when it has looked.
        self.changed = True
        # SysTick (B3.3.2): CSR ENABLE bit 0, TICKINT 1, CLKSOURCE 2, COUNTFLAG 16.
        self.syst_csr = 0
        self.syst_rvr = 0
        self.syst_base = 0  # cycle at which the counter was last loaded from RVR
        self.syst_loaded = False
        self.countflag = False
        self.now = 0  # emulated core cycles, kept by the board

    # -- priorities (B1.5.4) ----------------------------------------------------------------

    def priority(self, exception: int) -> int:
        if exception == HARDFAULT:
            return -1
        if exception >= IRQ_BASE:
            return self.ipr[exception - IRQ_BASE] & PRIORITY_MASK
        if 4 <= exception <= 15:
            return self.shpr[exception - 4] & PRIORITY_MASK
        return -2

    def group(self, priority: int) -> int:
        """The group (preemption) priority: PRIGROUP splits off sub-priority bits (B1.5.4)."""
        if priority < 0:
            return priority
        return priority & ~((2 << self.aircr_prigroup) - 1) & 0xFF

    def is_enabled(self, exception: int) -> bool:
        if exception >= IRQ_BASE:
            return bool(self.enabled >> (exception - IRQ_BASE) & 1)
        return True  # system exceptions the firmware can pend are always enabled

    def execution_priority(self, primask: int, basepri: int) -> int:
        """B1.5.4: the highest of the active exceptions' group priorities, BASEPRI and
        PRIMASK (which boosts to 0)."""
        level = THREAD_PRIORITY
        for exception in self.active_stack:
            level = min(level, self.group(self.priority(exception)))
        basepri &= PRIORITY_MASK
        if basepri:
            level = min(level, self.group(basepri))
        if primask & 1:
            level = min(level, 0)
        return level

    def next_pending(self) -> int | None:
        """The most urgent pending, enabled exception: lowest priority value, then lowest
        exception number (B1.5.4)."""
        ready = [e for e in self.pending if self.is_enabled(e)]
        if not ready:
            return None
        return min(ready, key=lambda e: (self.priority(e), e))

    def preempting(self, primask: int, basepri: int) -> int | None:
        exception = self.next_pending()
        if exception is None:
            return None
        if self.group(self.priority(exception)) < self.execution_priority(primask, basepri):
            return exception
        return None

    def set_pending(self, exception: int) -> None:
        if exception not in self.pending:
            self.pending.add(exception)
            self.changed = True
            self.on_pend(exception)

    # -- SysTick (B3.3) -------------------------------------------------------------------

    def systick_period(self) -> int:
        """Cycles per SysTick wrap. CLKSOURCE 0 is the STM32's HCLK/8 (RM0008 7.2)."""
        divider = 1 if self.syst_csr & 4 else 8
        return ((self.syst_rvr & 0xFF_FFFF) + 1) * divider

    def systick_running(self) -> bool:
        return bool(self.syst_csr & 1) and self.syst_rvr & 0xFF_FFFF != 0

    def next_systick(self) -> int | None:
        """The cycle of the next wrap, or None while stopped."""
        if not self.systick_running():
            return None
        period = self.systick_period()
        elapsed = self.now - self.syst_base
        return self.syst_base + (elapsed // period + 1) * period

    def advance_systick(self, until: int) -> None:
        """Counts wraps up to cycle `until`: COUNTFLAG, and the exception with TICKINT."""
        nxt = self.next_systick()
        if nxt is not None and nxt <= until:
            self.countflag = True
            if self.syst_csr & 2:
                self.set_pending(SYSTICK)

    def systick_cvr(self) -> int:
        if not self.systick_running():
            return 0
        divider = 1 if self.syst_csr & 4 else 8
        period = self.systick_period()
        elapsed = (self.now - self.syst_base) % period
        return (self.syst_rvr & 0xFF_FFFF) - elapsed // divider

    # -- registers ------------------------------------------------------------------------

    def read(self, address: int) -> int:
        """One aligned word of the system control space."""
        if address == SYST_CSR:
            value = self.syst_csr | (int(self.countflag) << 16)
            self.countflag = False  # B3.3.3: COUNTFLAG clears on read
            return value
        if address == SYST_RVR:
            return self.syst_rvr
        if address == SYST_CVR:
            return self.systick_cvr()
        if address == SYST_CALIB:
            return 9000  # PM0056 4.5.4: 9000 for 1 ms at HCLK/8 = 9 MHz
        if NVIC_ISER <= address < NVIC_ISER + 12 or NVIC_ICER <= address < NVIC_ICER + 12:
            word = (address & 0x7F) // 4
            return (self.enabled >> (32 * word)) & 0xFFFF_FFFF
        if NVIC_ISPR <= address < NVIC_ISPR + 12 or NVIC_ICPR <= address < NVIC_ICPR + 12:
            return self._irq_bits(self.pending, (address & 0x7F) // 4)
        if NVIC_IABR <= address < NVIC_IABR + 12:
            return self._irq_bits(set(self.active_stack), (address & 0x7F) // 4)
        if NVIC_IPR <= address < NVIC_IPR + IRQ_COUNT:
            i = address - NVIC_IPR
            return int.from_bytes(self.ipr[i : i + 4].ljust(4, b"\0"), "little")
        if address == SCB_CPUID:
            return 0x412F_C231  # Cortex-M3 r2p1
        if address == SCB_ICSR:
            active = self.active_stack[-1] if self.active_stack else 0
            nxt = self.next_pending() or 0
            value = active | (nxt << 12)
            if SYSTICK in self.pending:
                value |= 1 << 26
            if PENDSV in self.pending:
                value |= 1 << 28
            return value
        if address == SCB_VTOR:
            return self.vtor
        if address == SCB_AIRCR:
            return 0xFA05_0000 | (self.aircr_prigroup << 8)
        if address == SCB_CCR:
            return self.ccr
        if SCB_SHPR <= address < SCB_SHPR + 12:
            i = address - SCB_SHPR
            return int.from_bytes(self.shpr[i : i + 4], "little")
        return 0

    @staticmethod
    def _irq_bits(exceptions: set[int], word: int) -> int:
        value = 0
        for e in exceptions:
            irq = e - IRQ_BASE
            if 32 * word <= irq < 32 * word + 32:
                value |= 1 << (irq - 32 * word)
        return value

    def write(self, address: int, value: int, mask: int) -> None:
        """One word of the system control space; `mask` holds the written byte lanes."""
        self.changed = True  # an enable, a priority or a pend may let something preempt
        if address == SYST_CSR:
            was = self.syst_csr & 1
            self.syst_csr = (self.syst_csr & ~mask | value & mask) & 0x7
            if self.syst_csr & 1 and not was:
                self.syst_base = self.now
            return
        if address == SYST_RVR:
            self.syst_rvr = value & 0xFF_FFFF
            return
        if address == SYST_CVR:
            # B3.3.5: any write clears the counter and COUNTFLAG; it reloads on the next tick.
            self.syst_base = self.now
            self.countflag = False
            return
        if NVIC_ISER <= address < NVIC_ISER + 12:
            self.enabled |= (value & mask) << (32 * ((address & 0x7F) // 4))
            return
        if NVIC_ICER <= address < NVIC_ICER + 12:
            self.enabled &= ~((value & mask) << (32 * ((address & 0x7F) // 4)))
            return
        if NVIC_ISPR <= address < NVIC_ISPR + 12:
            for bit in range(32):
                if value & mask & (1 << bit):
                    self.set_pending(IRQ_BASE + 32 * ((address & 0x7F) // 4) + bit)
            return
        if NVIC_ICPR <= address < NVIC_ICPR + 12:
            for bit in range(32):
                if value & mask & (1 << bit):
                    self.pending.discard(IRQ_BASE + 32 * ((address & 0x7F) // 4) + bit)
            return
        if NVIC_IPR <= address < NVIC_IPR + IRQ_COUNT:
            i = address - NVIC_IPR
            for lane in range(4):
                if mask >> (8 * lane) & 0xFF and i + lane < IRQ_COUNT:
                    self.ipr[i + lane] = (value >> (8 * lane)) & PRIORITY_MASK
            return
        if address == SCB_ICSR:
            # B3.2.4: PENDSTSET 26, PENDSTCLR 25, PENDSVSET 28, PENDSVCLR 27.
            if value & (1 << 26):
                self.set_pending(SYSTICK)
            if value & (1 << 25):
                self.pending.discard(SYSTICK)
            if value & (1 << 28):
                self.set_pending(PENDSV)
            if value & (1 << 27):
                self.pending.discard(PENDSV)
            return
        if address == SCB_VTOR:
            self.vtor = value & 0x3FFF_FF80
            return
        if address == SCB_AIRCR:
            if (value >> 16) & 0xFFFF == 0x05FA:  # VECTKEY (B3.2.6)
                self.aircr_prigroup = (value >> 8) & 7
                if value & (1 << 2):  # SYSRESETREQ
                    self.reset_requested = True
            return
        if address == SCB_CCR:
            self.ccr = value & 0x31B
            return
        if SCB_SHPR <= address < SCB_SHPR + 12:
            i = address - SCB_SHPR
            for lane in range(4):
                if mask >> (8 * lane) & 0xFF:
                    self.shpr[i + lane] = (value >> (8 * lane)) & PRIORITY_MASK
            return
        if address == NVIC_STIR:
            self.set_pending(IRQ_BASE + (value & 0x1FF))
            return


class Observer:
    """What the core tells an instrument about exceptions (the default does nothing)."""

    def entered(self, exception: int, interrupted: int | None) -> None:
        """The handler of `exception` is about to run its first instruction: taken from the
        code whose next instruction is at `interrupted` (thread mode or a handler it
        preempts), or with None tail-chained onto the handler that just returned."""

    def returned(self, exception: int, chained: int | None) -> None:
        """The handler of `exception` returned; `chained` is the exception tail-chained
        next, or None when the core unstacks to the code it interrupted."""


class Core:
    """Unicorn plus the exception model. `run(count)` executes one slice."""

    def __init__(self, uc: Uc, nvic: Nvic, vectors_at) -> None:
        self.uc = uc
        self.nvic = nvic
        self.vectors_at = vectors_at  # callable: exception number -> vector word
        self.locked_up = False  # in HardFault for good (a panic's UDF)
        # Faults taken (cumulative over resets) and the data address of the last one that was
        # an access to unmapped or read-only memory (B1.5.14: a precise BusFault, escalated to
        # HardFault as the firmware enables no fault handler of its own), None if none was.
        self.faults = 0
        self.fault_address: int | None = None
        self._access_address: int | None = None
        uc.hook_add(UC_HOOK_MEM_INVALID, self._invalid_access)
        self.exceptions_taken = 0
        self.tail_chains = 0
        self.max_nesting = 0
        self.stop_reason = ""
        self.on_return = lambda: None
        self.observer = Observer()
        # Core clock cycles run so far (see the module's "Time"); `running` while unicorn
        # executes instructions.
        self.cycles = 0
        self.running = False
        self.cost = None  # precise mode: (address, size) -> cycles of that instruction
        self._stop_at = 0
        # Precise mode, per instruction address: the end of the IT block it starts (or 0),
        # and whether it may lower PRIMASK or BASEPRI (CPS, MSR).
        self._decoded: dict[int, tuple[int, bool]] = {}
        self._it_block = (0, 0)
        self._recheck = True  # whether to look for a preempting exception at the next one

    def reg(self, r: int) -> int:
        return self.uc.reg_read(r)

    def _invalid_access(self, _uc, _access, address, _size, _value, _user) -> bool:
        """An access unicorn refuses (unmapped, or a write to read-only memory): note where,
        and let the emulation stop with the error (the fault)."""
        self._access_address = address
        return False

    def mask_levels(self) -> tuple[int, int]:
        return self.reg(arm.UC_ARM_REG_PRIMASK), self.reg(arm.UC_ARM_REG_BASEPRI)

    # -- precise mode -------------------------------------------------------------------------

    def precise(self, cost=None) -> None:
        """Switches to precise mode (see the module's doc). `cost(address, size)` gives the
        cycles of the instruction about to run; it is called once per executed instruction,
        so it is also where an instrument looks at each one."""
        if self.cost is None:
            self.uc.hook_add(UC_HOOK_CODE, self._on_code)
        self.cost = cost or (lambda _address, _size: 1)

    def _on_code(self, uc, address, size, _user) -> None:
        start, end = self._it_block
        decoded = self._decoded.get(address)
        if decoded is None:
            decoded = self._decoded[address] = self._decode(address, size)
        if not start < address < end:
            if end:
                # The first instruction after an IT block. Unicorn (its hooks' view of the
                # CPU) can leave the block's IT bits in the CPU state, where the next
                # translation block would read them as an IT block still open (a B<cond>
                # there is then an invalid instruction): outside a block they are 0.
                self._it_block = (0, 0)
                xpsr = uc.reg_read(arm.UC_ARM_REG_XPSR)
                if xpsr & _IT_BITS:
                    uc.reg_write(arm.UC_ARM_REG_XPSR, xpsr & ~_IT_BITS)
            if self.cycles >= self._stop_at:
                self.stop_reason = "slice"
                uc.emu_stop()  # before this instruction: it runs in the next slice
                return
            nvic = self.nvic
            if self._recheck or nvic.changed:
                self._recheck = nvic.changed = False
                if nvic.pending and nvic.preempting(*self.mask_levels()) is not None:
                    self.stop_reason = "preempt"
                    uc.emu_stop()
                    return
            if decoded[0]:
                self._it_block = (address, decoded[0])
        if decoded[1]:
            self._recheck = True  # the masks may have come down
        self.cycles += self.cost(address, size)

    def _decode(self, address: int, size: int) -> tuple[int, bool]:
        """(the address after the IT block the instruction at `address` starts, or 0;
        whether it is CPS or MSR). IT is 0xBFxy with a mask y != 0 (ARMv7-M ARM A7.7.38),
        CPS 0xB66x (A7.7.24), MSR 0xF38x then a second half-word (A7.7.83)."""
        first = int.from_bytes(bytes(self.uc.mem_read(address, 2)), "little")
        if size == 4:
            return 0, first & 0xFFF0 == 0xF380
        mask = first & 0xF
        if first & 0xFF00 != 0xBF00 or not mask:
            return 0, first & 0xFFE8 == 0xB660
        count = 4 - (mask & -mask).bit_length() + 1
        end = address + 2
        for _ in range(count):
            half = int.from_bytes(bytes(self.uc.mem_read(end, 2)), "little")
            end += 4 if half >> 11 in (0b11101, 0b11110, 0b11111) else 2
        return end, False

    # -- exception entry and return (B1.5.6, B1.5.8) ---------------------------------------

    def _push_frame(self, return_address: int) -> None:
        uc = self.uc
        sp = uc.reg_read(arm.UC_ARM_REG_SP)
        xpsr = uc.reg_read(arm.UC_ARM_REG_XPSR)
        frame_sp = sp - 32
        if self.nvic.ccr & 0x200 and frame_sp & 4:  # STKALIGN: 8-byte aligned frame
            frame_sp -= 4
            xpsr |= 1 << 9
        else:
            xpsr &= ~(1 << 9)
        words = [uc.reg_read(r) for r in _FRAME] + [return_address, (xpsr | 1 << 24) & 0xFFFF_FFFF]
        uc.mem_write(frame_sp, b"".join(w.to_bytes(4, "little") for w in words))
        uc.reg_write(arm.UC_ARM_REG_SP, frame_sp)

    def _enter(self, exception: int, interrupted: int | None) -> None:
        nvic = self.nvic
        nvic.pending.discard(exception)
        nested = bool(nvic.active_stack)
        nvic.active_stack.append(exception)
        self.max_nesting = max(self.max_nesting, len(nvic.active_stack))
        self.exceptions_taken += 1
        self.uc.reg_write(arm.UC_ARM_REG_LR, EXC_RETURN_HANDLER if nested else EXC_RETURN_THREAD)
        self.uc.reg_write(arm.UC_ARM_REG_PC, self.vectors_at(exception) | 1)
        self._it_block = (0, 0)
        self.observer.entered(exception, interrupted)

    def take(self, exception: int, pc: int) -> None:
        """Exception entry from the current context, whose next instruction is at `pc`."""
        self._push_frame(pc & ~1)
        self._enter(exception, pc & ~1)

    def exception_return(self) -> None:
        """The handler branched to EXC_RETURN: tail-chain or unstack (B1.5.8)."""
        nvic = self.nvic
        if not nvic.active_stack:
            raise RuntimeError("exception return in thread mode")
        returning = nvic.active_stack.pop()
        self.on_return()  # level-sensitive lines still asserted pend again
        primask, basepri = self.mask_levels()
        nxt = nvic.preempting(primask, basepri)
        self.observer.returned(returning, nxt)
        if nxt is not None:
            # Tail-chaining: the stacked frame stays, the next handler starts at once.
            self.tail_chains += 1
            self._enter(nxt, None)
            return
        uc = self.uc
        sp = uc.reg_read(arm.UC_ARM_REG_SP)
        data = bytes(uc.mem_read(sp, 32))
        words = [int.from_bytes(data[i : i + 4], "little") for i in range(0, 32, 4)]
        for r, w in zip(_FRAME, words[:6]):
            uc.reg_write(r, w)
        xpsr = words[7]
        new_sp = sp + 32 + (4 if xpsr & (1 << 9) else 0)
        uc.reg_write(arm.UC_ARM_REG_SP, new_sp)
        uc.reg_write(arm.UC_ARM_REG_PC, words[6] | 1)
        uc.reg_write(arm.UC_ARM_REG_XPSR, xpsr & ~(1 << 9))
        self._it_block = (0, 0)

    def check_preemption(self) -> bool:
        """At a slice boundary: take the most urgent exception that beats the execution
        priority, if any (and any that then beats it again: late arrival is not modelled,
        the next boundary takes it)."""
        if self.locked_up:
            return False
        primask, basepri = self.mask_levels()
        exception = self.nvic.preempting(primask, basepri)
        if exception is None:
            return False
        self.take(exception, self.uc.reg_read(arm.UC_ARM_REG_PC))
        return True

    # -- running --------------------------------------------------------------------------

    def run(self, count: int) -> None:
        """Runs one slice of `count` cycles from the current PC: `count` instructions, or in
        precise mode until their costs add up to `count` (an IT block is finished first)."""
        if self.locked_up:
            return
        uc = self.uc
        pc = uc.reg_read(arm.UC_ARM_REG_PC)
        self.stop_reason = ""
        self._access_address = None
        if self.cost is None:
            self.cycles += count
        else:
            self._stop_at = self.cycles + count
            self._recheck = True
            count += 8  # the hook ends the slice; room to finish an IT block
        self.running = True
        try:
            uc.emu_start(pc | 1, 0xFFFF_FFFF, count=count)
        except UcError as error:
            pc = uc.reg_read(arm.UC_ARM_REG_PC)
            if pc >= 0xFFFF_FFE0:  # EXC_RETURN with bit 0 cleared by the branch
                self.stop_reason = "return"
                self.running = False
                self.exception_return()
                return
            if pc >= 2 and int.from_bytes(bytes(uc.mem_read(pc - 2, 2)), "little") == 0xBF10:
                # YIELD (a hint, `spin_loop` on ARMv7-M): unicorn stops after it as after
                # an unknown instruction; the PC is already past it, nothing else happened.
                self.stop_reason = "yield"
                return
            # A fault: the firmware's HardFault handler would spin; stay there.
            self.stop_reason = f"fault at {pc:#010x}: {error}"
            self.faults += 1
            self.fault_address = self._access_address
            self.locked_up = True
        finally:
            self.running = False


def make_uc() -> Uc:
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.ctl_set_cpu_model(arm.UC_CPU_ARM_CORTEX_M3)
    return uc
