"""Unit tests of the exception model and SysTick (ARMv7-M ARM B1.5, B3.3; PM0056 4.3-4.5)
on tiny hand-assembled Thumb programs, and of the unicorn behaviour it relies on."""

import pytest
from unicorn import UC_HOOK_MEM_READ, UC_HOOK_MEM_WRITE_PROT, UC_PROT_EXEC, UC_PROT_READ, UcError
from unicorn import arm_const as arm

from stm32emu import cortex
from stm32emu.cortex import IRQ_BASE, Core, Nvic

CODE = 0x0800_0000
RAM = 0x2000_0000
B_SELF = 0xE7FE  # b .
BX_LR = 0x4770
ADDS_R4_1 = 0x3401
ADDS_R5_1 = 0x3501

THREAD = CODE  # b .
SPIN = CODE + 0x10  # a handler that never returns: b .
BUMP_R4 = CODE + 0x20  # adds r4, #1; bx lr
BUMP_R5 = CODE + 0x30  # adds r5, #1; bx lr


def halfwords(*values):
    return b"".join(v.to_bytes(2, "little") for v in values)


@pytest.fixture
def core():
    uc = cortex.make_uc()
    uc.mem_map(CODE, 0x1000)
    uc.mem_map(RAM, 0x1000)
    uc.mem_write(THREAD, halfwords(B_SELF))
    uc.mem_write(SPIN, halfwords(B_SELF))
    uc.mem_write(BUMP_R4, halfwords(ADDS_R4_1, BX_LR))
    uc.mem_write(BUMP_R5, halfwords(ADDS_R5_1, BX_LR))
    vectors = {IRQ_BASE + 0: BUMP_R4, IRQ_BASE + 1: BUMP_R5, IRQ_BASE + 2: SPIN}
    nvic = Nvic()
    c = Core(uc, nvic, lambda e: vectors[e])
    uc.reg_write(arm.UC_ARM_REG_SP, RAM + 0x800)
    uc.reg_write(arm.UC_ARM_REG_PC, THREAD | 1)
    nvic.enabled = 0b111
    return c


def set_priority(nvic, irq, priority):
    nvic.write(cortex.NVIC_IPR, priority << (8 * irq), 0xFF << (8 * irq))


def run(core, slices=4, count=50):
    for _ in range(slices):
        core.check_preemption()
        core.run(count)


def test_unicorn_faults_on_exc_return_in_thread_mode():
    """The fact the model is built on: unicorn does not do EXC_RETURN itself; a branch to
    0xFFFFFFF9 from thread mode stops with UC_ERR_EXCEPTION at 0xFFFFFFF8."""
    uc = cortex.make_uc()
    uc.mem_map(CODE, 0x1000)
    uc.mem_write(CODE, halfwords(BX_LR))
    uc.reg_write(arm.UC_ARM_REG_LR, cortex.EXC_RETURN_THREAD)
    with pytest.raises(UcError):
        uc.emu_start(CODE | 1, 0, count=5)
    assert uc.reg_read(arm.UC_ARM_REG_PC) == 0xFFFF_FFF8


def test_pending_enabled_interrupt_runs_and_returns(core):  # B1.5.6, B1.5.8
    core.nvic.set_pending(IRQ_BASE + 0)
    sp = core.uc.reg_read(arm.UC_ARM_REG_SP)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 1
    assert core.uc.reg_read(arm.UC_ARM_REG_SP) == sp
    assert core.uc.reg_read(arm.UC_ARM_REG_PC) == THREAD
    assert core.nvic.active_stack == [] and core.nvic.pending == set()


def test_disabled_interrupt_stays_pending(core):  # B3.4.3 ISER
    core.nvic.write(cortex.NVIC_ICER, 1, 0xFFFF_FFFF)
    core.nvic.set_pending(IRQ_BASE + 0)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 0 and IRQ_BASE in core.nvic.pending
    assert core.nvic.read(cortex.NVIC_ISPR) & 1


def test_higher_priority_preempts_an_active_handler(core):  # B1.5.4 nested preemption
    set_priority(core.nvic, 2, 0x80)
    set_priority(core.nvic, 1, 0x40)
    core.nvic.set_pending(IRQ_BASE + 2)
    run(core, 2)
    assert core.nvic.active_stack == [IRQ_BASE + 2]
    core.nvic.set_pending(IRQ_BASE + 1)
    run(core, 2)
    assert core.uc.reg_read(arm.UC_ARM_REG_R5) == 1
    assert core.nvic.active_stack == [IRQ_BASE + 2] and core.max_nesting == 2
    assert core.uc.reg_read(arm.UC_ARM_REG_PC) == SPIN


def test_equal_or_lower_priority_waits(core):  # B1.5.4: only a higher group priority preempts
    set_priority(core.nvic, 2, 0x40)
    set_priority(core.nvic, 1, 0x40)
    core.nvic.set_pending(IRQ_BASE + 2)
    run(core, 2)
    core.nvic.set_pending(IRQ_BASE + 1)
    run(core, 2)
    assert core.uc.reg_read(arm.UC_ARM_REG_R5) == 0 and IRQ_BASE + 1 in core.nvic.pending


def test_basepri_masks_equal_and_lower_priorities(core):  # B1.4.3 BASEPRI, B1.5.4
    set_priority(core.nvic, 0, 0x40)
    set_priority(core.nvic, 1, 0x30)
    core.uc.reg_write(arm.UC_ARM_REG_BASEPRI, 0x40)
    core.nvic.set_pending(IRQ_BASE + 0)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 0
    core.nvic.set_pending(IRQ_BASE + 1)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R5) == 1  # 0x30 beats BASEPRI 0x40
    core.uc.reg_write(arm.UC_ARM_REG_BASEPRI, 0)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 1


def test_primask_masks_every_configurable_priority(core):  # B1.4.3 PRIMASK
    set_priority(core.nvic, 0, 0x00)
    core.uc.reg_write(arm.UC_ARM_REG_PRIMASK, 1)
    core.nvic.set_pending(IRQ_BASE + 0)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 0
    core.uc.reg_write(arm.UC_ARM_REG_PRIMASK, 0)
    run(core)
    assert core.uc.reg_read(arm.UC_ARM_REG_R4) == 1


def test_tail_chaining_keeps_the_frame(core):  # B1.5.12 tail-chaining
    set_priority(core.nvic, 0, 0x40)
    set_priority(core.nvic, 1, 0x80)
    sp = core.uc.reg_read(arm.UC_ARM_REG_SP)
    core.nvic.set_pending(IRQ_BASE + 0)
    core.nvic.set_pending(IRQ_BASE + 1)
    core.check_preemption()
    assert core.nvic.active_stack == [IRQ_BASE + 0]  # the more urgent first
    core.run(50)
    assert core.tail_chains == 1 and core.nvic.active_stack == [IRQ_BASE + 1]
    assert core.uc.reg_read(arm.UC_ARM_REG_SP) == sp - 32  # still the one frame
    core.run(50)
    regs = core.uc.reg_read(arm.UC_ARM_REG_R4), core.uc.reg_read(arm.UC_ARM_REG_R5)
    assert regs == (1, 1) and core.uc.reg_read(arm.UC_ARM_REG_SP) == sp


def test_frame_is_8_byte_aligned_with_the_stkalign_bit(core):  # B1.5.7
    core.uc.reg_write(arm.UC_ARM_REG_SP, RAM + 0x804)
    core.nvic.set_pending(IRQ_BASE + 2)
    run(core, 1)
    frame_sp = core.uc.reg_read(arm.UC_ARM_REG_SP)
    assert frame_sp == RAM + 0x804 - 36
    xpsr = int.from_bytes(core.uc.mem_read(frame_sp + 28, 4), "little")
    assert xpsr & (1 << 9) and xpsr & (1 << 24)
    assert int.from_bytes(core.uc.mem_read(frame_sp + 24, 4), "little") == THREAD
    assert core.uc.reg_read(arm.UC_ARM_REG_LR) == cortex.EXC_RETURN_THREAD


def test_priority_registers_keep_four_bits():  # PM0056 4.3.7
    nvic = Nvic()
    nvic.write(cortex.NVIC_IPR + 4, 0xFF, 0xFF)
    assert nvic.read(cortex.NVIC_IPR + 4) & 0xFF == 0xF0
    nvic.write(cortex.SCB_SHPR + 8, 0x3F << 24, 0xFF << 24)  # SysTick's byte
    assert nvic.priority(cortex.SYSTICK) == 0x30


def test_stir_icsr_and_icpr_pend_and_clear():  # B3.4 NVIC_ISPR/ICPR, STIR; B3.2.4 ICSR
    nvic = Nvic()
    nvic.write(cortex.NVIC_STIR, 23, 0xFFFF_FFFF)
    assert IRQ_BASE + 23 in nvic.pending and nvic.read(cortex.NVIC_ISPR) == 1 << 23
    nvic.write(cortex.NVIC_ICPR, 1 << 23, 0xFFFF_FFFF)
    assert not nvic.pending
    nvic.write(cortex.SCB_ICSR, 1 << 26, 0xFFFF_FFFF)
    assert cortex.SYSTICK in nvic.pending and nvic.read(cortex.SCB_ICSR) & (1 << 26)
    nvic.write(cortex.SCB_ICSR, 1 << 25, 0xFFFF_FFFF)
    assert cortex.SYSTICK not in nvic.pending


def test_systick_period_countflag_and_cvr():  # B3.3.1-B3.3.5
    nvic = Nvic()
    nvic.now = 100
    nvic.write(cortex.SYST_RVR, 71_999, 0xFFFF_FFFF)
    nvic.write(cortex.SYST_CSR, 0b111, 0xFFFF_FFFF)
    assert nvic.next_systick() == 100 + 72_000
    nvic.now = 100 + 1000
    assert nvic.read(cortex.SYST_CVR) == 71_999 - 1000
    nvic.advance_systick(100 + 72_000)
    assert cortex.SYSTICK in nvic.pending
    assert nvic.read(cortex.SYST_CSR) & (1 << 16)
    assert not nvic.read(cortex.SYST_CSR) & (1 << 16)  # COUNTFLAG clears on read
    nvic.write(cortex.SYST_CSR, 0b011, 0xFFFF_FFFF)  # CLKSOURCE 0: HCLK/8 on the STM32
    assert nvic.systick_period() == 8 * 72_000


def test_aircr_sysresetreq_needs_the_key():  # B3.2.6
    nvic = Nvic()
    nvic.write(cortex.SCB_AIRCR, 1 << 2, 0xFFFF_FFFF)
    assert not nvic.reset_requested
    nvic.write(cortex.SCB_AIRCR, 0x05FA_0004, 0xFFFF_FFFF)
    assert nvic.reset_requested


# -- precise mode --------------------------------------------------------------------------

STR_R1_R2 = 0x6011  # str r1, [r2]
ADDS_R6_1 = 0x3601
ADDS_R7_1 = 0x3701
CMP_R0_R0 = 0x4280
ITT_EQ = 0xBF04
MSR_BASEPRI_R3 = (0xF383, 0x8811)
B_SELF_AT = CODE + 0x40  # the thread programs below start here


class Recorder(cortex.Observer):
    """The observer's calls, in order."""

    def __init__(self) -> None:
        self.calls = []

    def entered(self, exception, interrupted):
        self.calls.append(("entered", exception - IRQ_BASE, interrupted))

    def returned(self, exception, chained):
        self.calls.append(("returned", exception - IRQ_BASE, chained and chained - IRQ_BASE))


@pytest.fixture
def precise(core):
    """The core in precise mode, the system control space mapped (stores reach the NVIC),
    r2 pointing at STIR, r1 = 0 (a store pends IRQ 0), and an observer."""

    def read(_uc, offset, size, _user):
        word = core.nvic.read(0xE000_E000 + (offset & ~3))
        return (word >> ((offset & 3) * 8)) & ((1 << (size * 8)) - 1)

    def write(_uc, offset, size, value, _user):
        shift = (offset & 3) * 8
        mask = ((1 << (size * 8)) - 1) << shift
        core.nvic.write(0xE000_E000 + (offset & ~3), (value << shift) & mask, mask)

    core.uc.mmio_map(0xE000_E000, 0x1000, read, None, write, None)
    core.uc.reg_write(arm.UC_ARM_REG_R2, cortex.NVIC_STIR)
    core.uc.reg_write(arm.UC_ARM_REG_R1, 0)
    core.observer = Recorder()
    core.precise()
    return core


def program(core, *words):
    """Thread mode runs `words`, then `b .`."""
    core.uc.mem_write(B_SELF_AT, halfwords(*words, B_SELF))
    core.uc.reg_write(arm.UC_ARM_REG_PC, B_SELF_AT | 1)


def test_precise_slice_ends_when_its_cycles_are_spent(core):
    program(core, *[ADDS_R6_1] * 8)
    core.precise(lambda _address, _size: 3)
    core.run(7)  # three instructions: 9 cycles, the first to reach 7
    assert core.uc.reg_read(arm.UC_ARM_REG_R6) == 3 and core.cycles == 9
    assert core.stop_reason == "slice" and core.uc.reg_read(arm.UC_ARM_REG_PC) == B_SELF_AT + 6


def test_slices_charge_their_whole_count_without_precise_mode(core):  # the board's time
    program(core, ADDS_R6_1, ADDS_R6_1)
    core.run(50)
    assert core.cycles == 50


def test_precise_a_store_that_pends_preempts_before_the_next_instruction(precise):
    """B1.5.6: an exception that becomes pending and beats the execution priority is taken
    at the next instruction boundary; the frame returns to that instruction."""
    program(precise, STR_R1_R2, ADDS_R6_1)
    precise.run(100)
    assert precise.stop_reason == "preempt" and precise.uc.reg_read(arm.UC_ARM_REG_R6) == 0
    assert precise.check_preemption()
    assert precise.observer.calls == [("entered", 0, B_SELF_AT + 2)]
    frame_sp = precise.uc.reg_read(arm.UC_ARM_REG_SP)
    assert int.from_bytes(precise.uc.mem_read(frame_sp + 24, 4), "little") == B_SELF_AT + 2
    for _ in range(3):
        precise.check_preemption()
        precise.run(100)
    assert precise.uc.reg_read(arm.UC_ARM_REG_R4) == 1, "the handler ran"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R6) == 1, "then the interrupted code went on"
    assert precise.observer.calls[1:] == [("returned", 0, None)]


def test_precise_never_stops_inside_an_it_block(precise):
    """The frame does not carry the IT state here, so a pend inside an IT block is taken
    after the block (ARMv7-M takes it inside and keeps ITSTATE in the stacked xPSR)."""
    program(precise, CMP_R0_R0, ITT_EQ, STR_R1_R2, ADDS_R6_1, ADDS_R7_1)
    precise.run(100)
    assert precise.stop_reason == "preempt"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R6) == 1, "the block's second instruction ran"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R7) == 0
    assert precise.uc.reg_read(arm.UC_ARM_REG_PC) == B_SELF_AT + 8


def test_precise_lowering_basepri_lets_the_pending_one_in_at_once(precise):  # B1.4.3, B5.2.3
    set_priority(precise.nvic, 0, 0x40)
    precise.uc.reg_write(arm.UC_ARM_REG_BASEPRI, 0x40)
    precise.uc.reg_write(arm.UC_ARM_REG_R3, 0)
    program(precise, STR_R1_R2, ADDS_R6_1, *MSR_BASEPRI_R3, ADDS_R7_1)
    precise.run(100)
    assert precise.stop_reason == "preempt"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R6) == 1, "masked: the store did not preempt"
    assert precise.uc.reg_read(arm.UC_ARM_REG_PC) == B_SELF_AT + 8, "right after the MSR"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R7) == 0


def test_observer_sees_nesting_and_tail_chaining(precise):  # B1.5.4, B1.5.12
    set_priority(precise.nvic, 2, 0x80)
    set_priority(precise.nvic, 0, 0x40)
    set_priority(precise.nvic, 1, 0x40)
    precise.nvic.set_pending(IRQ_BASE + 2)  # the handler that spins
    run(precise, 2)
    precise.nvic.set_pending(IRQ_BASE + 0)
    precise.nvic.set_pending(IRQ_BASE + 1)
    run(precise, 4)
    assert precise.observer.calls == [
        ("entered", 2, THREAD),
        ("entered", 0, SPIN),  # preempts the spinning handler
        ("returned", 0, 1),  # and tail-chains into the other one of its priority
        ("entered", 1, None),
        ("returned", 1, None),  # back to the spinning handler
    ]
    assert precise.nvic.active_stack == [IRQ_BASE + 2]


def test_on_pend_names_the_exception():
    nvic = Nvic()
    pends = []
    nvic.on_pend = pends.append
    nvic.write(cortex.NVIC_STIR, 5, 0xFFFF_FFFF)
    nvic.set_pending(IRQ_BASE + 5)  # already pending: no second call
    nvic.write(cortex.SCB_ICSR, 1 << 26, 0xFFFF_FFFF)
    assert pends == [IRQ_BASE + 5, cortex.SYSTICK]


def test_a_push_below_ram_is_a_fault_with_its_address(core):
    """A stack that runs off the start of RAM (flip-link's layout puts it there): the push
    faults (a precise BusFault, taken as HardFault), the core stays locked until a reset,
    and the faulting address is kept for the board's `status`."""
    push = CODE + 0x40
    core.uc.mem_write(push, halfwords(0xB401, B_SELF))  # push {r0}; b .
    core.uc.reg_write(arm.UC_ARM_REG_SP, RAM)
    core.uc.reg_write(arm.UC_ARM_REG_PC, push | 1)
    assert (core.faults, core.fault_address) == (0, None)
    run(core, slices=2)
    assert core.locked_up
    assert core.faults == 1
    assert core.fault_address == RAM - 4
    run(core, slices=2)
    assert core.faults == 1, "a locked core runs nothing more"


LDRB_R4_R3 = 0x781C  # ldrb r4, [r3]
CMP_R4_R4 = 0x42A4
BEQ_SKIP_ONE = 0xD000  # beq over the next half-word
BNE_SKIP_ONE = 0xD100  # bne over the next half-word


def test_precise_a_branch_after_an_it_block_with_a_load_is_no_it_block(precise):
    """A load inside an IT block, then a conditional branch out of it to another B<cond>:
    unicorn (with the precise hook) left the block's IT bits in the CPU state, and the
    branch target's B<cond> ran as if inside an IT block, an invalid instruction (the
    firmware's SDO read path hit it, under the machine benchmark's hook on flash reads). The
    hook clears them after the block."""
    precise.uc.reg_write(arm.UC_ARM_REG_R3, RAM)
    precise.uc.hook_add(UC_HOOK_MEM_READ, lambda *_: None, begin=RAM, end=RAM + 3)
    program(
        precise,
        CMP_R0_R0,
        ITT_EQ,
        LDRB_R4_R3,
        CMP_R4_R4,
        BEQ_SKIP_ONE,
        ADDS_R7_1,
        BNE_SKIP_ONE,
        ADDS_R6_1,
        ADDS_R6_1,
    )
    precise.run(100)
    assert not precise.locked_up, precise.stop_reason
    assert precise.uc.reg_read(arm.UC_ARM_REG_R7) == 0, "beq taken"
    assert precise.uc.reg_read(arm.UC_ARM_REG_R6) == 2, "bne not taken, both adds ran"


def flash_uc():
    """Code in read/execute memory (as the board maps its flash): `blx r4` to a function F
    (`movs r0, #1; bx lr`), `mov r5, r0`, `strh r1, [r6]` (r6 = F), `blx r4` again."""
    uc = cortex.make_uc()
    uc.mem_map(CODE, 0x1000, UC_PROT_READ | UC_PROT_EXEC)
    uc.mem_map(RAM, 0x1000)
    uc.mem_write(CODE, halfwords(0x47A0, 0x4605, 0x8031, 0x47A0, B_SELF))
    uc.mem_write(CODE + 0x200, halfwords(0x2001, BX_LR))
    uc.reg_write(arm.UC_ARM_REG_R4, (CODE + 0x200) | 1)
    uc.reg_write(arm.UC_ARM_REG_R6, CODE + 0x200)
    uc.reg_write(arm.UC_ARM_REG_R1, 0x2002)  # movs r0, #2
    uc.reg_write(arm.UC_ARM_REG_SP, RAM + 0x800)
    return uc


@pytest.mark.parametrize("drop", [False, True])
def test_unicorn_store_to_protected_code_lands_only_as_the_hook_writes_it(drop):
    """The board's flash writes (machine.py): a write-protection hook that returns True
    makes the store count as done without its bytes landing (the hook's `mem_write` is what
    memory holds), and a `mem_write` alone leaves the old translation of that code in use:
    only `ctl_remove_cache` makes the CPU run the new bytes."""
    uc = flash_uc()
    stores = []

    def hook(uc, _access, address, size, value, _user):
        stores.append((address, size, value))
        uc.mem_write(address, (value & 0xFFF0 | 3).to_bytes(size, "little"))  # not `value`
        if drop:
            uc.ctl_remove_cache(address, address + size)
        return True

    uc.hook_add(UC_HOOK_MEM_WRITE_PROT, hook, begin=CODE, end=CODE + 0xFFF)
    uc.emu_start(CODE | 1, 0, count=8)
    assert stores == [(CODE + 0x200, 2, 0x2002)]
    assert bytes(uc.mem_read(CODE + 0x200, 2)) == halfwords(0x2003), "the hook's bytes"
    first, second = uc.reg_read(arm.UC_ARM_REG_R5), uc.reg_read(arm.UC_ARM_REG_R0)
    assert (first, second) == ((1, 3) if drop else (1, 1))
