"""The release image on the machine, without the server: it boots, sends its boot-up,
feeds the watchdog, and what it stores in the parameter page survives a power cycle
through the flash file. Needs the release ELF (`cargo xtask test` builds it first; the
path comes from HANDWHEEL_BOARD_ELF, else target/)."""

import os
from pathlib import Path

import pytest

import machine
import periph

ROOT = Path(__file__).resolve().parents[2]
ELF = Path(
    os.environ.get(
        "HANDWHEEL_BOARD_ELF", ROOT / "target/thumbv7m-none-eabi/release/handwheel-firmware"
    )
)

pytestmark = pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")

SAVE = (0x65766173).to_bytes(4, "little")


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
    assert flash.read_bytes() != b"\xff" * 1024
    again = machine.Machine(str(ELF), str(flash))  # a new board from the same flash file
    again.run_ms(50)
    reply = sdo(again, bytes([0x40, 0x17, 0x10, 0, 0, 0, 0, 0]))
    assert int.from_bytes(reply[4:6], "little") == 250


def test_the_watchdog_resets_a_starved_loop_and_rcc_csr_says_so():
    m = machine.Machine(str(ELF))
    m.run_ms(20)
    m.storm_until = m.now + 2 * 72_000_000
    m.run_ms(600)
    assert m.stats.resets[-1].endswith("IndependentWatchdog")
    assert m.boot_cause == "IndependentWatchdog"
    m.run_ms(5)
    assert m.rcc.csr_flags == 0, "the firmware read the cause and cleared the flags (RMVF)"


def test_a_wheel_edge_raises_exti9_5():
    m = machine.Machine(str(ELF))
    m.run_ms(20)
    taken = m.core.exceptions_taken
    m.set_ab(1)
    m.run_ms(1)
    assert m.exti.pr == 0, "the handler cleared PR6/PR7"
    assert m.core.exceptions_taken > taken
