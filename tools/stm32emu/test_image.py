"""The loader and the memory map: the map is the linker script's, checked against the ELF."""

import pytest

from stm32emu.image import MEMORY_X, Image, MemoryMap, check_stack_layout
from stm32emu.test_machine import ELF

SCRIPT = """
/* a comment: FLASH : ORIGIN = 0, LENGTH = 1K */
MEMORY
{
  FLASH   : ORIGIN = 0x08000000, LENGTH = 63K
  STORAGE : ORIGIN = 0x0800FC00, LENGTH = 1K
  RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 20K
}
"""


def test_the_memory_command_gives_flash_page_and_ram():
    memory = MemoryMap.parse(SCRIPT)
    assert (memory.flash.origin, memory.flash.length) == (0x0800_0000, 63 * 1024)
    assert (memory.storage.origin, memory.storage.end) == (0x0800_FC00, 0x0801_0000)
    assert (memory.ram.origin, memory.ram.end) == (0x2000_0000, 0x2000_5000)
    assert memory.flash_end - memory.flash_base == 64 * 1024
    assert 0x0800_FBFF in memory.flash and 0x0800_FC00 not in memory.flash


def test_a_script_without_a_region_or_with_a_gap_is_refused():
    with pytest.raises(ValueError, match="STORAGE"):
        MemoryMap.parse(SCRIPT.replace("STORAGE", "OTHER"))
    with pytest.raises(ValueError, match="follow"):
        MemoryMap.parse(SCRIPT.replace("0x0800FC00", "0x0800F800"))


def test_the_board_script_is_the_part_the_board_has():  # memory.x, STM32F103C8
    memory = MemoryMap.load(MEMORY_X)
    assert memory.flash_end - memory.flash_base == 64 * 1024
    # RAM is the images'; the last 8 bytes of the 20 KiB are the loader hand-off's.
    assert memory.ram.length + memory.handoff.length == 20 * 1024
    assert memory.handoff.origin == memory.ram.end


def test_the_stack_must_lie_below_static_ram():  # flip-link's layout
    memory = MemoryMap.parse(SCRIPT)
    statics = [(".data", 0x2000_4600, 0x40), (".bss", 0x2000_4640, 0x9C0)]
    check_stack_layout(memory, 0x2000_4600, statics)
    with pytest.raises(ValueError, match="initial SP"):
        check_stack_layout(memory, 0x2000_5004, statics)
    # The classic layout: statics at RAM's start, the stack from RAM's end down onto them.
    classic = [(".data", 0x2000_0000, 0x40), (".bss", 0x2000_0040, 0x9C0)]
    with pytest.raises(ValueError, match="flip-link"):
        check_stack_layout(memory, 0x2000_5000, classic)


@pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")
def test_the_release_image_fits_the_map_and_names_its_handlers():
    image = Image(str(ELF))
    assert image.initial_sp == image.symbols["_stack_start"] < image.memory.ram.end
    assert image.symbols["_stack_end"] == image.memory.ram.origin
    assert {name for name, _, _ in image.statics} >= {".data", ".bss", ".uninit"}
    assert image.handlers[16 + 23] == "EXTI9_5"
    assert image.exception_of("USB_LP_CAN_RX0") == 16 + 20
    assert image.function_at(image.symbols["EXTI9_5"] & ~1) == "EXTI9_5"
    # The same map with 8 KiB of RAM: the image's stack starts above it.
    small_ram = (
        MEMORY_X.read_text()
        .replace("ORIGIN = 0x20000000, LENGTH = 20472", "ORIGIN = 0x20000000, LENGTH = 8184")
        .replace("ORIGIN = 0x20004FF8", "ORIGIN = 0x20001FF8")
        .replace("== 0x20005000", "== 0x20002000")
    )
    with pytest.raises(ValueError, match="initial SP"):
        Image(str(ELF), MemoryMap.parse(small_ram))
