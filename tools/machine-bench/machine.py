"""The release firmware on an emulated Cortex-M3 (unicorn), with a minimal NVIC.

`Machine` loads the ELF's loadable segments at their load addresses (the firmware's own
reset handler copies .data to RAM), maps 20 KiB of RAM, the system memory page with a unique
ID, and the peripherals as the register model of `stm32.py`. `boot()` runs from the reset
vector until the idle loop. From then on the machine acts as the NVIC: `run_pending()` takes
the most urgent pending, enabled exception and calls its handler like the hardware would
(8-word frame stacked below SP, 8-byte aligned), with the return address set to a magic
address where emulation stops; then the next, until none is pending.

Every executed instruction goes through `cycles.CycleCounter`; every handler call becomes
an `Invocation` with its instruction count, cycle estimate and stack depth. Nested
preemption is not emulated: a handler pended by another runs after it. Stack depths are
measured per handler from its own frame, so the worst case is composed from them (see
`bench.py`). After every MSR/CPS in a handler the machine also checks, for each priority
level of interest (`mask_levels`), whether PRIMASK or BASEPRI now hold off an interrupt of
that level, and keeps the longest such stretch per level (`longest_masks`). Reads of chosen
peripheral registers (`watch_reads`) are marked in the invocation with the cycles up to
and including the reading instruction, so that a handler's latency to its port read can be
composed.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass, field

from capstone import arm as cs_arm
from elftools.elf.elffile import ELFFile
from unicorn import (
    UC_ARCH_ARM,
    UC_HOOK_CODE,
    UC_HOOK_MEM_READ,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    Uc,
    UcError,
    arm_const,
)
from unicorn.arm_const import (
    UC_ARM_REG_BASEPRI,
    UC_ARM_REG_LR,
    UC_ARM_REG_PC,
    UC_ARM_REG_PRIMASK,
    UC_ARM_REG_R0,
    UC_ARM_REG_R1,
    UC_ARM_REG_R2,
    UC_ARM_REG_R3,
    UC_ARM_REG_R12,
    UC_ARM_REG_SP,
    UC_ARM_REG_XPSR,
    UC_CPU_ARM_CORTEX_M3,
)

import cycles
import stm32

FLASH_BASE = 0x0800_0000
FLASH_SIZE = 0x1_0000
RAM_BASE = 0x2000_0000
RAM_SIZE = 20 * 1024
SYSTEM_MEMORY = 0x1FFF_F000
UNIQUE_ID = 0x1FFF_F7E8
FLASH_SIZE_REGISTER = 0x1FFF_F7E0
# Where handlers "return" to: an unused page of the code region.
MAGIC_RETURN = 0x0001_0000
# Pattern painted over the stack region before reset.
PAINT = 0xC5C5_C5C5
# Instructions any single run may take before it counts as hung.
RUN_LIMIT = 5_000_000
THREAD_PRIORITY = 0x100
FRAME_BYTES = 32

# Exceptions that are faults: never called by the benchmark.
FAULTS = range(2, 7)


@dataclass(frozen=True)
class Mark:
    """The counters of a handler up to and including one instruction."""

    instructions: int
    cycles: int
    refetches: int
    flash_reads: int
    frame: stm32.CanFrame


@dataclass
class Invocation:
    """One handler call."""

    exception: int
    name: str
    priority: int
    instructions: int = 0
    cycles: int = 0
    # Refetches from flash (taken branches, ISB) and data reads from flash: each costs the
    # flash wait states on the real part.
    refetches: int = 0
    flash_reads: int = 0
    # Bytes below the handler's entry SP (after the hardware frame) at its deepest.
    depth: int = 0
    # Exceptions it pended.
    pended: list[int] = field(default_factory=list)
    # Where each transmit request (TXRQ) fell in the handler, with its frame.
    transmits: list[Mark] = field(default_factory=list)
    label: str = ""
    # Executed instructions by class (see `cycles`).
    mix: dict[str, int] = field(default_factory=dict)
    # (address, cycles charged) per executed instruction, for traced exceptions.
    trace: list[tuple[int, int]] | None = None
    # Watched register address -> cycles of the handler up to its first read, inclusive.
    reads: dict[int, int] = field(default_factory=dict)


def readable(symbol: str) -> str:
    """A Rust symbol without its hash and mangling noise, short enough for a table."""
    name = re.sub(r"17h[0-9a-f]{16}E$", "", symbol)
    if name.startswith("_ZN"):
        parts = []
        rest = name[3:]
        while rest and rest[0].isdigit():
            length = int(re.match(r"\d+", rest).group())
            digits = len(str(length))
            parts.append(rest[digits : digits + length])
            rest = rest[digits + length :]
        name = "::".join(parts)
    for escape, char in (("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("..", "::"), ("$C$", ",")):
        name = name.replace(escape, char)
    return name


class FirmwareImage:
    """What the benchmark needs from the ELF: segments, symbols, vector table."""

    def __init__(self, path: str) -> None:
        with open(path, "rb") as f:
            elf = ELFFile(f)
            self.segments = [
                (seg["p_paddr"], seg.data())
                for seg in elf.iter_segments()
                if seg["p_type"] == "PT_LOAD" and seg["p_filesz"] > 0
            ]
            self.symbols: dict[str, int] = {}
            self.sizes: dict[str, int] = {}
            symtab = elf.get_section_by_name(".symtab")
            if symtab is None:
                raise ValueError(f"{path} has no symbol table")
            for sym in symtab.iter_symbols():
                if sym.name:
                    self.symbols.setdefault(sym.name, sym["st_value"])
                    self.sizes.setdefault(sym.name, sym["st_size"])
            section = elf.get_section_by_name(".vector_table")
            if section is None:
                raise ValueError(f"{path} has no .vector_table")
            data = section.data()
        words = [int.from_bytes(data[i : i + 4], "little") for i in range(0, len(data), 4)]
        self.initial_sp = words[0]
        self.vectors = words  # index = exception number; [0] is the initial SP
        default = self.symbols.get("DefaultHandler")
        # Handler name by address: the global function symbols the vector table points at.
        by_address: dict[int, str] = {}
        for name, address in self.symbols.items():
            if address & ~1 in {w & ~1 for w in words[1:]} and name not in by_address.values():
                by_address.setdefault(address & ~1, name)
        self.handlers: dict[int, str] = {}
        for exception, vector in enumerate(words):
            if (
                exception < 2
                or vector == 0
                or (default is not None and vector & ~1 == default & ~1)
            ):
                continue
            self.handlers[exception] = self._name(exception, vector & ~1)

    def _name(self, exception: int, address: int) -> str:
        names = [n for n, a in self.symbols.items() if a & ~1 == address and not n.startswith("$")]
        # Prefer the vector's own name (e.g. EXTI9_5) over aliases and mangled names.
        plain = sorted(n for n in names if n.isidentifier() and not n.startswith("_"))
        return plain[0] if plain else f"exception {exception}"

    def function_at(self, address: int) -> str:
        """The name of the function symbol that contains `address` (demangled roughly)."""
        if not hasattr(self, "_functions"):
            self._functions = sorted(
                ((a & ~1), n)
                for n, a in self.symbols.items()
                if self.sizes.get(n) and FLASH_BASE <= a < FLASH_BASE + FLASH_SIZE
            )
            self._starts = [f[0] for f in self._functions]
        index = bisect.bisect_right(self._starts, address) - 1
        while index >= 0:
            start, name = self._functions[index]
            if start <= address < start + self.sizes[name]:
                return readable(name)
            index -= 1
        return f"{address:#010x}"

    def exception_of(self, name: str) -> int:
        for exception, handler in self.handlers.items():
            if handler == name:
                return exception
        raise KeyError(f"no vector points at {name}")


class Machine:
    """The emulated MCU."""

    def __init__(self, image: FirmwareImage, unique_id: bytes = bytes(range(0x31, 0x3D))):
        self.image = image
        self.uc = uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M3)
        uc.mem_map(FLASH_BASE, FLASH_SIZE)
        uc.mem_write(FLASH_BASE, b"\xff" * FLASH_SIZE)  # erased, parameter page included
        for address, data in image.segments:
            if FLASH_BASE <= address < FLASH_BASE + FLASH_SIZE:
                uc.mem_write(address, data)
        uc.mem_map(RAM_BASE, RAM_SIZE)
        uc.mem_map(SYSTEM_MEMORY, 0x1000)
        uc.mem_write(UNIQUE_ID, unique_id)
        uc.mem_write(FLASH_SIZE_REGISTER, (64).to_bytes(2, "little"))
        uc.mem_map(MAGIC_RETURN, 0x1000)
        self.periph = stm32.Peripherals(self._pend, self._transmitted)
        uc.mmio_map(
            stm32.PERIPH_BASE, stm32.PERIPH_SIZE, self._mmio_read, None, self._mmio_write, None
        )
        uc.mmio_map(
            stm32.BITBAND_BASE,
            stm32.BITBAND_SIZE,
            self._bitband_read,
            None,
            self._bitband_write,
            None,
        )
        uc.mmio_map(stm32.PPB_BASE, stm32.PPB_SIZE, self._ppb_read, None, self._ppb_write, None)

        self.stack_top = image.initial_sp
        self.stack_bottom = image.symbols.get("_stack_end", image.symbols.get("__euninit"))
        if self.stack_bottom is None:
            raise ValueError("no _stack_end or __euninit symbol: where does the stack end?")
        self._paint()

        self._md = cycles.disassembler()
        self._timings: dict[int, tuple[cycles.Timing, int, bool]] = {}
        self.counter = cycles.CycleCounter()
        self.flash_reads = 0
        self.min_sp = self.stack_top
        self._check_sp = False
        self.current: Invocation | None = None
        self.invocations: list[Invocation] = []
        self.thread_min_sp = self.stack_top
        self.idle_address: int | None = None
        self._trace: list[tuple[int, int]] | None = None
        self.lowest_sp = self.stack_top
        # Exceptions whose invocations record every instruction (`Invocation.trace`).
        self.traced: set[int] = set()
        # Masking: the hardware priorities of interest (set by the caller); per level, the
        # longest stretch of a handler during which PRIMASK or BASEPRI held an interrupt of
        # that priority off, as (cycles, instructions, handler, address of the instruction
        # that started it).
        self.mask_levels: tuple[int, ...] = ()
        self.longest_masks: dict[int, tuple[int, int, str, int]] = {}
        self._mask_starts: dict[int, tuple[int, int, int]] = {}
        self._check_mask = False
        # Peripheral registers whose first read per invocation is marked (`Invocation.reads`).
        self.watch_reads: set[int] = set()
        # Code addresses whose executions are counted (a function's entry: its calls).
        self.pc_counts: dict[int, int] = {}
        uc.hook_add(UC_HOOK_CODE, self._on_code)
        uc.hook_add(
            UC_HOOK_MEM_READ, self._on_flash_read, begin=FLASH_BASE, end=FLASH_BASE + FLASH_SIZE - 1
        )

    # -- memory-mapped I/O -----------------------------------------------------------------

    def _mmio_read(self, _uc, offset, size, _user):
        address = stm32.PERIPH_BASE + offset
        if address in self.watch_reads and self.current is not None:
            self.current.reads.setdefault(address, self.counter.cycles)
        return self.periph.read(address, size)

    def _mmio_write(self, _uc, offset, size, value, _user):
        self.periph.write(stm32.PERIPH_BASE + offset, size, value)

    def _bitband_read(self, _uc, offset, _size, _user):
        address, bit = stm32.bitband_target(offset)
        return (self.periph.read(address, 1) >> bit) & 1

    def _bitband_write(self, _uc, offset, _size, value, _user):
        address, bit = stm32.bitband_target(offset)
        byte = self.periph.read(address, 1)
        byte = (byte | (1 << bit)) if value & 1 else (byte & ~(1 << bit))
        self.periph.write(address, 1, byte)

    def _ppb_read(self, _uc, offset, size, _user):
        return self.periph.read(stm32.PPB_BASE + offset, size)

    def _ppb_write(self, _uc, offset, size, value, _user):
        self.periph.write(stm32.PPB_BASE + offset, size, value)

    def _pend(self, exception: int) -> None:
        self.periph.pending.add(exception)
        if self.current is not None:
            self.current.pended.append(exception)

    def _transmitted(self, _box: int, frame: stm32.CanFrame) -> None:
        if self.current is not None:
            counter = self.counter
            self.current.transmits.append(
                Mark(
                    counter.instructions, counter.cycles, counter.refetches, self.flash_reads, frame
                )
            )

    def _on_flash_read(self, _uc, _access, _address, _size, _value, _user):
        self.flash_reads += 1

    # -- instruction hook ------------------------------------------------------------------

    def _timing(self, address: int, size: int):
        code = bytes(self.uc.mem_read(address, size))
        insn = next(self._md.disasm(code, address), None)
        if insn is None:
            raise RuntimeError(f"cannot decode the instruction at {address:#010x}")
        timing = cycles.classify(insn)
        conditional = timing.cond not in (cs_arm.ARM_CC_AL, cs_arm.ARM_CC_INVALID) and (
            timing.kind != cycles.BRANCH
        )
        entry = (timing, conditional, self._is_idle_loop(insn))
        self._timings[address] = entry
        return entry

    def _is_idle_loop(self, insn) -> bool:
        """Whether `insn` starts the idle loop: hints (YIELD, WFI, WFE, NOP) up to an
        unconditional branch back to `insn`. The emulator stops before executing it."""
        if insn.id not in _HINTS:
            return False
        code = bytes(self.uc.mem_read(insn.address, 32))
        for following in self._md.disasm(code, insn.address):
            if following.id in _HINTS:
                continue
            return (
                following.id == cs_arm.ARM_INS_B
                and following.cc in (cs_arm.ARM_CC_AL, cs_arm.ARM_CC_INVALID)
                and following.operands[0].imm == insn.address
            )
        return False

    def _on_code(self, uc, address, size, _user):
        entry = self._timings.get(address)
        if entry is None:
            entry = self._timing(address, size)
        timing, conditional, idle = entry
        if address in self.pc_counts:
            self.pc_counts[address] += 1
        if idle and self.current is None:
            self.idle_address = address
            uc.emu_stop()
            return
        if self._check_sp:
            sp = uc.reg_read(UC_ARM_REG_SP)
            if sp < self.min_sp:
                self.min_sp = sp
        if self._check_mask:
            self._update_mask(address)
        passed = True
        if conditional:
            passed = cycles.condition_passes(timing.cond, uc.reg_read(UC_ARM_REG_XPSR))
        counter = self.counter
        if self._trace is not None:
            before = counter.cycles
            counter.step(timing, address, size, passed)
            self._trace.append((address, counter.cycles - before))
        else:
            counter.step(timing, address, size, passed)
        self._check_sp = timing.writes_sp
        self._check_mask = timing.kind == cycles.SYSTEM and self.current is not None

    def masks(self, level: int) -> bool:
        """Whether PRIMASK or BASEPRI now hold off an interrupt of hardware priority `level`."""
        if self.uc.reg_read(UC_ARM_REG_PRIMASK) & 1:
            return True
        basepri = self.uc.reg_read(UC_ARM_REG_BASEPRI) & 0xFF
        return basepri != 0 and basepri <= level

    def _update_mask(self, address: int) -> None:
        """Called after a system instruction (MSR, CPS) ran: did masking start or end?"""
        for level in self.mask_levels:
            masked = self.masks(level)
            if masked and level not in self._mask_starts:
                self._mask_starts[level] = (
                    self.counter.instructions,
                    self.counter.cycles,
                    address,
                )
            elif not masked and level in self._mask_starts:
                self._close_mask(level)

    def _close_mask(self, level: int) -> None:
        instructions, start_cycles, address = self._mask_starts.pop(level)
        length = self.counter.cycles - start_cycles
        longest = self.longest_masks.get(level, (0, 0, "", 0))
        if length > longest[0] and self.current is not None:
            self.longest_masks[level] = (
                length,
                self.counter.instructions - instructions,
                f"{self.current.name} (during: {self.current.label})",
                address,
            )

    # -- running ---------------------------------------------------------------------------

    def _paint(self) -> None:
        words = (self.stack_top - self.stack_bottom) // 4
        self.uc.mem_write(self.stack_bottom, PAINT.to_bytes(4, "little") * words)

    def painted_depth(self) -> int:
        """Bytes from the top of the stack down to the deepest word that is not the paint."""
        data = bytes(self.uc.mem_read(self.stack_bottom, self.stack_top - self.stack_bottom))
        paint = PAINT.to_bytes(4, "little")
        for offset in range(0, len(data), 4):
            if data[offset : offset + 4] != paint:
                return self.stack_top - (self.stack_bottom + offset)
        return 0

    def _run(self, start: int, until: int) -> None:
        try:
            self.uc.emu_start(start | 1, until, count=RUN_LIMIT)
        except UcError as error:
            pc = self.uc.reg_read(UC_ARM_REG_PC)
            raise RuntimeError(f"emulation stopped at {pc:#010x}: {error}") from error

    def boot(self) -> int:
        """Runs from the reset vector into the idle loop; returns the instructions it took."""
        uc = self.uc
        uc.reg_write(UC_ARM_REG_SP, self.stack_top)
        self.min_sp = self.stack_top
        self.counter = cycles.CycleCounter()
        self._run(self.image.vectors[1], MAGIC_RETURN)
        if self.idle_address is None:
            pc = uc.reg_read(UC_ARM_REG_PC)
            raise RuntimeError(f"the firmware did not reach an idle loop (pc {pc:#010x})")
        self.thread_min_sp = min(self.thread_min_sp, self.min_sp)
        self.lowest_sp = min(self.lowest_sp, self.min_sp)
        return self.counter.instructions

    @property
    def thread_depth(self) -> int:
        return self.stack_top - self.thread_min_sp

    def call(self, exception: int, label: str = "") -> Invocation:
        """Calls one handler as the hardware would take the exception from thread mode."""
        uc = self.uc
        saved = {reg: uc.reg_read(reg) for reg in _SAVED_REGS}
        sp = saved[UC_ARM_REG_SP]
        frame_sp = (sp - FRAME_BYTES) & ~7
        frame = [
            saved[UC_ARM_REG_R0],
            saved[UC_ARM_REG_R1],
            saved[UC_ARM_REG_R2],
            saved[UC_ARM_REG_R3],
            saved[UC_ARM_REG_R12],
            saved[UC_ARM_REG_LR],
            saved[UC_ARM_REG_PC],
            saved[UC_ARM_REG_XPSR] | (1 << 24),
        ]
        uc.mem_write(frame_sp, b"".join(w.to_bytes(4, "little") for w in frame))
        uc.reg_write(UC_ARM_REG_SP, frame_sp)
        uc.reg_write(UC_ARM_REG_LR, MAGIC_RETURN | 1)
        name = self.image.handlers.get(exception, f"exception {exception}")
        invocation = Invocation(exception, name, self.periph.priority(exception), label=label)
        self.current = invocation
        self.counter = cycles.CycleCounter()
        self.flash_reads = 0
        self.min_sp = frame_sp
        self._check_sp = False
        self._check_mask = False
        self._mask_starts = {}
        self._trace = [] if exception in self.traced else None
        try:
            self._run(self.image.vectors[exception], MAGIC_RETURN)
            self.counter.finish(MAGIC_RETURN)
            if uc.reg_read(UC_ARM_REG_PC) != MAGIC_RETURN:
                raise RuntimeError(f"{name} did not return within {RUN_LIMIT} instructions")
            if uc.reg_read(UC_ARM_REG_SP) != frame_sp:
                raise RuntimeError(f"{name} returned with a different SP")
        finally:
            for level in list(self._mask_starts):
                self._close_mask(level)
            self.current = None
        invocation.instructions = self.counter.instructions
        invocation.cycles = self.counter.cycles
        invocation.refetches = self.counter.refetches
        invocation.flash_reads = self.flash_reads
        invocation.mix = dict(self.counter.by_kind)
        invocation.trace, self._trace = self._trace, None
        invocation.depth = frame_sp - self.min_sp
        self.lowest_sp = min(self.lowest_sp, self.min_sp)
        for reg, value in saved.items():
            uc.reg_write(reg, value)
        self.invocations.append(invocation)
        return invocation

    def run_pending(self, label: str = "", limit: int = 10_000) -> list[Invocation]:
        """Takes pending exceptions, most urgent first, until none is left."""
        done = []
        for _ in range(limit):
            ready = [
                e
                for e in self.periph.pending
                if e not in FAULTS and self.periph.enabled(e) and e in self.image.handlers
            ]
            if not ready:
                return done
            exception = min(ready, key=lambda e: (self.periph.priority(e), e))
            self.periph.pending.discard(exception)
            done.append(self.call(exception, label))
        raise RuntimeError(f"still pending after {limit} handler calls: an interrupt storm")


_HINTS = {
    cs_arm.ARM_INS_HINT,
    cs_arm.ARM_INS_YIELD,
    cs_arm.ARM_INS_WFI,
    cs_arm.ARM_INS_WFE,
    cs_arm.ARM_INS_NOP,
}

_SAVED_REGS = [getattr(arm_const, f"UC_ARM_REG_R{i}") for i in range(13)] + [
    UC_ARM_REG_SP,
    UC_ARM_REG_LR,
    UC_ARM_REG_PC,
    UC_ARM_REG_XPSR,
]
