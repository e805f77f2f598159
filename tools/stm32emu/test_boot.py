"""The board as a flashed board is (docs/FIRMWARE-UPDATE.md): the loader's and the
application's images flashed as a probe does, the FPEC over the whole flash with code
rewritten by the CPU executed anew, the boot from the loader through VTOR into the
application, and the HANDOFF words across a system reset and a power-on. On tiny
hand-assembled Thumb programs (as test_cortex.py), no firmware build needed."""

import pytest

from stm32emu import cortex, machine, periph
from stm32emu.image import APPLICATION, LOADER, Image, MemoryMap

# The contract's map, written with the expressions a linker script may use.
SCRIPT = """
MEMORY
{
  LOADER  : ORIGIN = 0x08000000, LENGTH = 12K
  HEADER  : ORIGIN = ORIGIN(LOADER) + LENGTH(LOADER), LENGTH = 256
  FLASH   : ORIGIN = 0x08003100, LENGTH = 50K - 256
  STORAGE : ORIGIN = 0x0800F800, LENGTH = 2K
  RAM     : ORIGIN = 0x20000000, LENGTH = 20K - 8
  HANDOFF : ORIGIN = 0x20004FF8, LENGTH = 8
}
"""
MEMORY = MemoryMap.parse(SCRIPT)
FLASH = 0x0800_0000
APP_TABLE = 0x0800_3100
HANDOFF = 0x2000_4FF8
REQUEST = 0x4C4F_4144  # "LOAD": stay in the loader
FPEC = periph.FLASH_IF_BASE
ICSR, AIRCR, VTOR = cortex.SCB_ICSR, cortex.SCB_AIRCR, cortex.SCB_VTOR
B_SELF = 0xE7FE
YIELD = 0xBF10
B_BACK_2 = 0xE7FD  # b to the half-word before
BX_LR = 0x4770


class Asm:
    """A few Thumb instructions (ARMv7-M ARM A7.7) at `base`, literals after the code."""

    def __init__(self, base: int) -> None:
        self.base = base
        self.items: list = []  # half-words, or ("ldr", rt, value) / ("b", cond, label)
        self.labels: dict[str, int] = {}

    def here(self) -> int:
        return self.base + 2 * len(self.items)

    def label(self, name: str) -> None:
        self.labels[name] = self.here()

    def op(self, *halfwords: int) -> None:
        self.items.extend(halfwords)

    def ldr(self, rt: int, value: int) -> None:  # LDR Rt, =value (literal, T1)
        self.items.append(("ldr", rt, value))

    def str(self, rt: int, rn: int, offset: int = 0) -> None:  # STR Rt, [Rn, #offset]
        self.op(0x6000 | offset // 4 << 6 | rn << 3 | rt)

    def ldr_imm(self, rt: int, rn: int, offset: int = 0) -> None:  # LDR Rt, [Rn, #offset]
        self.op(0x6800 | offset // 4 << 6 | rn << 3 | rt)

    def strh(self, rt: int, rn: int, offset: int = 0) -> None:  # STRH Rt, [Rn, #offset]
        self.op(0x8000 | offset // 2 << 6 | rn << 3 | rt)

    def movs(self, rd: int, imm: int) -> None:
        self.op(0x2000 | rd << 8 | imm)

    def adds(self, rd: int, imm: int) -> None:
        self.op(0x3000 | rd << 8 | imm)

    def mov(self, rd: int, rm: int) -> None:
        self.op(0x4600 | (rd & 8) << 4 | rm << 3 | rd & 7)

    def cmp(self, rn: int, rm: int) -> None:
        self.op(0x4280 | rm << 3 | rn)

    def blx(self, rm: int) -> None:
        self.op(0x4780 | rm << 3)

    def bx(self, rm: int) -> None:
        self.op(0x4700 | rm << 3)

    def msr_msp(self, rn: int) -> None:  # MSR MSP, Rn (T1, SYSm 8)
        self.op(0xF380 | rn, 0x8808)

    def beq(self, label: str) -> None:
        self.items.append(("b", 0, label))

    def assemble(self) -> bytes:
        end = self.here()
        pool = end + (end & 2)  # word-aligned
        literals: list[int] = []
        out = []
        for i, item in enumerate(self.items):
            at = self.base + 2 * i
            if isinstance(item, int):
                out.append(item)
            elif item[0] == "ldr":
                _, rt, value = item
                if value not in literals:
                    literals.append(value)
                offset = pool + 4 * literals.index(value) - ((at + 4) & ~3)
                assert 0 <= offset < 1024
                out.append(0x4800 | rt << 8 | offset // 4)
            else:
                _, cond, label = item
                offset = (self.labels[label] - (at + 4)) // 2
                assert -128 <= offset < 128
                out.append(0xD000 | cond << 8 | offset & 0xFF)
        code = b"".join(h.to_bytes(2, "little") for h in out)
        code += b"\0" * (pool - end)
        return code + b"".join(v.to_bytes(4, "little") for v in literals)


def image(table: int, sp: int, code: Asm, vectors: dict[int, int] | None = None) -> Image:
    """An image with its vector table at `table` (SP, reset = the code's start, and
    `vectors`) and the code after it."""
    words = [sp, code.base | 1] + [0] * 14
    for exception, address in (vectors or {}).items():
        words[exception] = address | 1
    data = b"".join(w.to_bytes(4, "little") for w in words)
    data = data.ljust(code.base - table, b"\0") + code.assemble()
    return Image.from_segments([(table, data)], table, MEMORY)


def loader_booting_the_app() -> Image:
    """The contract's boot decision without the CRC: HANDOFF's request -> stay (r7 = 1),
    else VTOR := the application's table, MSP := its SP, jump to its reset vector."""
    a = Asm(FLASH + 0x40)
    a.ldr(0, HANDOFF)
    a.ldr_imm(1, 0)
    a.ldr(2, REQUEST)
    a.cmp(1, 2)
    a.beq("stay")
    a.ldr(0, VTOR)
    a.ldr(1, APP_TABLE)
    a.str(1, 0)
    a.ldr_imm(2, 1, 0)
    a.msr_msp(2)
    a.ldr_imm(3, 1, 4)
    a.bx(3)
    a.label("stay")
    a.adds(7, 1)
    a.op(B_SELF)
    return image(FLASH, 0x2000_4000, a)


def app_asking_for_the_loader() -> Image:
    """Pends SysTick (taken through VTOR: the loader's table has no SysTick vector); its
    handler writes the HANDOFF request and resets the chip (SYSRESETREQ)."""
    a = Asm(APP_TABLE + 0x40)
    a.ldr(0, ICSR)
    a.ldr(1, 1 << 26)  # PENDSTSET
    a.str(1, 0)
    a.op(B_SELF)
    a.label("systick")
    a.adds(6, 1)
    a.ldr(0, HANDOFF)
    a.ldr(1, REQUEST)
    a.str(1, 0)
    a.ldr(1, ~REQUEST & 0xFFFF_FFFF)
    a.str(1, 0, 4)
    a.ldr(0, AIRCR)
    a.ldr(1, 0x05FA_0004)
    a.str(1, 0)
    a.op(B_SELF)
    a.assemble()
    return image(APP_TABLE, 0x2000_2000, a, {15: a.labels["systick"]})


def reg(m, r: int) -> int:
    return m.uc.reg_read(getattr(cortex.arm, f"UC_ARM_REG_R{r}"))


def handoff(m) -> bytes:
    return bytes(m.uc.mem_read(HANDOFF, 8))


def test_the_map_with_the_loader_regions():  # docs/FIRMWARE-UPDATE.md "Memory map"
    assert (MEMORY.loader.origin, MEMORY.loader.end) == (0x0800_0000, 0x0800_3000)
    assert (MEMORY.header.origin, MEMORY.header.length) == (0x0800_3000, 256)
    assert (MEMORY.flash.origin, MEMORY.flash.end) == (0x0800_3100, 0x0800_F800)
    assert (MEMORY.slot.origin, MEMORY.slot.length) == (0x0800_3000, 50 * 1024)
    assert (MEMORY.flash_base, MEMORY.flash_end) == (0x0800_0000, 0x0801_0000)
    assert (MEMORY.ram.end, MEMORY.sram.end) == (0x2000_4FF8, 0x2000_5000)
    with pytest.raises(ValueError, match="HEADER region does not follow LOADER"):
        MemoryMap.parse(SCRIPT.replace("ORIGIN(LOADER) + LENGTH(LOADER)", "0x08002C00"))
    with pytest.raises(ValueError, match="HANDOFF"):
        MemoryMap.parse(SCRIPT.replace("0x20004FF8", "0x20004FF0"))
    with pytest.raises(ValueError, match="names no region"):
        MemoryMap.parse(SCRIPT.replace("ORIGIN(LOADER)", "ORIGIN(BOOT)"))


def test_each_image_is_checked_against_its_region():
    loader, app = loader_booting_the_app(), app_asking_for_the_loader()
    assert (loader.kind, loader.region.name) == (LOADER, "LOADER")
    assert (app.kind, app.region.name) == (APPLICATION, "SLOT")
    assert loader.pages() == [FLASH] and app.pages() == [0x0800_3000]
    table = loader.segments[0][1]
    with pytest.raises(ValueError, match="outside LOADER"):
        Image.from_segments([(FLASH, table), (0x0800_3000, b"\0" * 4)], FLASH, MEMORY)
    with pytest.raises(ValueError, match="not at FLASH's or LOADER's origin"):
        Image.from_segments([(0x0800_0400, table)], 0x0800_0400, MEMORY)
    with pytest.raises(ValueError, match="initial SP"):
        Image.from_segments([(FLASH, b"\0" * 4 + table[4:])], FLASH, MEMORY)
    with pytest.raises(ValueError, match="not the loader"):
        machine.Machine(None, loader=app)


def test_the_loader_jumps_through_vtor_and_handoff_survives_a_system_reset():
    """Power-on: the loader finds no request, jumps into the application (VTOR, MSP); the
    application's SysTick handler (its own table's vector) asks for the loader and resets
    the chip: VTOR is 0 again, the CPU boots the loader, which finds the request (SRAM
    kept). A power-on clears it: the loader starts the application again."""
    m = machine.Machine(app_asking_for_the_loader(), loader=loader_booting_the_app())
    assert m.running() == LOADER and m.nvic.vtor == 0
    m.run_ms(1)
    assert [r.split()[-1] for r in m.stats.resets] == ["PowerOn", "Software"]
    assert m.running() == LOADER and reg(m, 7) == 1, "stays in the loader"
    assert m.nvic.vtor == 0 and not m.core.locked_up
    assert handoff(m) == REQUEST.to_bytes(4, "little") + (~REQUEST & 0xFFFF_FFFF).to_bytes(
        4, "little"
    )
    m.power_on()
    assert handoff(m) == bytes(8)
    m.run_ms(1)
    assert [r.split()[-1] for r in m.stats.resets][-2:] == ["PowerOn", "Software"]
    assert m.core.exceptions_taken == 2, "the application's SysTick, once a boot"


def test_an_application_without_a_loader_starts_as_the_loader_would_start_it():
    m = machine.Machine(app_asking_for_the_loader())
    assert m.running() == APPLICATION and m.nvic.vtor == APP_TABLE
    assert m.uc.reg_read(cortex.arm.UC_ARM_REG_SP) == 0x2000_2000
    m.run_ms(1)
    assert m.stats.resets[-1].endswith("Software") and m.running() == APPLICATION


F = 0x0800_5000  # a function in the application's slot


def unlock_fpec(a: Asm) -> None:
    """r6 := the FPEC's base; the key sequence into FLASH_KEYR (PM0075 2.3.1)."""
    a.ldr(6, FPEC)
    a.ldr(1, periph.FLASH_KEY1)
    a.str(1, 6, 0x04)
    a.ldr(1, periph.FLASH_KEY2)
    a.str(1, 6, 0x04)


def erase_page_of_f(a: Asm) -> None:
    """Starts the erase of F's page (r6 the FPEC's base; r7 := F): PER, AR, PER | STRT."""
    a.movs(1, 0x02)  # CR.PER
    a.str(1, 6, 0x10)
    a.ldr(7, F)
    a.str(7, 6, 0x14)  # AR
    a.movs(1, 0x42)  # PER | STRT
    a.str(1, 6, 0x10)


def loader_rewriting_f() -> Image:
    """Calls F (r5 := its result), erases F's page, programs `movs r0, #2; bx lr` there,
    stores a half-word with PG off (PGERR: nothing written), calls F again (r0)."""
    a = Asm(FLASH + 0x40)
    unlock_fpec(a)
    a.ldr(4, F | 1)
    a.blx(4)
    a.mov(5, 0)
    erase_page_of_f(a)
    a.movs(1, 0x01)  # PG
    a.str(1, 6, 0x10)
    a.ldr(1, 0x2002)  # movs r0, #2
    a.strh(1, 7, 0)
    a.ldr(1, BX_LR)
    a.strh(1, 7, 2)
    a.movs(1, 0)
    a.str(1, 6, 0x10)
    a.ldr(1, 0x1234)
    a.strh(1, 7, 4)  # PG off: PGERR
    a.blx(4)
    a.op(B_SELF)
    return image(FLASH, 0x2000_4000, a)


def flash_with_f(tmp_path, page_fill: bytes = b"\xa5"):
    """A whole-flash file: garbage in the loader's first pages, F (`movs r0, #1; bx lr`) in
    a page of `page_fill`, a parameter page."""
    content = bytearray(b"\xff" * 0x10000)
    content[0:0x1000] = b"\x5a" * 0x1000  # pages 0-3: an older loader
    content[F - FLASH : F - FLASH + 0x400] = page_fill * 0x400
    content[F - FLASH : F - FLASH + 4] = bytes.fromhex("0120 7047")
    content[0xF800:0xF804] = b"HWP2"
    path = tmp_path / "flash.bin"
    path.write_bytes(bytes(content))
    return path, content


def test_loading_an_image_erases_and_writes_only_the_pages_it_covers(tmp_path):
    path, content = flash_with_f(tmp_path)
    loader = loader_rewriting_f()
    m = machine.Machine(None, str(path), loader=loader)
    size = len(loader.segments[0][1])
    flash = bytes(m.fpec.memory)
    assert flash[:size] == loader.segments[0][1]
    assert flash[size:0x400] == b"\xff" * (0x400 - size), "the rest of its page erased"
    assert flash[0x400:0x1000] == content[0x400:0x1000], "pages it does not cover kept"
    assert flash[0x1000:] == content[0x1000:], "the slot and the parameter pages kept"
    assert path.read_bytes() == flash and bytes(m.uc.mem_read(FLASH, 0x10000)) == flash
    assert m.fpec.operations == 0, "a probe's work, not the FPEC's"


def test_a_parameter_page_file_of_before_is_read_as_the_parameter_pages(tmp_path):
    path = tmp_path / "flash.bin"
    path.write_bytes(b"HWP2" + b"\x11" * 1020)  # one page, as the first such files were
    m = machine.Machine(None, str(path), loader=loader_booting_the_app())
    assert bytes(m.fpec.memory[0xF800:0xFC00]) == b"HWP2" + b"\x11" * 1020
    assert bytes(m.fpec.memory[0xFC00:]) == b"\xff" * 1024
    assert bytes(m.fpec.memory[0x1000:0xF800]) == b"\xff" * 0xE800
    assert path.read_bytes() == bytes(m.fpec.memory), "the whole flash from now on"
    with pytest.raises(ValueError, match="neither the whole flash"):
        path.write_bytes(bytes(4096))
        machine.Machine(None, str(path), loader=loader_booting_the_app())


def test_code_the_cpu_erases_and_programs_runs_anew_and_persists(tmp_path):
    """Unicorn would run F's old translation: the board drops it with every change. The
    raw store of a refused program never lands (what the CPU reads is the FPEC's)."""
    path, _ = flash_with_f(tmp_path)
    m = machine.Machine(None, str(path), loader=loader_rewriting_f())
    m.run_ms(30)  # the erase stalls the CPU for 20 ms
    assert (reg(m, 5), reg(m, 0)) == (1, 2), "F before and after"
    assert (m.fpec.erases, m.fpec.programs, m.fpec.operations) == (1, 2, 3)
    assert m.fpec.read(0x0C, m.now) & 0x04, "PGERR from the store with PG off"
    page = bytes.fromhex("0220 7047") + b"\xff" * 1020
    assert bytes(m.uc.mem_read(F, 0x400)) == page == bytes(m.fpec.memory[0x5000:0x5400])
    assert path.read_bytes()[0x5000:0x5400] == page
    # A new board from the file (the loader flashed again) finds F rewritten.
    again = machine.Machine(None, str(path), loader=loader_rewriting_f())
    assert bytes(again.uc.mem_read(F, 4)) == bytes.fromhex("0220 7047")


def test_a_cut_inside_the_erase_of_a_code_page_leaves_a_random_half(tmp_path):
    """`arm(1, inside)`: the power fails inside the erase of F's page (the first operation):
    some half-words erased, the rest as they were, in the FPEC, the CPU's view and the
    file; nothing else changed."""
    path, content = flash_with_f(tmp_path, page_fill=b"\x00")
    m = machine.Machine(None, str(path), cut_seed=3, loader=loader_rewriting_f())
    before = bytes(m.fpec.memory)
    m.fpec.arm(1, inside=True)
    while m.fpec.cuts == 0:
        m.step()
    assert m.stats.resets[-1].endswith("PowerOn") and len(m.stats.resets) == 2
    page = bytes(m.fpec.memory[0x5000:0x5400])
    halves = {page[i : i + 2] for i in range(0, 0x400, 2)}
    old = {b"\x00\x00", bytes.fromhex("0120"), bytes.fromhex("7047")}
    assert halves <= old | {b"\xff\xff"}, "each half-word erased or as it was"
    assert b"\xff\xff" in halves and b"\x00\x00" in halves
    assert 100 < page.count(b"\xff") < 924, "about half erased"
    flash = bytes(m.fpec.memory)
    assert flash[:0x5000] == before[:0x5000] and flash[0x5400:] == before[0x5400:]
    assert bytes(m.uc.mem_read(FLASH, 0x10000)) == flash == path.read_bytes()
    assert (m.fpec.erases, m.fpec.programs) == (1, 0)


def test_a_cut_before_a_program_of_a_code_page_leaves_it_erased(tmp_path):
    """`arm(2, before)`: the erase done, the power fails before the first program."""
    path, _ = flash_with_f(tmp_path)
    m = machine.Machine(None, str(path), loader=loader_rewriting_f())
    m.fpec.arm(2, inside=False)
    while len(m.stats.resets) < 2:
        m.step()
    assert m.fpec.cuts == 0 and (m.fpec.erases, m.fpec.programs) == (1, 0)
    assert path.read_bytes()[0x5000:0x5400] == b"\xff" * 0x400


def loader_erasing_then_idle() -> Image:
    """Starts the erase of F's page, then waits in a YIELD loop (as the resident loader's
    loop does when nothing came in): the YIELD lands in the slice that started the erase."""
    a = Asm(FLASH + 0x40)
    unlock_fpec(a)
    erase_page_of_f(a)
    a.op(YIELD, B_BACK_2)
    return image(FLASH, 0x2000_4000, a)


def test_a_yield_right_after_a_flash_operation_waits_for_it():
    """The erase stalls the CPU for its 20 ms although the slice ended idle (YIELD): idle
    time never skips an operation's stall."""
    m = machine.Machine(None, None, loader=loader_erasing_then_idle())
    while m.fpec.erases == 0:
        assert not m.step(idle_jump=False), "idle before the erase ran"
    assert m.stall_until - m.now >= 20 * cortex.CORE_HZ // 1000 - machine.SLICE


@pytest.mark.parametrize("inside", [False, True])
def test_a_cut_armed_at_an_operation_right_before_a_yield_happens(tmp_path, inside):
    """The cut at the erase comes although the CPU yields right after it (before the fix,
    the idle slice dropped it: the page was erased whole and the power never failed)."""
    path, _ = flash_with_f(tmp_path)
    m = machine.Machine(None, str(path), loader=loader_erasing_then_idle())
    m.fpec.arm(1, inside=inside)
    for _ in range(1000):
        if len(m.stats.resets) == 2:
            break
        m.step(idle_jump=False)
    assert m.stats.resets[-1].endswith("PowerOn") and len(m.stats.resets) == 2
    assert m.fpec.cuts == int(inside)


def spinning(table: int, sp: int, poll: int | None = None) -> Image:
    """Pure computation forever (a branch to itself), or with `poll` a loop reading that
    peripheral register."""
    a = Asm(table + 0x40)
    if poll is not None:
        a.ldr(0, poll)
        a.label("loop")
        a.ldr_imm(1, 0)
        a.op(0xE000 | (a.labels["loop"] - (a.here() + 4)) // 2 & 0x7FF)  # B loop
    else:
        a.op(B_SELF)
    return image(table, sp, a)


def slices_in_5_ms(m) -> list[int]:
    lengths = []
    end = m.now + 5 * cortex.CORE_HZ // 1000
    while m.now < end:
        before = m.now
        m.step()
        lengths.append(m.now - before)
    return lengths


def test_the_loaders_pure_computation_runs_in_growing_slices():
    """A stretch of the loader's that touches no peripheral (its CRC over the slot) runs in
    slices doubling up to LONG_SLICE; a loop polling a register, or the application, keeps
    SLICE (its interrupts are taken at the end of a slice)."""
    computing = slices_in_5_ms(machine.Machine(None, None, loader=spinning(FLASH, 0x2000_4000)))
    doubling = [machine.SLICE << n for n in range(6)]
    assert computing[:6] == doubling and set(computing[6:-1]) == {machine.LONG_SLICE}
    polling = machine.Machine(None, None, loader=spinning(FLASH, 0x2000_4000, FPEC + 0x0C))
    assert set(slices_in_5_ms(polling)[:-1]) == {machine.SLICE}
    app = machine.Machine(spinning(APP_TABLE, 0x2000_2000))
    assert app.running() == APPLICATION
    assert set(slices_in_5_ms(app)[:-1]) == {machine.SLICE}
