"""Unit tests of the exception model and SysTick (ARMv7-M ARM B1.5, B3.3; PM0056 4.3-4.5)
on tiny hand-assembled Thumb programs, and of the unicorn behaviour it relies on."""

import pytest
from unicorn import UcError
from unicorn import arm_const as arm

import cortex
from cortex import IRQ_BASE, Core, Nvic

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
