"""Unit tests of the peripheral models, one or more per register behaviour, each naming
the section of RM0008 (or PM0075 for the FPEC) it checks."""

import pytest

from stm32emu import periph
from stm32emu.periph import Bxcan, Exti, Fpec, Frame, Gpio, Iwdg, Rcc

ALL = 0xFFFF_FFFF


# -- RCC (RM0008 7.3) ---------------------------------------------------------------------


def test_rcc_ready_flags_follow_their_enables():  # 7.3.1 CR, 7.3.2 CFGR
    rcc = Rcc()
    assert rcc.read(0x00) & 0b11 == 0b11  # HSION, HSIRDY out of reset
    rcc.write(0x00, 1 << 16 | 1 << 24 | 1, ALL)
    assert rcc.read(0x00) & (1 << 17 | 1 << 25) == 1 << 17 | 1 << 25
    rcc.write(0x04, 0b10, ALL)  # SW = PLL
    assert (rcc.read(0x04) >> 2) & 3 == 0b10  # SWS


def test_rcc_csr_reset_flags_and_rmvf():  # 7.3.10
    rcc = Rcc()
    assert rcc.read(0x24) & (Rcc.PORRSTF | Rcc.PINRSTF) == Rcc.PORRSTF | Rcc.PINRSTF
    rcc.write(0x24, 1 << 24, ALL)
    assert rcc.read(0x24) & 0xFC00_0000 == 0
    rcc.csr_flags |= Rcc.IWDGRSTF
    rcc.reset()  # a system reset keeps the flags
    assert rcc.read(0x24) & Rcc.IWDGRSTF


# -- GPIO (RM0008 9.2) ---------------------------------------------------------------------


def test_gpio_bsrr_brr_and_idr():  # 9.2.3-9.2.6
    changes = []
    gpio = Gpio("C", lambda port, odr: changes.append(odr))
    gpio.write(0x04, 0x0020_0000, ALL)  # PC13 output (MODE 10)
    gpio.write(0x10, 1 << 13, ALL)
    assert gpio.read(0x0C) == 1 << 13 and changes == [1 << 13]
    gpio.write(0x10, 1 << 13 | 1 << 29, ALL)  # set and reset together: set wins
    assert gpio.read(0x0C) == 1 << 13
    gpio.write(0x14, 1 << 13, ALL)
    assert gpio.read(0x0C) == 0
    gpio.levels = 0xFFFF
    assert gpio.read(0x08) == 0xFFFF & ~(1 << 13)  # an output reads its latch (9.1.9)


# -- AFIO and EXTI (RM0008 9.4, 10.3) -----------------------------------------------------


def test_afio_exticr_selects_the_port():  # 9.4.4
    afio = periph.Afio()
    afio.write(0x0C, 0x11 << 8, ALL)  # EXTICR2: lines 6 and 7 on port B
    assert afio.port_of_line(6) == 1 and afio.port_of_line(7) == 1 and afio.port_of_line(5) == 0


def test_exti_edges_need_trigger_and_mask_and_pr_clears_on_one():  # 10.2.3, 10.3.1-6
    exti = Exti()
    exti.edge(6, rising=True)
    assert exti.pr == 0  # masked, no trigger
    exti.write(0x00, 1 << 6, ALL)
    exti.write(0x08, 1 << 6, ALL)  # rising only
    exti.edge(6, rising=False)
    assert exti.pr == 0
    exti.edge(6, rising=True)
    assert exti.pr == 1 << 6 and exti.irqs() == {periph.IRQ_EXTI9_5}
    exti.write(0x14, 1 << 6, ALL)
    assert exti.pr == 0 and exti.irqs() == set()
    exti.write(0x10, 1 << 6, ALL)  # SWIER
    assert exti.pr == 1 << 6


# -- IWDG (RM0008 19) ----------------------------------------------------------------------


def test_iwdg_registers_are_write_protected_without_the_access_key():  # 19.3.2
    iwdg = Iwdg()
    iwdg.write(0x04, 3, ALL, 0)
    assert iwdg.read(0x04, 0) == 0
    iwdg.write(0x00, 0x5555, ALL, 0)
    iwdg.write(0x04, 3, ALL, 0)
    iwdg.write(0x08, 625, ALL, 0)
    assert iwdg.read(0x04, 0) == 3 and iwdg.read(0x08, 0) == 625
    assert iwdg.read(0x0C, 0) == 0b11  # PVU, RVU while updating (19.4.4)
    assert iwdg.read(0x0C, Iwdg.UPDATE_CYCLES) == 0
    iwdg.write(0x00, 0x1234, ALL, 0)  # another key closes them
    iwdg.write(0x08, 1, ALL, 0)
    assert iwdg.read(0x08, 0) == 625


def test_iwdg_counts_down_from_the_reload_and_key_aaaa_reloads():  # 19.3.1, 19.4.1
    iwdg = Iwdg()
    assert iwdg.expiry() is None
    iwdg.write(0x00, 0xCCCC, ALL, 1000)
    iwdg.write(0x00, 0x5555, ALL, 1000)
    iwdg.write(0x04, 3, ALL, 1000)  # /32: 1.25 kHz
    iwdg.write(0x08, 625, ALL, 1000)
    iwdg.write(0x00, 0xAAAA, ALL, 1000)
    assert iwdg.expiry() == 1000 + 626 * 72_000_000 * 32 // 40_000  # 500.8 ms
    iwdg.write(0x00, 0xAAAA, ALL, 5000)
    assert iwdg.expiry() == 5000 + 626 * 57_600


# -- FPEC (PM0075) -------------------------------------------------------------------------


def unlocked_fpec():
    f = Fpec(0x0800_FC00, bytearray(b"\xff" * 1024))
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    return f


def test_fpec_unlock_sequence_and_lock():  # PM0075 3.1, 4.2, 4.5
    f = Fpec(0x0800_FC00, bytearray(1024))
    assert f.read(0x10, 0) & 0x80
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    assert not f.read(0x10, 0) & 0x80
    f.write(0x10, 0x80, ALL, 0)
    assert f.read(0x10, 0) & 0x80


def test_fpec_wrong_key_locks_until_reset():  # PM0075 3.1
    f = Fpec(0x0800_FC00, bytearray(1024))
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    assert f.read(0x10, 0) & 0x80
    f.reset()
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    assert not f.read(0x10, 0) & 0x80


def test_fpec_page_erase_sets_eop_and_stalls():  # PM0075 2.3.4, 4.4
    f = unlocked_fpec()
    f.memory[:4] = b"\x01\x02\x03\x04"
    f.write(0x10, 0x02, ALL, 0)  # PER
    f.write(0x14, 0x0800_FC00, ALL, 0)
    f.write(0x10, 0x42, ALL, 0)  # STRT
    assert f.memory == bytearray(b"\xff" * 1024)
    assert f.read(0x0C, 0) & 0x20  # EOP
    assert f.take_stall() == Fpec.ERASE_CYCLES
    f.write(0x0C, 0x20, ALL, 0)
    assert not f.read(0x0C, 0) & 0x20


def test_fpec_half_word_programming_and_errors():  # PM0075 2.3.3, 4.4
    f = unlocked_fpec()
    f.write_memory(0, 2, 0x1234, 0)
    assert f.memory[:2] == b"\xff\xff" and f.read(0x0C, 0) & 0x04  # no PG: PGERR
    f.write(0x0C, 0x04, ALL, 0)
    f.write(0x10, 0x01, ALL, 0)  # PG
    f.write_memory(0, 2, 0x1234, 0)
    assert f.memory[:2] == b"\x34\x12" and not f.read(0x0C, 0) & 0x04
    f.write_memory(0, 2, 0x5678, 0)  # not erased: PGERR, unchanged
    assert f.memory[:2] == b"\x34\x12" and f.read(0x0C, 0) & 0x04
    f.write(0x0C, 0x04, ALL, 0)
    f.write_memory(0, 2, 0x0000, 0)  # zero may always be written
    assert f.memory[:2] == b"\x00\x00"
    f.write_memory(4, 4, 0x1111_2222, 0)  # not a half-word: PGERR
    assert f.memory[4:8] == b"\xff" * 4 and f.read(0x0C, 0) & 0x04


def test_fpec_locked_ignores_programming():  # PM0075 4.5 LOCK
    f = Fpec(0x0800_FC00, bytearray(b"\xff" * 1024))
    f.write(0x10, 0x01, ALL, 0)
    f.write_memory(0, 2, 0x1234, 0)
    assert f.memory[:2] == b"\xff\xff"


def erasing(seed=1, fill=b"\x00"):
    """An unlocked FPEC over two pages of `fill`, PER set and AR on the second page."""
    f = Fpec(0x0800_F800, bytearray(fill * 2048), seed)
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    f.write(0x10, 0x02, ALL, 0)
    f.write(0x14, 0x0800_FC00, ALL, 0)
    return f


def test_fpec_power_cut_inside_an_erase_leaves_a_seeded_part_erased():
    changes = []
    f = erasing(seed=7)
    f.on_change = lambda offset, length: changes.append((offset, length, bytes(f.memory)))
    f.write(0x10, 0x42, ALL, 1000)  # STRT at cycle 1000
    assert changes == [(1024, 1024, b"\x00" * 1024 + b"\xff" * 1024)], "written through at once"
    assert f.cut(1000 + Fpec.ERASE_CYCLES // 2)
    page = bytes(f.memory[1024:])
    halves = [page[i : i + 2] for i in range(0, 1024, 2)]
    assert set(halves) == {b"\x00\x00", b"\xff\xff"}, "erased or unchanged half-words"
    assert 150 < halves.count(b"\xff\xff") < 362
    assert f.memory[:1024] == b"\x00" * 1024, "the other page is untouched"
    assert changes[-1] == (1024, 1024, bytes(f.memory)) and f.cuts == 1
    # The same seed cuts the same way; another seed another way.
    again = erasing(seed=7)
    again.write(0x10, 0x42, ALL, 1000)
    again.cut(1001)
    other = erasing(seed=8)
    other.write(0x10, 0x42, ALL, 1000)
    other.cut(1001)
    assert again.memory == f.memory and other.memory != f.memory


def test_fpec_power_cut_after_an_operation_changes_nothing():
    f = erasing()
    f.write(0x10, 0x42, ALL, 1000)
    assert not f.cut(1000 + Fpec.ERASE_CYCLES)
    assert f.memory[1024:] == b"\xff" * 1024 and f.cuts == 0


def test_fpec_power_cut_inside_a_program_clears_only_some_bits():
    f = unlocked_fpec()
    f.write(0x10, 0x01, ALL, 0)  # PG
    f.write_memory(0, 2, 0x0000, 500)
    assert f.cut(501)
    value = f.read_memory(0, 2)
    assert value not in (0x0000, 0xFFFF), hex(value)
    # What is left may still be programmed to 0x0000 (NOR flash: clearing bits only).
    f.write_memory(0, 2, 0x0000, 10_000)
    assert f.read_memory(0, 2) == 0


def test_fpec_armed_cut_before_an_operation_stops_the_flash():
    f = unlocked_fpec()
    f.write(0x10, 0x01, ALL, 0)
    f.arm(2, inside=False)
    f.write_memory(0, 2, 0x1234, 0)
    assert not f.cut_requested
    f.write_memory(2, 2, 0x5678, 0)  # the second: never starts
    f.write_memory(4, 2, 0x9ABC, 0)  # nor anything after it
    assert f.cut_requested and f.operations == 1
    assert f.memory[:6] == b"\x34\x12\xff\xff\xff\xff"
    f.reset()  # the power-on after the cut
    assert not f.dead and not f.cut_requested


def test_fpec_armed_cut_inside_an_erase_leaves_it_half_done():
    f = erasing(seed=3)
    f.arm(1, inside=True)
    f.write(0x10, 0x42, ALL, 0)
    assert f.cut_requested and f.cuts == 1 and f.operations == 1
    page = bytes(f.memory[1024:])
    assert b"\xff\xff" in page and b"\x00\x00" in page
    assert not f.cut(1), "nothing left running"


# -- bxCAN (RM0008 24) ---------------------------------------------------------------------


def normal_can(sent=None):
    can = Bxcan((sent if sent is not None else []).append)
    can.write(0x00, 0x01, ALL, 0)  # INRQ, leave sleep
    can.write(0x1C, 0x001E_0001, ALL, 0)  # 1 Mbit/s
    can.write(0x00, 0x40, ALL, 0)  # ABOM, normal mode
    return can


def test_can_modes_and_acknowledges():  # 24.4.1-24.4.3, 24.9.1-2
    can = Bxcan(lambda f: None)
    assert can.read(0x04) & 0b11 == 0b10  # sleep after reset: SLAK
    can.write(0x00, 0x01, ALL, 0)
    assert can.read(0x04) & 0b11 == 0b01  # INAK
    can.write(0x00, 0x00, ALL, 0)
    assert can.read(0x04) & 0b11 == 0b00
    can.write(0x00, 0x02, ALL, 0)
    assert can.read(0x04) & 0b11 == 0b10 and can.read(0x04) & 0x10  # SLAKI
    can.write(0x04, 0x10, ALL, 0)
    assert not can.read(0x04) & 0x10


def test_can_normal_mode_waits_for_a_free_bus_to_synchronise():  # 24.4.2, figure 222
    can = Bxcan(lambda f: None)
    can.bus_dominant_until = 5000
    can.write(0x00, 0x01, ALL, 0)  # INRQ: acknowledged at once, dominant or not
    assert can.read(0x04) & 0b11 == 0b01
    can.write(0x00, 0x00, ALL, 100)  # request normal mode: no 11 recessive bits yet
    assert can.read(0x04) & 0b11 == 0b01 and not can.online()
    assert can.next_event(100) == 5000, "the end of the dominant stretch is an event"
    can.advance(4999)
    assert can.read(0x04) & 0b11 == 0b01
    can.advance(5000)
    assert can.read(0x04) & 0b11 == 0b00 and can.online()
    assert can.next_event(5000) is None, "an expired stretch is no event"
    # Sleep to normal mode synchronises the same way; a stretch held on waits for ever.
    can.write(0x00, 0x02, ALL, 6000)
    can.bus_dominant_until = None
    can.write(0x00, 0x00, ALL, 6000)
    can.advance(10**9)
    assert can.read(0x04) & 0b11 == 0b10
    can.bus_dominant_until = 0
    can.advance(10**9 + 1)
    assert can.read(0x04) & 0b11 == 0b00


def test_a_trickling_bus_takes_one_frame_per_interval():  # server `trickle <ms>`
    sent = []
    can = normal_can(sent)
    can.bus_trickle = 5000
    can.bus_hold_until = 5000
    for box, ident in enumerate((0x185, 0x186, 0x187)):
        load(can, box, ident)
    now = 0
    starts, ends = [], []
    while len(sent) < 3:
        now = can.next_event(now)
        was_idle = can.on_bus is None
        can.advance(now)
        if was_idle and can.on_bus is not None:
            starts.append(now)
            ends.append(can.on_bus_until)
    assert [f.can_id for f in sent] == [0x185, 0x186, 0x187]
    assert starts[0] == 5000
    assert starts[1:] == [end + 5000 for end in ends[:-1]], "each frame's end + the interval"


def test_can_timed_hold_and_dominant_bus_hold_the_mailboxes_then_end():  # server `hold <ms>`
    sent = []
    can = normal_can(sent)
    can.bus_hold_until = 3000
    load(can, 0, 0x710)
    can.advance(0)
    assert can.on_bus is None and can.next_event(0) == 3000
    can.advance(2999)
    assert can.on_bus is None
    can.advance(3000)
    assert can.on_bus == 0, "the hold is over: the frame starts"
    end = can.on_bus_until
    assert can.next_event(3000) == end, "the frame's end, not the expired hold"
    can.advance(end)
    assert [f.can_id for f in sent] == [0x710]
    assert can.next_event(end) is None, "an expired hold is no event"
    can.bus_dominant_until = end + 1000
    load(can, 1, 0x190)
    can.advance(end + 999)
    assert can.on_bus is None and can.next_event(end + 999) == end + 1000
    can.advance(end + 1000)
    assert can.on_bus == 1


def test_can_btr_only_in_init_mode_and_rate():  # 24.7.7, 24.9.7
    can = normal_can()
    can.write(0x1C, 0x0012_0003, ALL, 0)  # ignored outside init mode
    assert can.read(0x1C) == 0x001E_0001
    assert periph.btr_bitrate(0x001E_0001) == 1_000_000
    assert periph.btr_bitrate(0x001C_0008) == 250_000
    assert periph.btr_sample_point(0x001C_0008) == pytest.approx(0.875)


def program_filters(can, bank_regs, fm1r=0, fs1r=0, ffa1r=0, fa1r=1):
    can.write(0x200, 1, ALL, 0)  # FINIT
    can.write(0x204, fm1r, ALL, 0)
    can.write(0x20C, fs1r, ALL, 0)
    can.write(0x214, ffa1r, ALL, 0)
    for bank, (r1, r2) in enumerate(bank_regs):
        can.write(0x240 + 8 * bank, r1, ALL, 0)
        can.write(0x244 + 8 * bank, r2, ALL, 0)
    can.write(0x21C, fa1r, ALL, 0)
    can.write(0x200, 0, ALL, 0)


def test_can_filters_16_bit_list_and_mask():  # 24.7.4, 24.9.5
    can = normal_can()
    entry = lambda i: i << 5  # noqa: E731  (16-bit: STID at 15:5, RTR 4, IDE 3)
    program_filters(
        can,
        [
            (entry(0x000) | entry(0x080) << 16, entry(0x610) | entry(0x7E5) << 16),
            (entry(0x700) | entry(0x780) << 16, entry(0x700) | entry(0x780) << 16 | (1 << 4) << 16),
        ],
        fm1r=0b01,
        fa1r=0b11,
    )
    assert can.deliver(Frame(0x610, b"\x40")) == "fifo0"
    assert can.deliver(Frame(0x611, b"\x40")) == "filtered"
    assert can.deliver(Frame(0x701, b"\x05")) == "fifo0"  # mask 0x780 on 0x700
    assert can.deliver(Frame(0x181, b"\x05")) == "filtered"
    assert can.filtered == 2


def test_can_filters_32_bit_mask_fifo1_and_finit():  # 24.7.4
    can = normal_can()
    program_filters(can, [(0x123 << 21, 0x7FF << 21 | 0b110)], fs1r=1, ffa1r=1)
    assert can.accept(Frame(0x123, b"")) == (1, 0)
    assert can.accept(Frame(0x124, b"")) is None
    assert can.accept(Frame(0x123, b"", remote=True)) is None  # RTR bit compared
    can.write(0x200, 1, ALL, 0)
    assert can.accept(Frame(0x123, b"")) is None  # FINIT: no reception


def test_can_filter_registers_locked_while_active():  # 24.9.5
    can = normal_can()
    program_filters(can, [(1, 2)])
    can.write(0x240, 5, ALL, 0)
    assert can.read(0x240) == 1


def accept_all(can):
    program_filters(can, [(0, 0)], fs1r=1)


def test_can_fifo0_three_deep_overrun_and_release():  # 24.7.5, 24.9.4
    can = normal_can()
    accept_all(can)
    can.write(0x14, 0b1010, ALL, 0)  # FMPIE0, FOVIE0
    for i in range(3):
        assert can.deliver(Frame(0x100 + i, bytes([i]))) == "fifo0"
    assert can.read(0x0C) & 0b1011 == 0b1011  # FMP0 = 3, FULL0
    assert can.deliver(Frame(0x1FF, b"\xff")) == "overrun"
    assert can.read(0x0C) & 0x10 and can.overruns == 1
    assert periph.IRQ_CAN_RX0 in can.irqs()
    assert can.read(0x1B0) >> 21 == 0x100 and can.read(0x1B4) & 0xF == 1
    assert can.read(0x1B8) & 0xFF == 0
    can.write(0x0C, 1 << 5, ALL, 0)  # RFOM0
    assert can.read(0x0C) & 0b11 == 2 and can.read(0x1B0) >> 21 == 0x101
    can.write(0x0C, 1 << 5, ALL, 0)
    assert can.read(0x1B0) >> 21 == 0x1FF  # RFLM clear: the newest replaced the last
    can.write(0x0C, 1 << 4, ALL, 0)
    assert not can.read(0x0C) & 0x10


def test_can_fifo_locked_mode_keeps_the_old_frames():  # 24.7.5 RFLM
    can = normal_can()
    can.write(0x00, 0x48, ALL, 0)
    accept_all(can)
    for i in range(4):
        can.deliver(Frame(0x100 + i, b""))
    for want in (0x100, 0x101, 0x102):
        assert can.read(0x1B0) >> 21 == want
        can.write(0x0C, 1 << 5, ALL, 0)


def load(can, box, cob_id, data=b"\x01"):
    base = 0x180 + 0x10 * box
    can.write(base + 4, len(data), ALL, 0)
    can.write(base + 8, int.from_bytes(data[:4].ljust(4, b"\0"), "little"), ALL, 0)
    can.write(base, cob_id << 21 | 1, ALL, 0)  # TXRQ


def test_can_transmit_priority_by_identifier_and_completion():  # 24.7.1, 24.9.3
    sent = []
    can = normal_can(sent)
    can.bus_hold_until = None
    load(can, 0, 0x710)
    load(can, 1, 0x190)
    load(can, 2, 0x590)
    tsr = can.read(0x08)
    assert tsr >> 26 & 7 == 0  # no TME
    assert tsr >> 24 & 3 == 0 and tsr >> 29 & 7 == 0b001  # CODE/LOW: mailbox 0 least urgent
    can.bus_hold_until = 0
    now = 0
    while can.mailboxes[0][0] & 1 or can.mailboxes[1][0] & 1 or can.mailboxes[2][0] & 1:
        can.advance(now)
        now += 1000
    assert [f.can_id for f in sent] == [0x190, 0x590, 0x710]
    assert can.read(0x08) & 0x0303_0303 == 0x0003_0303  # RQCP and TXOK of all three
    can.write(0x14, 1, ALL, 0)
    assert periph.IRQ_CAN_TX in can.irqs()
    can.write(0x08, 0x0001_0101, ALL, 0)  # RQCP clears TXOK too
    assert can.read(0x08) & 0xFFFF == 0 and periph.IRQ_CAN_TX not in can.irqs()


def test_can_txfp_sends_in_request_order():  # 24.9.1 TXFP
    sent = []
    can = normal_can(sent)
    can.write(0x00, 0x44, ALL, 0)
    can.bus_hold_until = None
    load(can, 1, 0x700)
    load(can, 0, 0x100)
    can.bus_hold_until = 0
    for now in range(0, 10**6, 1000):
        can.advance(now)
    assert [f.can_id for f in sent] == [0x700, 0x100]


def test_can_abort_of_a_waiting_mailbox():  # 24.7.1 "Abort", 24.9.3 ABRQ
    can = normal_can()
    can.bus_hold_until = None
    load(can, 1, 0x590)
    can.write(0x08, 1 << 15, ALL, 0)
    tsr = can.read(0x08)
    assert tsr & (1 << 27) and tsr & (1 << 8) and not tsr & (1 << 9)  # TME1, RQCP1, no TXOK1
    assert not tsr & (1 << 15) and can.aborted == 1


def test_can_mailbox_is_write_protected_while_pending():  # 24.9.10
    can = normal_can()
    can.bus_hold_until = None
    load(can, 0, 0x123)
    can.write(0x180, 0x456 << 21, ALL, 0)
    assert can.read(0x180) >> 21 == 0x123


def test_can_error_states_and_erri():  # 24.7.6, 24.9.2, 24.9.6
    can = normal_can()
    can.write(0x14, 1 << 8 | 1 << 9 | 1 << 10 | 1 << 15, ALL, 0)
    can.inject(12, 0, 0)
    esr = can.read(0x18)
    assert esr & 0b111 == 0b001 and esr >> 16 & 0xFF == 96 and (esr >> 4) & 7 == 3
    assert can.read(0x04) & 0b100 and periph.IRQ_CAN_SCE in can.irqs()
    can.write(0x04, 0b100, ALL, 0)
    assert periph.IRQ_CAN_SCE not in can.irqs()
    can.inject(4, 0, 0)
    assert can.read(0x18) & 0b111 == 0b011  # error passive
    can.inject(16, 0, 0)
    assert can.read(0x18) & 0b111 == 0b111 and not can.online()  # bus-off


def test_can_bus_off_recovers_automatically_with_abom():  # 24.7.6 ABOM
    can = normal_can()
    can.inject(40, 0, 0)
    assert can.bus_off
    recovery = 128 * 11 * 72  # 128 x 11 bits at 1 Mbit/s in 72 MHz cycles
    can.advance(recovery - 100)
    assert can.bus_off
    can.advance(recovery + 1)
    assert not can.bus_off and can.tec == 0


def test_can_bus_off_without_abom_needs_init_mode():  # 24.7.6
    can = normal_can()
    can.write(0x00, 0x00, ALL, 0)  # ABOM off
    can.inject(40, 0, 0)
    can.advance(10**9)
    assert can.bus_off
    can.write(0x00, 0x01, ALL, 0)
    can.write(0x00, 0x00, ALL, 0)
    assert not can.bus_off


def test_can_wrong_bus_rate_keeps_the_node_off_the_bus():  # 24.7.7
    can = normal_can()
    accept_all(can)
    can.bus_bitrate = 500_000
    assert can.deliver(Frame(0x100, b"")) == "offline"
    can.bus_bitrate = 1_000_000
    assert can.deliver(Frame(0x100, b"")) == "fifo0"


def whole_flash(seed=1):
    """An unlocked FPEC over the whole 64 KiB main flash of zeros, as the board's."""
    f = Fpec(0x0800_0000, bytearray(64 * 1024), seed)
    f.write(0x04, periph.FLASH_KEY1, ALL, 0)
    f.write(0x04, periph.FLASH_KEY2, ALL, 0)
    return f


def test_fpec_erases_and_programs_a_code_page_of_the_whole_flash():  # PM0075 2.3.3, 2.3.4
    f = whole_flash()
    f.write(0x10, 0x02, ALL, 0)  # PER
    f.write(0x14, 0x0800_5123, ALL, 0)  # any address in page 20
    f.write(0x10, 0x42, ALL, 0)
    assert f.memory[0x5000:0x5400] == b"\xff" * 1024
    assert f.memory[:0x5000] == bytes(0x5000) and f.memory[0x5400:] == bytes(0xAC00)
    f.write(0x10, 0x01, ALL, 0)  # PG
    f.write_memory(0x5000, 2, 0x2002, 0)
    assert f.memory[0x5000:0x5002] == b"\x02\x20" and not f.read(0x0C, 0) & 0x04
    f.write_memory(0x5000, 2, 0x2001, 0)  # programmed already: PGERR
    f.write_memory(0x0100, 2, 0x1234, 0)  # a loader page, never erased: PGERR
    assert f.memory[0x5000:0x5002] == b"\x02\x20" and f.memory[0x100:0x102] == b"\0\0"
    assert f.read(0x0C, 0) & 0x04 and (f.erases, f.programs) == (1, 1)
    f.write(0x0C, 0x04, ALL, 0)
    f.write(0x10, 0x02, ALL, 0)
    f.write(0x14, 0x0801_0000, ALL, 0)  # past the flash: not a page of it
    f.write(0x10, 0x42, ALL, 0)
    assert f.read(0x0C, 0) & 0x10 and f.erases == 1, "WRPRTERR"


def test_fpec_power_cut_inside_an_application_page_erase_leaves_a_random_half():
    f = whole_flash(seed=11)
    f.arm(1, inside=True)
    f.write(0x10, 0x02, ALL, 0)
    f.write(0x14, 0x0800_3000, ALL, 0)  # the header's page
    f.write(0x10, 0x42, ALL, 1000)
    assert f.cut_requested and f.cuts == 1
    page = bytes(f.memory[0x3000:0x3400])
    halves = [page[i : i + 2] for i in range(0, 1024, 2)]
    assert set(halves) == {b"\x00\x00", b"\xff\xff"}
    assert 150 < halves.count(b"\xff\xff") < 362
    assert f.memory[:0x3000] == bytes(0x3000) and f.memory[0x3400:] == bytes(0xCC00)
    f.write(0x10, 0x42, ALL, 2000)  # the power is going: nothing more happens
    assert f.erases == 1 and f.operations == 1


def test_fpec_an_operation_that_begins_ends_the_one_before():
    """The CPU stalls until an operation ends before it can start the next: a cut armed
    before the next one finds the erase before it done, not half done."""
    f = whole_flash()
    f.arm(2, inside=False)
    f.write(0x10, 0x02, ALL, 0)
    f.write(0x14, 0x0800_4000, ALL, 0)
    f.write(0x10, 0x42, ALL, 1000)
    f.write(0x10, 0x01, ALL, 1001)  # PG, still within the erase's time
    f.write_memory(0x4000, 2, 0x1234, 1002)
    assert f.cut_requested and not f.cut(1003) and f.cuts == 0
    assert f.memory[0x4000:0x4400] == b"\xff" * 1024
