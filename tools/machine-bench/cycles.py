"""Cortex-M3 cycle estimate for one executed Thumb-2 instruction.

The classes follow the instruction timing table of the Cortex-M3 Technical Reference Manual
(cycle counts at zero wait states). Where the manual gives a range, the upper end is used,
so the estimate is pessimistic:

| class | instructions | cycles |
|---|---|---|
| alu | data processing, shifts, extend, bit field, MOVW/MOVT, ADR, IT, NOP, YIELD, MUL | 1 |
| mla | MLA, MLS | 2 |
| mull | UMULL, SMULL (3..5) / UMLAL, SMLAL (4..7) | 5 / 7 |
| div | UDIV, SDIV (2..12) | 12 |
| load / store | LDR*, STR* single | 2, or 1 when pipelined (below) |
| exclusive | LDREX*, STREX*, CLREX | 2 (never pipelined), CLREX 1 |
| dual | LDRD, STRD | 1 + 2 |
| multiple | LDM, STM, PUSH, POP | 1 + N (+ P if PC is loaded) |
| branch | B, B<cond>, BL, CBZ, CBNZ | 1, + P = 2 when taken |
| indirect | BX, BLX (register) | 1 + P = 4 |
| table | TBB, TBH | 2 + P = 4 |
| to pc | data processing or load writing PC | 1 (or 2) + P = 3 |
| system | MRS, MSR, CPSID, CPSIE (1..2) | 2 |
| isb | ISB (1 + B, B = a pipeline refill) | 4 |
| barrier | DMB, DSB (1 + B, B >= 0) | 2 |

P, the pipeline refill, ranges 1..3 in the manual; 2 is charged for PC-relative branches
(their target is known at decode) and 3 for branches to a register or a loaded value.
An instruction inside an IT block whose condition fails costs 1 cycle. A load or store single
right after another one takes 1 cycle (the manual's pipelining footnote) unless its address
uses the previous load's result.

Flash wait states (`wait_state_events`): at 72 MHz the STM32F103 needs 2 wait states. The
prefetch buffer hides them on sequential fetches; every taken branch, pipeline flush (ISB)
and data read from flash (literal pools, tables in .rodata) is charged the full 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import capstone
from capstone import arm

# Pipeline refills.
P_DIRECT = 2
P_INDIRECT = 3

# Exception entry (stacking, vector fetch) and return (unstacking), Cortex-M3 TRM
# "Exception entry and exit", zero wait states. A tail-chained exception skips the
# unstacking and restacking between two handlers.
EXCEPTION_ENTRY = 12
EXCEPTION_EXIT = 10
TAIL_CHAIN = 6

ALU = "alu"
LOAD = "load"
STORE = "store"
EXCLUSIVE = "exclusive"
MULTIPLE = "multiple"
BRANCH = "branch"
SYSTEM = "system"
BARRIER = "barrier"
OTHER = "other"


@dataclass(frozen=True)
class Timing:
    """How one instruction is charged."""

    # Instruction class (one of the constants above; for the report).
    kind: str
    # Cycles when executed (a branch: when not taken).
    cycles: int
    # Cycles when it is a load/store single that pipelines behind the previous one.
    pipelined: int
    # Extra cycles when it changes the flow (a taken branch, or PC written).
    taken: int
    # Whether it is a load/store single (may pipeline with a neighbour).
    single_transfer: bool
    # Registers its address is formed from (capstone register ids).
    address_regs: tuple[int, ...]
    # Registers a load writes (its result).
    loaded_regs: tuple[int, ...]
    # Whether it writes SP.
    writes_sp: bool
    # Condition code (capstone ARM_CC_*); ARM_CC_AL when unconditional.
    cond: int
    # Whether it flushes the pipeline without branching (ISB): a refetch.
    flushes: bool


_ALU_SIMPLE = {
    # Names of capstone instruction ids that take one cycle.
    "ADC",
    "ADD",
    "ADDW",
    "ADR",
    "AND",
    "ASR",
    "BFC",
    "BFI",
    "BIC",
    "CLZ",
    "CMN",
    "CMP",
    "EOR",
    "IT",
    "LSL",
    "LSR",
    "MOV",
    "MOVS",
    "MOVT",
    "MOVW",
    "MUL",
    "MVN",
    "NOP",
    "ORN",
    "ORR",
    "RBIT",
    "REV",
    "REV16",
    "REVSH",
    "ROR",
    "RRX",
    "RSB",
    "SBC",
    "SBFX",
    "SSAT",
    "SUB",
    "SUBW",
    "SXTB",
    "SXTH",
    "TEQ",
    "TST",
    "UBFX",
    "USAT",
    "UXTB",
    "UXTH",
    "YIELD",
    "SEV",
    "NEG",
    "HINT",
}


def _ids(names):
    return {getattr(arm, "ARM_INS_" + n) for n in names if hasattr(arm, "ARM_INS_" + n)}


ALU_IDS = _ids(_ALU_SIMPLE)
MLA_IDS = _ids(["MLA", "MLS"])
MULL_IDS = _ids(["UMULL", "SMULL"])
MLAL_IDS = _ids(["UMLAL", "SMLAL"])
DIV_IDS = _ids(["UDIV", "SDIV"])
LOAD_IDS = _ids(
    ["LDR", "LDRB", "LDRH", "LDRSB", "LDRSH", "LDRT", "LDRBT", "LDRHT", "LDRSBT", "LDRSHT"]
)
STORE_IDS = _ids(["STR", "STRB", "STRH", "STRT", "STRBT", "STRHT"])
EXCL_IDS = _ids(["LDREX", "LDREXB", "LDREXH", "STREX", "STREXB", "STREXH"])
DUAL_IDS = _ids(["LDRD", "STRD"])
MULTI_IDS = _ids(["LDM", "LDMDB", "STM", "STMDB", "PUSH", "POP"])
DIRECT_BRANCH_IDS = _ids(["B", "BL", "CBZ", "CBNZ"])
INDIRECT_BRANCH_IDS = _ids(["BX", "BLX"])
TABLE_IDS = _ids(["TBB", "TBH"])
SYSTEM_IDS = _ids(["MRS", "MSR", "CPS"])
ISB_IDS = _ids(["ISB"])
DMB_IDS = _ids(["DMB", "DSB"])
CLREX_IDS = _ids(["CLREX"])


def disassembler() -> capstone.Cs:
    """A Thumb-2, M-profile disassembler with operand details."""
    md = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
    md.detail = True
    return md


def _mem_regs(insn) -> tuple[int, ...]:
    regs = []
    for op in insn.operands:
        if op.type == arm.ARM_OP_MEM:
            for reg in (op.mem.base, op.mem.index):
                if reg != 0:
                    regs.append(reg)
    return tuple(regs)


def classify(insn) -> Timing:
    """The timing of a capstone instruction (disassembled with `detail`)."""
    _read, written = insn.regs_access()
    writes_pc = arm.ARM_REG_PC in written
    writes_sp = arm.ARM_REG_SP in written
    ident = insn.id
    cond = insn.cc
    address_regs = _mem_regs(insn)
    loaded: tuple[int, ...] = ()

    def timing(kind, cycles, *, pipelined=None, taken=0, single=False, flushes=False):
        return Timing(
            kind=kind,
            cycles=cycles,
            pipelined=cycles if pipelined is None else pipelined,
            taken=taken,
            single_transfer=single,
            address_regs=address_regs,
            loaded_regs=loaded,
            writes_sp=writes_sp,
            cond=cond,
            flushes=flushes,
        )

    if ident in LOAD_IDS:
        loaded = tuple(r for r in written if r not in address_regs or r == arm.ARM_REG_PC)
        if writes_pc:
            return timing(BRANCH, 2, taken=P_INDIRECT)
        return timing(LOAD, 2, pipelined=1, single=True)
    if ident in STORE_IDS:
        return timing(STORE, 2, pipelined=1, single=True)
    if ident in EXCL_IDS:
        return timing(EXCLUSIVE, 2)
    if ident in CLREX_IDS:
        return timing(EXCLUSIVE, 1)
    if ident in DUAL_IDS:
        return timing(LOAD if ident == arm.ARM_INS_LDRD else STORE, 3)
    if ident in MULTI_IDS:
        count = sum(1 for op in insn.operands if op.type == arm.ARM_OP_REG)
        # LDM/STM name the base register as the first operand; PUSH/POP do not.
        if ident not in _ids(["PUSH", "POP"]):
            count -= 1
        if writes_pc:
            return timing(BRANCH, 1 + count, taken=P_INDIRECT)
        return timing(MULTIPLE, 1 + count)
    if ident in DIRECT_BRANCH_IDS:
        return timing(BRANCH, 1, taken=P_DIRECT)
    if ident in INDIRECT_BRANCH_IDS:
        return timing(BRANCH, 1, taken=P_INDIRECT)
    if ident in TABLE_IDS:
        return timing(BRANCH, 2, taken=P_DIRECT)
    if ident in SYSTEM_IDS:
        return timing(SYSTEM, 2)
    if ident in ISB_IDS:
        return timing(BARRIER, 1 + P_INDIRECT, flushes=True)
    if ident in DMB_IDS:
        return timing(BARRIER, 2)
    if ident in MLA_IDS:
        return timing(ALU, 2)
    if ident in MULL_IDS:
        return timing(ALU, 5)
    if ident in MLAL_IDS:
        return timing(ALU, 7)
    if ident in DIV_IDS:
        return timing(ALU, 12)
    if ident in ALU_IDS:
        if writes_pc:
            return timing(BRANCH, 1, taken=P_INDIRECT)
        return timing(ALU, 1)
    # Anything else (UDF, BKPT, SVC, WFI...) is not expected on the measured paths; charge it
    # as one cycle and let the caller report it by its class.
    return timing(OTHER, 1)


def condition_passes(cond: int, xpsr: int) -> bool:
    """Whether condition `cond` (capstone ARM_CC_*) holds for the flags in `xpsr`."""
    n = bool(xpsr & (1 << 31))
    z = bool(xpsr & (1 << 30))
    c = bool(xpsr & (1 << 29))
    v = bool(xpsr & (1 << 28))
    table = {
        arm.ARM_CC_EQ: z,
        arm.ARM_CC_NE: not z,
        arm.ARM_CC_HS: c,
        arm.ARM_CC_LO: not c,
        arm.ARM_CC_MI: n,
        arm.ARM_CC_PL: not n,
        arm.ARM_CC_VS: v,
        arm.ARM_CC_VC: not v,
        arm.ARM_CC_HI: c and not z,
        arm.ARM_CC_LS: (not c) or z,
        arm.ARM_CC_GE: n == v,
        arm.ARM_CC_LT: n != v,
        arm.ARM_CC_GT: (not z) and n == v,
        arm.ARM_CC_LE: z or n != v,
    }
    return table.get(cond, True)


class CycleCounter:
    """Accumulates the estimate over a stream of executed instructions.

    Feed it every executed instruction in order with `step(timing, address, size, passed)`;
    `passed` is False for an IT-block instruction whose condition failed. Call `finish(next)`
    with the address execution continued at after the last instruction.
    """

    def __init__(self) -> None:
        self.instructions = 0
        self.cycles = 0
        # Taken branches and pipeline flushes (each a refetch from flash).
        self.refetches = 0
        self.by_kind: dict[str, int] = {}
        self._prev: Timing | None = None
        self._prev_end = 0

    def _close_previous(self, address: int) -> None:
        prev = self._prev
        if prev is None:
            return
        if prev.taken and address != self._prev_end:
            self.cycles += prev.taken
            self.refetches += 1
        if prev.flushes:
            self.refetches += 1

    def step(self, timing: Timing, address: int, size: int, passed: bool = True) -> None:
        self._close_previous(address)
        if not passed:
            cycles = 1
        elif (
            timing.single_transfer
            and self._prev is not None
            and self._prev.single_transfer
            and not set(timing.address_regs) & set(self._prev.loaded_regs)
        ):
            cycles = timing.pipelined
        else:
            cycles = timing.cycles
        self.instructions += 1
        self.cycles += cycles
        self.by_kind[timing.kind] = self.by_kind.get(timing.kind, 0) + 1
        self._prev = timing if passed else None
        self._prev_end = address + size

    def finish(self, next_address: int) -> None:
        """Charges the last instruction's branch, given where execution went on."""
        self._close_previous(next_address)
        self._prev = None
