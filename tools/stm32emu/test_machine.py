"""The release image on the machine, without the server: it boots, sends its boot-up,
feeds the watchdog, and what it stores in the parameter page survives a power cycle
through the flash file. Needs the release ELF (`cargo xtask test` builds it first; the
path comes from HANDWHEEL_BOARD_ELF, else target/)."""

import os
from pathlib import Path

import pytest

from stm32emu import cortex, machine, periph

ROOT = Path(__file__).resolve().parents[2]
ELF = Path(
    os.environ.get(
        "HANDWHEEL_BOARD_ELF", ROOT / "target/thumbv7m-none-eabi/release/handwheel-firmware"
    )
)

pytestmark = pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")

SAVE = (0x65766173).to_bytes(4, "little")


def storage(m) -> slice:
    """Where the parameter pages are in the flash (the FPEC's memory, the flash file)."""
    start = m.memory.storage.origin - m.flash.origin
    return slice(start, start + m.memory.storage.length)


def sdo(m, request: bytes) -> bytes:
    """One SDO exchange with node 16 through the bus."""
    before = len(m.transmitted)
    m.deliver(periph.Frame(0x610, request))
    for _ in range(200):
        m.run_ms(1)
        for _, frame in m.transmitted[before:]:
            if frame.can_id == 0x590:
                return frame.data
    raise AssertionError("no SDO reply")


def test_boots_into_pre_operational_and_feeds_the_watchdog():
    m = machine.Machine(str(ELF))
    m.run_ms(700)
    frames = [(f.can_id, f.data) for _, f in m.transmitted]
    assert frames[0] == (0x710, b"\x00")
    assert m.iwdg.running and m.iwdg.feeds > 50
    assert m.stats.resets == ["0.0 ms PowerOn"]
    assert m.can.btr == 0x001E_0001 and round(m.can.bitrate()) == 1_000_000
    assert m.led_state["run"] is not None


def test_a_store_survives_a_power_cycle_through_the_flash_file(tmp_path):
    flash = tmp_path / "flash.bin"
    m = machine.Machine(str(ELF), str(flash))
    m.run_ms(50)
    assert sdo(m, bytes([0x2B, 0x17, 0x10, 0, 0xFA, 0, 0, 0]))[0] == 0x60  # 0x1017 = 250
    assert sdo(m, bytes([0x23, 0x10, 0x10, 1]) + SAVE)[0] == 0x60
    # The page is erased already: the record (154 bytes) is appended, no erase needed.
    assert m.fpec.erases == 0 and m.fpec.programs == 77
    assert flash.read_bytes()[storage(m)][:154] != b"\xff" * 154
    again = machine.Machine(str(ELF), str(flash))  # a new board from the same flash file
    again.run_ms(50)
    reply = sdo(again, bytes([0x40, 0x17, 0x10, 0, 0, 0, 0, 0]))
    assert int.from_bytes(reply[4:6], "little") == 250


def save_heartbeat(m, ms: int) -> None:
    assert sdo(m, bytes([0x2B, 0x17, 0x10, 0]) + ms.to_bytes(2, "little") + b"\0\0")[0] == 0x60
    assert sdo(m, bytes([0x23, 0x10, 0x10, 1]) + SAVE)[0] == 0x60


def test_a_power_cut_inside_the_erase_of_a_move_boots_the_moved_record(tmp_path):
    """Six saves fill the first page; the seventh is programmed to the second page, then
    the first is erased. Power fails in the middle of that erase (as the board's `power`
    command does while the CPU waits for the flash): the first page is left partly erased,
    the flash file says so at once, and the next boot finds the seventh value."""
    flash = tmp_path / "flash.bin"
    m = machine.Machine(str(ELF), str(flash), cut_seed=5)
    m.run_ms(50)
    for n in range(6):
        save_heartbeat(m, 200 + n)
    assert (m.fpec.erases, m.fpec.programs) == (0, 6 * 77)
    m.deliver(periph.Frame(0x610, bytes([0x2B, 0x17, 0x10, 0, 0x2C, 0x01, 0, 0])))  # 300
    m.run_ms(20)
    m.deliver(periph.Frame(0x610, bytes([0x23, 0x10, 0x10, 1]) + SAVE))
    while m.fpec.erases == 0:
        m.step()
    assert m.now < m.stall_until, "the CPU waits for the erase"
    assert m.power_cut(), "an operation was running"
    first = bytes(m.fpec.memory[storage(m)][:1024])
    assert first != b"\xff" * 1024 and b"\xff\xff" in first, "partly erased"
    assert flash.read_bytes() == bytes(m.fpec.memory)
    m.run_ms(50)
    assert m.stats.resets[-1].endswith("PowerOn") and len(m.stats.resets) == 2
    reply = sdo(m, bytes([0x40, 0x17, 0x10, 0, 0, 0, 0, 0]))
    assert int.from_bytes(reply[4:6], "little") == 300


def test_the_watchdog_resets_a_starved_loop_and_rcc_csr_says_so():
    m = machine.Machine(str(ELF))
    m.run_ms(20)
    m.storm_until = m.now + 2 * 72_000_000
    m.run_ms(600)
    assert m.stats.resets[-1].endswith("IndependentWatchdog")
    assert m.boot_cause == "IndependentWatchdog"
    m.run_ms(5)
    assert m.rcc.csr_flags == 0, "the firmware read the cause and cleared the flags (RMVF)"


def test_a_stall_that_holds_a_round_up_is_no_transmit_stall():
    """The board's `stall` (TIM2's vector kept pending: tests/interop/test_hostile.py's
    receive overrun) landing inside the round that takes the NMT start: that round goes on
    200 ms later, after the transmit interrupt drained the path, and queues EMCY 0x8110.
    What waits then waits since then, not since the round's tick: the next round finds it
    still on its way and raises no EMCY 0x8100 (transmit path blocked). The stall starts a
    slice further on in each run, so that some land inside the round."""
    dispatcher = cortex.IRQ_BASE + 29  # TIM3, RTIC's dispatcher of the `canopen` task
    held_up = 0
    for slices in range(12):
        m = machine.Machine(str(ELF))
        m.run_ms(2)
        m.deliver(periph.Frame(0x000, bytes([0x01, 0x10])))  # NMT start, node 16
        for _ in range(slices):
            m.step()
        held_up += dispatcher in m.nvic.active_stack
        mark = len(m.transmitted)
        m.storm_until = m.now + 200 * 72_000
        for _ in range(40):
            m.deliver(periph.Frame(0x77F, b"\x05"))  # accepted, more than the queues hold
        m.run_ms(300)
        emcy = [d[:2] for _, d in after(m, mark, 0x090)]
        assert emcy == [b"\x10\x81", b"\x00\x00"], f"stall {slices} slices in: {emcy}"
    assert held_up, "no stall landed inside a round"


def test_a_wheel_edge_raises_exti9_5():
    m = machine.Machine(str(ELF))
    m.run_ms(20)
    taken = m.core.exceptions_taken
    m.set_ab(1)
    m.run_ms(1)
    assert m.exti.pr == 0, "the handler cleared PR6/PR7"
    assert m.core.exceptions_taken > taken


def lss(m, *data: int) -> None:
    """An LSS request (CiA 305) from the host."""
    m.deliver(periph.Frame(0x7E5, bytes(data).ljust(8, b"\0")))


def after(m, mark: int, can_id: int) -> list[tuple[float, bytes]]:
    """(ms, data) of the node's frames with `can_id` since `mark` (an index of transmitted)."""
    return [(ms, f.data) for ms, f in m.transmitted[mark:] if f.can_id == can_id]


def switch_to_250_kbit(m) -> float:
    """LSS: configuration state, bit timing index 3 (250 kbit/s), activate with a 20 ms
    switch delay. Returns the emulated time (ms) of the activation."""
    mark = len(m.transmitted)
    lss(m, 0x04, 0x01)  # switch state global: configuration
    lss(m, 0x13, 0x00, 3)  # configure bit timing: CiA table, index 3
    m.run_ms(5)
    assert after(m, mark, 0x7E4) == [(pytest.approx(m.ms(), abs=5), bytes([0x13] + [0] * 7))]
    lss(m, 0x15, 20, 0)  # activate bit timing, switch delay 20 ms
    m.run_ms(1)
    return m.ms()


def test_a_bit_rate_switch_on_a_healthy_bus_is_quick_and_quiet():
    m = machine.Machine(str(ELF))
    m.run_ms(50)
    t = switch_to_250_kbit(m)
    m.run_ms(30)
    assert round(m.can.bitrate()) == 250_000 and m.can.mode == "normal"
    mark = len(m.transmitted)
    m.run_ms(1000)
    assert after(m, mark, 0x090) == [], "no EMCY: the node was never off the bus"
    assert [d for _, d in after(m, mark, 0x710)] == [b"\x7f"], "its heartbeat, at 250 kbit/s"
    assert not [c for c in m.leds if c.led == "err" and c.on and c.ms > t]
    assert m.stats.resets == ["0.0 ms PowerOn"]


def test_a_bit_rate_switch_on_a_dominant_bus_keeps_the_node_running_off_the_bus():
    """The bus is stuck dominant when the switch comes: the controller cannot synchronise.
    The CAN-side loop keeps running (it feeds the watchdog, SysTick ticks), the node is off
    the bus with the ERR LED on, and rejoins at the new rate by itself once the bus is
    free, with EMCY 0x8140."""
    m = machine.Machine(str(ELF))
    m.run_ms(50)
    t = switch_to_250_kbit(m)
    m.can.bus_dominant_until = m.now + 1000 * 72_000  # 1 s
    feeds = m.iwdg.feeds
    m.run_ms(900)
    assert m.stats.resets == ["0.0 ms PowerOn"], "no watchdog reset"
    assert m.iwdg.feeds - feeds > 50, "the loop kept running and feeding the watchdog"
    assert m.can.mode == "init" and not m.can.online(), "waiting to synchronise"
    assert round(m.can.bitrate()) == 250_000
    err = [c for c in m.leds if c.led == "err" and c.ms > t]
    assert err and err[0].on and err[0].ms < t + 20 + 50 + 60, f"ERR on when off the bus: {err}"
    mark = len(m.transmitted)
    m.run_ms(300)  # the bus is free from t + 1000 ms
    assert m.can.mode == "normal" and m.stats.resets == ["0.0 ms PowerOn"]
    emcy = after(m, mark, 0x090)
    assert [d[:2] for _, d in emcy] == [b"\x40\x81", b"\x00\x00"], f"0x8140, then reset: {emcy}"
    assert emcy[0][0] < t + 1000 + 20, "within a poll of the bus's release"
    assert m.led_state["err"] is False


def test_time_jumps_from_event_to_event_after_a_timed_hold():
    """A timed hold (`hold <ms>`) that has expired is no event: the machine still jumps
    from event to event (an idle CPU to the next SysTick) instead of a cycle per step, and
    a wheel turn after it is done in its 25 ms."""
    m = machine.Machine(str(ELF))
    m.run_ms(50)
    m.can.bus_hold_until = m.now + 5 * 72_000
    m.run_ms(10)
    assert m.next_event() - m.now > 1000, "the next event is a SysTick or later, not now + 1"
    done = []
    m.turn(1, done=lambda: done.append(m.ms()))
    start = m.ms()
    for _ in range(3000):  # about one step per SysTick when idle; 30 ms with the turn's work
        m.step()
        if done:
            break
    assert done and done[0] - start == pytest.approx(27.4, abs=0.1), f"{m.ms() - start:.3f} ms"


def test_the_memory_map_is_the_linker_scripts():  # image.py, RM0008 30.1
    m = machine.Machine(str(ELF))
    memory = m.image.memory
    assert m.fpec.base == 0x0800_0000 and len(m.fpec.memory) == 64 * 1024, "the whole flash"
    assert memory.storage.length == 2048, "two parameter pages"
    size = int.from_bytes(m.uc.mem_read(machine.FLASH_SIZE_REGISTER, 2), "little")
    assert size == (memory.flash_end - memory.flash_base) // 1024 == 64
    start, data = m.image.segments[0]
    assert bytes(m.uc.mem_read(start, 16)) == data[:16]


def test_unmodelled_registers_read_back_with_their_byte_lanes():
    m = machine.Machine(str(ELF))
    usart1 = 0x4001_3800 - machine.PERIPH_BASE  # no model: plain memory
    m._periph_write(None, usart1, 4, 0x1234_5678, None)
    m._periph_write(None, usart1 + 2, 1, 0xAB, None)
    assert m._periph_read(None, usart1, 4, None) == 0x12AB_5678
    assert m._periph_read(None, usart1 + 1, 2, None) == 0xAB56


def test_bit_band_alias_reaches_the_peripheral_bit():  # PM0056 2.2.5
    m = machine.Machine(str(ELF))
    apb1enr = periph.RCC_BASE + 0x1C
    alias = (apb1enr - machine.PERIPH_BASE) * 32 + 25 * 4  # CANEN
    m._bb_write(None, alias, 4, 1, None)
    assert m._read_word(apb1enr) == 1 << 25 and m._bb_read(None, alias, 4, None) == 1
    m._bb_write(None, alias, 4, 0, None)
    assert m._read_word(apb1enr) == 0


def test_precise_mode_runs_the_image_as_the_board_does():
    """The same boot in precise mode (one cycle per instruction, exceptions taken at the
    instruction boundary): boot-up, watchdog, a wheel edge; time is what ran."""
    m = machine.Machine(str(ELF))
    m.core.precise()
    m.run_ms(300)
    assert [(f.can_id, f.data) for _, f in m.transmitted][:1] == [(0x710, b"\x00")]
    assert m.iwdg.running and m.iwdg.feeds > 20 and m.stats.resets == ["0.0 ms PowerOn"]
    taken = m.core.exceptions_taken
    cycles = m.core.cycles
    m.set_ab(1)
    m.run_ms(1)
    assert m.exti.pr == 0 and m.core.exceptions_taken > taken
    assert 0 < m.core.cycles - cycles < 72_000, "busy only for what its instructions took"


# -- the loader and the application, as a flashed board (docs/FIRMWARE-UPDATE.md) ------------

LOADER_ELF = Path(
    os.environ.get(
        "HANDWHEEL_LOADER_ELF", ROOT / "target/thumbv7m-none-eabi/release/handwheel-loader"
    )
)
with_loader = pytest.mark.skipif(not LOADER_ELF.exists(), reason=f"no loader image at {LOADER_ELF}")


HANDOFF = 0x2000_4FF8
TRIAL_TAG = 0x5452_4C00  # canopen_loader::boot: "TRL" and the count of unconfirmed starts
RESCUE = bytes([0x2F, 0x51, 0x1F, 0x01, 0, 0, 0, 0])  # 0x1F51:1 = 0, the window's request


def handoff(m) -> tuple[int, int]:
    words = bytes(m.uc.mem_read(HANDOFF, 8))
    return int.from_bytes(words[:4], "little"), int.from_bytes(words[4:], "little")


@with_loader
def test_the_loader_starts_the_application_it_was_flashed_with():
    """Power-on: the loader finds the application valid, listens for 100 ms without a frame
    of its own, counts the start and jumps (VTOR at its vector table) with the watchdog
    running and bxCAN, GPIOB and AFIO back in their reset state: the first frame is the
    application's boot-up, whose acknowledgement confirms the start (the count cleared)."""
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    assert m.running() == "loader" and m.nvic.vtor == 0
    m.run_ms(100)
    assert m.running() == "loader" and not m.transmitted, "listening, silent"
    m.run_ms(200)
    assert m.running() == "application" and m.nvic.vtor == m.app.table_address
    assert [(f.can_id, f.data) for _, f in m.transmitted][:1] == [(0x710, b"\x00")]
    assert m.stats.resets == ["0.0 ms PowerOn"] and not m.core.locked_up
    assert handoff(m) == (0, 0), "confirmed"


@with_loader
def test_the_window_costs_the_boot_up_100_ms():
    """The boot-up comes 100 ms (the window) after the loader's check of the image, about
    35 ms of CRC: docs/FIRMWARE-UPDATE.md states the figures."""
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    m.run_ms(300)
    boot_up = next(ms for ms, f in m.transmitted if f.can_id == 0x710)
    assert 130 <= boot_up <= 145, boot_up


@with_loader
def test_a_request_in_the_window_keeps_the_loader():
    """0x1F51:1 = 0 to the node inside the window: the loader boots up, answers it and
    stays, the application never started (VTOR 0, no reset); 0x1F57 reads 0 (the
    application is valid)."""
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    m.run_ms(80)
    reply = sdo(m, RESCUE)
    assert reply[:4] == bytes([0x60, 0x51, 0x1F, 0x01])
    assert [(f.can_id, f.data) for _, f in m.transmitted][:1] == [(0x710, b"\x00")]
    m.run_ms(300)
    assert m.running() == "loader" and m.nvic.vtor == 0
    assert m.stats.resets == ["0.0 ms PowerOn"]
    reply = sdo(m, bytes([0x40, 0x57, 0x1F, 1, 0, 0, 0, 0]))
    assert reply[0] == 0x43 and reply[4:] == bytes(4)


@with_loader
def test_an_application_that_never_confirms_is_started_three_times():
    """The application's boot-up is never acknowledged (the bus at another rate): the count
    stays, and it runs on; each reset counts one more start; the third keeps the loader,
    with 0x1F57 code 64."""
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    m.can.bus_bitrate = 500_000  # the node's 1 Mbit/s frames reach nobody
    m.run_ms(300)
    assert m.running() == "application"
    assert handoff(m) == (TRIAL_TAG | 1, ~(TRIAL_TAG | 1) & 0xFFFF_FFFF)
    for starts in (2, 3):
        m.pin_reset()
        m.run_ms(300)
        assert m.running() == "application" and handoff(m)[0] == TRIAL_TAG | starts
    m.pin_reset()
    m.run_ms(300)
    assert m.running() == "loader" and handoff(m)[0] == TRIAL_TAG | 3
    m.can.bus_bitrate = None
    reply = sdo(m, bytes([0x40, 0x57, 0x1F, 1, 0, 0, 0, 0]))
    assert reply[0] == 0x43 and int.from_bytes(reply[4:], "little") == 64 << 1
    m.power_on()
    m.run_ms(300)
    assert m.running() == "application" and handoff(m) == (0, 0), "a power-on: a fresh trial"


def test_a_peripheral_reset_bit_resets_the_peripheral():
    """RCC_APB1RSTR's CANRST and APB2RSTR's IOPBRST and AFIORST put bxCAN, GPIOB and AFIO
    back to their reset values (RM0008 7.3.4, 7.3.5)."""
    m = machine.Machine(str(ELF))
    m.run_ms(50)
    assert m.can.mode == "normal" and m.gpio["B"].crh != 0x4444_4444 and m.afio.regs[1]
    m._write_word(periph.RCC_BASE + 0x10, 1 << 25, 0xFFFF_FFFF)
    m._write_word(periph.RCC_BASE + 0x0C, 1 << 3 | 1, 0xFFFF_FFFF)
    assert m.can.mode == "sleep" and m.can.btr == 0x0123_0000
    assert m.gpio["B"].crh == 0x4444_4444 and m.afio.regs == [0] * 7


@with_loader
def test_without_the_validity_mark_the_loader_stays_and_answers():
    """The header's mark erased (as after "clear"): the loader stays, sends its boot-up and
    answers SDO; 0x1000 says it is the loader."""
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    header = m.memory.header.origin - m.flash.origin
    m.write_flash(header, b"\0\0\0\0")
    m.power_on()
    m.run_ms(300)
    assert m.running() == "loader" and not m.core.locked_up
    assert [(f.can_id, f.data) for _, f in m.transmitted][:1] == [(0x710, b"\x00")]
    reply = sdo(m, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    assert reply[0] == 0x43 and int.from_bytes(reply[4:8], "little") == 0x544F_4F42


def bad_images():
    """tools/rig/bad_images.py, by its path: the rig package itself needs python-can."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bad_images", ROOT / "tools/rig/bad_images.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@with_loader
@pytest.mark.parametrize("kind", ["hang", "fault", "lockup", "silent", "wrong-bit-rate"])
def test_each_broken_image_does_what_its_name_says(kind):
    """The images of tools/rig/bad_images.py behind the real loader: the loader takes each
    (header, vector table, CRC genuine); `hang`, `fault` and `lockup` are reset by the
    watchdog until the loader stays after the third start; `silent` and `wrong-bit-rate` run
    on, never reset, never heard, their first start never confirmed."""
    made = bad_images()
    m = machine.Machine(str(ELF), loader=str(LOADER_ELF))
    slot = m.memory.header.origin - m.flash.origin
    length = int.from_bytes(m.fpec.memory[slot + 0x14 : slot + 0x18], "little")
    release = bytes(m.fpec.memory[slot : slot + 512 + length])
    m.write_flash(slot, made.make(kind, release))
    m.can.bus_bitrate = 1_000_000  # the node's rate: another one stays off the bus
    m.power_on()
    powered = len(m.stats.resets)
    m.run_ms(7_000 if kind in ("hang", "fault", "lockup") else 3_000)
    boot_ups = [ms for ms, f in m.transmitted if f.can_id == 0x710 and f.data == b"\x00"]
    if kind in ("hang", "fault", "lockup"):
        assert m.running() == "loader", m.stats.resets
        assert [r.split()[-1] for r in m.stats.resets[powered:]] == ["IndependentWatchdog"] * 3
        assert len(boot_ups) == 1 and boot_ups[0] > 6_000, "the loader's, after 3 starts"
        assert handoff(m)[0] == TRIAL_TAG | 3
        assert (m.core.faults > 0) == (kind != "hang")
    else:
        assert m.running() == "application" and len(m.stats.resets) == powered
        assert not m.transmitted, "nothing reaches the bus"
        assert handoff(m)[0] == TRIAL_TAG | 1, "never confirmed"
        assert m.iwdg.feeds > 100
