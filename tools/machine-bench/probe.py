"""The machine benchmark's instrument on the chip model: `stm32emu`'s machine in precise mode,
every instruction charged its Cortex-M3 cycle estimate (`cycles.py`), every exception entry,
return and tail-chain its cost from the Cortex-M3 TRM, and what the benchmark reads off
the run:

- one `Invocation` per handler run, with its own instructions, cycles, flash refetches and
  data reads, instruction mix and stack depth (bytes below its own exception frame, counted
  only while it is the running context: a handler that preempts it has its own);
- the run's running totals (`Totals`): the core clock (`Core.cycles`, the machine's time in
  this mode) and the counts of instructions, refetches, flash reads, entries, tail-chains
  and exits, so that a span across handlers (an SDO request's path, a millisecond of the
  CAN side, an edge's wait for its port read) is read directly, nested preemptions and
  tail-chains included;
- per priority level, the longest stretch PRIMASK or BASEPRI held an interrupt of that
  level off (`longest_masks`), from the system instruction that raised the mask to the one
  that lowered it or the return of the handler that raised it;
- the first read of each watched register per invocation (`Invocation.reads`), with its
  time on the core clock;
- the exceptions an invocation pended, and each transmit request (TXRQ) it made with the
  frame;
- the lowest SP of the whole run and of thread mode, and the entries of chosen functions
  (`pc_counts`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from capstone import arm as cs_arm
from unicorn import UC_HOOK_MEM_READ
from unicorn.arm_const import UC_ARM_REG_BASEPRI, UC_ARM_REG_PRIMASK, UC_ARM_REG_SP, UC_ARM_REG_XPSR

import cycles
from stm32emu import cortex, periph
from stm32emu.image import FAULTS
from stm32emu.machine import Machine

FRAME_BYTES = 32


@dataclass(frozen=True)
class Totals:
    """The run's counters at one moment."""

    cycles: int
    instructions: int
    refetches: int
    flash_reads: int
    # Exception entries (from thread mode or preempting), tail-chains, and returns that
    # unstack.
    entries: int
    chains: int
    exits: int


@dataclass(frozen=True)
class Mark:
    """A handler's own counters up to and including one instruction, and the run's."""

    instructions: int
    cycles: int
    refetches: int
    flash_reads: int
    at: Totals
    frame: periph.Frame


@dataclass
class Invocation:
    """One handler run, from its entry to its return."""

    exception: int
    name: str
    priority: int
    label: str
    # The run's totals before its entry (or the tail-chain into it) and after its last
    # instruction.
    start: Totals
    end: Totals | None = None
    # Its own instructions, cycles (entry and return not included), refetches from flash
    # (taken branches, ISB) and data reads from flash: each costs the flash wait states.
    instructions: int = 0
    cycles: int = 0
    refetches: int = 0
    flash_reads: int = 0
    # Bytes below its own exception frame at its deepest.
    depth: int = 0
    # Exceptions its instructions pended.
    pended: list[int] = field(default_factory=list)
    # Where each transmit request (TXRQ) fell in the handler, with its frame.
    transmits: list[Mark] = field(default_factory=list)
    # Executed instructions by class (see `cycles`).
    mix: dict[str, int] = field(default_factory=dict)
    # (address, cycles charged) per executed instruction, for traced exceptions.
    trace: list[tuple[int, int]] | None = None
    # Watched register address -> its own cycles up to its first read, inclusive; and the
    # core clock then.
    reads: dict[int, int] = field(default_factory=dict)
    read_at: dict[int, int] = field(default_factory=dict)
    # Handlers that preempted it.
    preempted_by: list[str] = field(default_factory=list)
    # The core clock once its return (unstacking or tail-chaining) is done.
    done_at: int = 0


class Context:
    """What runs: thread mode (no invocation) or a handler."""

    def __init__(self, invocation: Invocation | None, frame_sp: int, traced: bool) -> None:
        self.invocation = invocation
        self.counter = cycles.CycleCounter()
        self.flash_reads = 0
        self.frame_sp = frame_sp
        self.min_sp = frame_sp
        self.trace: list[tuple[int, int]] | None = [] if traced else None


class Probe(cortex.Observer):
    """Instruments `machine` (before it runs): precise mode with the cycle estimate."""

    def __init__(self, machine: Machine) -> None:
        self.m = machine
        self.uc = machine.uc
        self.core = machine.core
        self.image = machine.image
        self.stack_top = self.image.initial_sp
        self._md = cycles.disassembler()
        self._timings: dict[int, tuple[cycles.Timing, bool]] = {}
        self.thread = Context(None, self.stack_top, False)
        self.contexts = [self.thread]  # the running context last
        self.invocations: list[Invocation] = []
        self.instructions = 0
        self.refetches = 0
        self.flash_reads = 0
        self.entries = 0
        self.chains = 0
        self.exits = 0
        self.lowest_sp = self.stack_top
        self.label = ""
        # Exceptions whose invocations record every instruction (`Invocation.trace`).
        self.traced: set[int] = set()
        # Masking: the hardware priorities of the image's handlers (read from the NVIC at the
        # first exception entry: init has set them by then); per level the longest stretch
        # PRIMASK or BASEPRI held an interrupt of that priority off in a handler, as
        # (cycles, instructions, handler and label, address of the instruction after the
        # one that raised the mask).
        self.mask_levels: tuple[int, ...] | None = None
        self.longest_masks: dict[int, tuple[int, int, str, int]] = {}
        self._mask_starts: dict[int, tuple[int, int, int, Context]] = {}
        # Code addresses whose executions are counted (a function's entry: its calls).
        self.pc_counts: dict[int, int] = {}
        # The benchmark's hooks: a handler is about to run (`Invocation`), a watched register
        # was read (`Invocation`, address), a handler raised a mask over `level`.
        self.on_entered = None
        self.on_read = None
        self.on_mask = None
        self._chain_start: Totals | None = None
        self._outside = False
        self._check_sp = False
        self._check_mask = False
        self.core.observer = self
        self.core.precise(self._cost)
        machine.nvic.on_pend = self._pended
        machine.can.on_request = self._requested
        memory = self.image.memory
        self.uc.hook_add(
            UC_HOOK_MEM_READ, self._flash_read, begin=memory.flash_base, end=memory.flash_end - 1
        )

    # -- the run's counters ----------------------------------------------------------------

    @property
    def cycles(self) -> int:
        return self.core.cycles

    def totals(self) -> Totals:
        return Totals(
            self.core.cycles,
            self.instructions,
            self.refetches,
            self.flash_reads,
            self.entries,
            self.chains,
            self.exits,
        )

    @property
    def current(self) -> Invocation | None:
        return self.contexts[-1].invocation

    @property
    def thread_depth(self) -> int:
        return self.stack_top - self.thread.min_sp

    def from_outside(self, action) -> None:
        """Runs `action`, a stimulus from outside the CPU made while a handler runs (from a
        hook), without counting what it pends as that handler's."""
        self._outside = True
        try:
            action()
        finally:
            self._outside = False

    def watch(self, address: int) -> None:
        """Marks the first read of the register at `address` in every invocation."""
        self.uc.hook_add(UC_HOOK_MEM_READ, self._watched_read, begin=address, end=address + 3)

    # -- per instruction -------------------------------------------------------------------

    def _timing(self, address: int, size: int) -> tuple[cycles.Timing, bool]:
        code = bytes(self.uc.mem_read(address, size))
        insn = next(self._md.disasm(code, address), None)
        if insn is None:
            raise RuntimeError(f"cannot decode the instruction at {address:#010x}")
        timing = cycles.classify(insn)
        conditional = timing.cond not in (cs_arm.ARM_CC_AL, cs_arm.ARM_CC_INVALID) and (
            timing.kind != cycles.BRANCH
        )
        entry = (timing, conditional)
        self._timings[address] = entry
        return entry

    def _cost(self, address: int, size: int) -> int:
        """The core's precise hook: called before each instruction runs; its cycles."""
        entry = self._timings.get(address)
        if entry is None:
            entry = self._timing(address, size)
        timing, conditional = entry
        if address in self.pc_counts:
            self.pc_counts[address] += 1
        context = self.contexts[-1]
        if self._check_sp:
            self._update_sp(context)
        if self._check_mask:
            self._update_mask(address)
        passed = True
        if conditional:
            passed = cycles.condition_passes(timing.cond, self.uc.reg_read(UC_ARM_REG_XPSR))
        counter = context.counter
        before, refetches = counter.cycles, counter.refetches
        counter.step(timing, address, size, passed)
        charged = counter.cycles - before
        self.instructions += 1
        self.refetches += counter.refetches - refetches
        if context.trace is not None:
            context.trace.append((address, charged))
        self._check_sp = timing.writes_sp
        self._check_mask = timing.kind == cycles.SYSTEM and context.invocation is not None
        return charged

    def _update_sp(self, context: Context) -> None:
        sp = self.uc.reg_read(UC_ARM_REG_SP)
        if sp < context.min_sp:
            context.min_sp = sp
        if sp < self.lowest_sp:
            self.lowest_sp = sp

    def _flush(self, address: int) -> None:
        """The checks the last instruction asked for, before the context changes."""
        if self._check_sp:
            self._update_sp(self.contexts[-1])
        if self._check_mask:
            self._update_mask(address)
        self._check_sp = self._check_mask = False

    def _finish(self, context: Context, next_address: int) -> None:
        """Charges the context's last instruction's branch, given where execution goes on."""
        counter = context.counter
        before, refetches = counter.cycles, counter.refetches
        counter.finish(next_address)
        self.core.cycles += counter.cycles - before
        self.refetches += counter.refetches - refetches

    # -- masking ---------------------------------------------------------------------------

    def masks(self, level: int) -> bool:
        """Whether PRIMASK or BASEPRI now hold off an interrupt of hardware priority `level`."""
        if self.uc.reg_read(UC_ARM_REG_PRIMASK) & 1:
            return True
        basepri = self.uc.reg_read(UC_ARM_REG_BASEPRI) & 0xFF
        return basepri != 0 and basepri <= level

    def _update_mask(self, address: int) -> None:
        """After a system instruction (MSR, CPS) in a handler: did masking start or end?"""
        for level in self.mask_levels or ():
            masked = self.masks(level)
            if masked and level not in self._mask_starts:
                self._mask_starts[level] = (
                    self.instructions,
                    self.core.cycles,
                    address,
                    self.contexts[-1],
                )
                if self.on_mask is not None:
                    self.on_mask(level)
            elif not masked and level in self._mask_starts:
                self._close_mask(level)

    def _close_mask(self, level: int) -> None:
        instructions, start, address, context = self._mask_starts.pop(level)
        length = self.core.cycles - start
        longest = self.longest_masks.get(level, (0, 0, "", 0))
        invocation = context.invocation
        if length > longest[0] and invocation is not None:
            self.longest_masks[level] = (
                length,
                self.instructions - instructions,
                f"{invocation.name} (during: {invocation.label})",
                address,
            )

    # -- exceptions (cortex.Observer) --------------------------------------------------------

    def entered(self, exception: int, interrupted: int | None) -> None:
        if interrupted is not None:
            self._flush(interrupted)
            running = self.contexts[-1]
            self._finish(running, interrupted)
            start = self.totals()
            self.core.cycles += cycles.EXCEPTION_ENTRY
            self.entries += 1
        else:
            start = self._chain_start
        if self.mask_levels is None:
            nvic = self.m.nvic
            self.mask_levels = tuple(
                sorted({nvic.priority(e) for e in self.image.handlers if e not in FAULTS})
            )
        name = self.image.handlers.get(exception, f"exception {exception}")
        invocation = Invocation(exception, name, self.m.nvic.priority(exception), self.label, start)
        if interrupted is not None and self.contexts[-1].invocation is not None:
            self.contexts[-1].invocation.preempted_by.append(name)
        sp = self.uc.reg_read(UC_ARM_REG_SP)
        self.contexts.append(Context(invocation, sp, exception in self.traced))
        self.invocations.append(invocation)
        if self.on_entered is not None:
            self.on_entered(invocation)

    def returned(self, exception: int, chained: int | None) -> None:
        context = self.contexts.pop()
        invocation = context.invocation
        if invocation is None or invocation.exception != exception:
            raise RuntimeError(f"exception {exception} returned, but it was not running")
        # The last instruction's checks, then its branch to EXC_RETURN (a refill).
        self.contexts.append(context)
        self._flush(cortex.EXC_RETURN_FAULT_PC)
        self.contexts.pop()
        self._finish(context, cortex.EXC_RETURN_FAULT_PC)
        for level, (_, _, _, opener) in list(self._mask_starts.items()):
            if opener is context:
                self._close_mask(level)
        counter = context.counter
        invocation.instructions = counter.instructions
        invocation.cycles = counter.cycles
        invocation.refetches = counter.refetches
        invocation.flash_reads = context.flash_reads
        invocation.mix = dict(counter.by_kind)
        invocation.trace = context.trace
        invocation.depth = context.frame_sp - context.min_sp
        invocation.end = self.totals()
        if chained is None:
            self.core.cycles += cycles.EXCEPTION_EXIT
            self.exits += 1
        else:
            self._chain_start = self.totals()
            self.core.cycles += cycles.TAIL_CHAIN
            self.chains += 1
        invocation.done_at = self.core.cycles

    # -- memory and peripheral hooks -------------------------------------------------------

    def _flash_read(self, _uc, _access, _address, _size, _value, _user) -> None:
        self.flash_reads += 1
        self.contexts[-1].flash_reads += 1

    def _watched_read(self, _uc, _access, address, _size, _value, _user) -> None:
        invocation = self.contexts[-1].invocation
        if invocation is None or address in invocation.reads:
            return
        invocation.reads[address] = self.contexts[-1].counter.cycles
        invocation.read_at[address] = self.core.cycles
        if self.on_read is not None:
            self.on_read(invocation, address)

    def _pended(self, exception: int) -> None:
        invocation = self.contexts[-1].invocation
        if self.core.running and invocation is not None and not self._outside:
            invocation.pended.append(exception)

    def _requested(self, box: int) -> None:
        context = self.contexts[-1]
        if context.invocation is None:
            return
        counter = context.counter
        context.invocation.transmits.append(
            Mark(
                counter.instructions,
                counter.cycles,
                counter.refetches,
                context.flash_reads,
                self.totals(),
                self.m.can.frame_in(box),
            )
        )
