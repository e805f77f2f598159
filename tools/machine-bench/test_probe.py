"""The instrument on the release image (`stm32emu`'s machine in precise mode): a handler's
own cycles are its instructions' estimates, entries, returns and tail-chains are charged on
the core clock, and a handler that preempts another is counted apart from it. Needs the
release ELF (as tools/stm32emu/test_machine.py)."""

import pytest

import cycles
from probe import Probe
from stm32emu import periph
from stm32emu.machine import Machine
from stm32emu.test_machine import ELF

pytestmark = pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")

EXTI9_5 = 16 + 23
RX0 = 16 + 20
TIM3 = 16 + 29
GPIOB_IDR = periph.GPIOB_BASE + 0x08


def booted(on_entered=None) -> tuple[Machine, Probe]:
    m = Machine(str(ELF))
    p = Probe(m)
    p.traced.add(EXTI9_5)
    p.watch(GPIOB_IDR)
    p.on_entered = on_entered
    m.set_ab(3)
    until_idle(m)
    m.run_ms(20)
    until_idle(m)
    return m, p


def until_idle(m: Machine) -> None:
    for _ in range(10_000):
        if m.step(idle_jump=False):
            return
    raise AssertionError("the CPU did not idle")


def test_an_edge_handler_is_its_instructions_plus_entry_and_exit():
    m, p = booted()
    mark = len(p.invocations)
    m.set_ab(1)
    until_idle(m)
    (edge,) = [i for i in p.invocations[mark:] if i.exception == EXTI9_5]
    # Its instructions, then the refill of its return's branch to EXC_RETURN.
    charged = sum(charged for _, charged in edge.trace)
    assert edge.cycles == charged + cycles.P_INDIRECT and charged > edge.instructions > 10
    assert sum(edge.mix.values()) == edge.instructions
    # Taken from idle, back to idle: an entry and an exit on the core clock.
    assert edge.done_at - edge.start.cycles == (
        cycles.EXCEPTION_ENTRY + edge.cycles + cycles.EXCEPTION_EXIT
    )
    assert 0 < edge.reads[GPIOB_IDR] < edge.cycles, "it reads the port on its way"
    assert (
        edge.read_at[GPIOB_IDR]
        == edge.start.cycles + cycles.EXCEPTION_ENTRY + edge.reads[GPIOB_IDR]
    )
    assert edge.depth > 0


def sdo_path(preempt: bool):
    """An SDO upload of 0x1000; with `preempt`, a wheel edge as TIM3 starts on it."""
    made = []

    def entered(invocation):
        if preempt and invocation.exception == TIM3 and invocation.label == "sdo" and not made:
            made.append(invocation)
            m.exti.edge(6, rising=False)
            m.update_irqs()

    m, p = booted(entered)
    # Just after a SysTick: the frame's 8000 cycles on the bus and the path fit before the
    # next one (the SysTick that TIM3 pends itself for its timer queue comes after the reply).
    m.run_until(m.nvic.next_systick() + 1)
    until_idle(m)
    p.label = "sdo"
    mark = len(p.invocations)
    m.deliver(periph.Frame(0x610, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])))
    m.run_ms(2)
    done = p.invocations[mark:]
    rx0 = next(i for i in done if i.exception == RX0)
    tim3 = next(i for i in done if i.exception == TIM3)
    (reply,) = [t for t in tim3.transmits if t.frame.can_id == 0x590]
    edges = [i for i in done if i.exception == EXTI9_5]
    return p, rx0, tim3, reply, edges


def test_a_preempting_handler_is_counted_apart_and_on_the_clock():
    """The same request twice, the second time with a wheel edge that preempts TIM3 at its
    start: TIM3's own figures do not change, the span from RX0's entry to the reply grows
    by exactly the edge's entry, handler and return, and the edge nests on TIM3's stack."""
    _, rx0, tim3, reply, edges = sdo_path(False)
    p, rx0_b, tim3_b, reply_b, (edge,) = sdo_path(True)
    assert not edges and tim3_b.preempted_by == ["EXTI9_5"] + tim3.preempted_by
    assert tim3_b.start.cycles == rx0_b.done_at - cycles.TAIL_CHAIN, "TIM3 tail-chains on RX0"
    assert (tim3_b.cycles, tim3_b.instructions) == (tim3.cycles, tim3.instructions)
    assert reply_b.cycles == reply.cycles and reply_b.frame == reply.frame
    span = reply.at.cycles - rx0.start.cycles
    span_b = reply_b.at.cycles - rx0_b.start.cycles
    assert span_b - span == cycles.EXCEPTION_ENTRY + edge.cycles + cycles.EXCEPTION_EXIT
    assert (reply_b.at.entries - rx0_b.start.entries, reply_b.at.chains - rx0_b.start.chains) == (
        2,
        1,
    ), "RX0 and the edge entered, TIM3 tail-chained"
    assert p.stack_top - p.lowest_sp >= tim3_b.depth + edge.depth + 2 * 32


def test_critical_sections_in_handlers_are_measured():
    m, p = booted()
    m.deliver(periph.Frame(0x610, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])))
    m.run_ms(2)
    assert p.mask_levels and p.longest_masks, "the CAN side locks its resources"
    length, instructions, where, _ = max(p.longest_masks.values())
    assert length > instructions > 0 and where.split()[0] in p.image.handlers.values()
