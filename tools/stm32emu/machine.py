"""The emulated Blue Pill: the firmware as a flashed board holds it (the resident loader in
the first pages and the application in its slot, docs/FIRMWARE-UPDATE.md; or, as before the
loader, the application alone) on the Cortex-M3 core of `cortex.py` with the peripherals of
`periph.py`, the pins of the handwheel (wheel, switches, DIP switch, LEDs) and a CAN bus
whose other node is the host. No I/O and no wall clock here: `run_until` moves emulated
time on; the board emulator (`tools/board-emu/server.py`) paces it and connects it to TCP,
the machine benchmark (`tools/machine-bench`) measures it.

Memory map: flash and SRAM as the linker script gives them (`image.py` reads the root
`memory.x`). The whole 64 KiB main flash belongs to the FPEC model (`periph.Fpec`): every
erase and half-word program anywhere (loader, application slot, parameter pages) goes
through it, with its power-cut model, and is persisted in the flash file at once (64 KiB,
the whole flash; an older 2 KiB file is read as the parameter pages). The CPU executes from
the flash, which unicorn can only do from plain memory: the flash is mapped read/execute,
and a CPU store into it (unicorn's write-protection hook) goes to the FPEC, whose result
alone is then copied into unicorn's memory, with the translated code of those bytes
dropped (unicorn keeps executing stale code otherwise: `uc.mem_write` does not drop it).
Loading the images is flashing them as a probe does: the pages they cover are erased and
written, every other page keeps the flash file's content (an application an update wrote,
the parameter pages). An access below RAM faults (a stack that overflows under flip-link's
layout; `Core.faults`). The chip's own regions (RM0008 3.3, figure 2): the system memory
with the unique device ID (RM0008 30.2) and the flash size register (30.1), the peripherals
at 0x4000_0000 with their bit-band alias (PM0056 2.2.5), and the Cortex-M3's private
peripheral bus (NVIC, SCB, SysTick, DBGMCU).

Boot: the CPU starts from the vector table at the flash's start (the loader), VTOR 0 after
every reset; the loader sets VTOR and jumps into the application. A machine without a loader
starts the application as the loader would (VTOR at its vector table). SRAM (HANDOFF
included) keeps its content across a system reset and is cleared by a power-on.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from unicorn import UC_HOOK_MEM_WRITE_PROT, UC_PROT_EXEC, UC_PROT_READ
from unicorn import arm_const as arm

from . import cortex, periph
from .image import APPLICATION, LOADER, Image, Region

SYSTEM_MEMORY = 0x1FFF_F000
UNIQUE_ID = 0x1FFF_F7E8
FLASH_SIZE_REGISTER = 0x1FFF_F7E0
PERIPH_BASE = 0x4000_0000
PERIPH_SIZE = 0x3_0000
BITBAND_BASE = 0x4200_0000
BITBAND_SIZE = PERIPH_SIZE * 32
PPB_BASE = 0xE000_0000
PPB_SIZE = 0x10_0000

# Instructions per slice: 2000 cycles, 27.8 us at 72 MHz. An interrupt raised from outside
# the CPU (a CAN frame, a wheel edge) is taken at the end of the slice it falls in (the
# loader's stretches of pure computation excepted: LONG_SLICE).
SLICE = 2000
# The longest slice of the loader's stretches of pure computation (its CRC over the
# application's slot, 40 ms of the core's time): slices double up to it while the loader
# runs whole slices without touching a peripheral, and fall back to SLICE at the first
# access. The Python work per slice, not the instructions, made a boot take longer than its
# emulated time (docs/EMULATED-BOARD.md). 0.9 ms: a host frame arriving meanwhile waits at
# most that long.
LONG_SLICE = 32 * SLICE

# Pins (crates/handwheel-board/src/pins.rs, README "Pin map").
WHEEL_A, WHEEL_B = 6, 7  # PB6, PB7
AXIS_PINS = [0, 1, 2, 3, 4]  # PA0..PA4 = X, Y, Z, W, V, active low
MULT_PINS = {1: 5, 10: 6, 100: 7}  # PA5..PA7, active low
DIP_PINS = [12, 13, 14, 15, 0, 1, 10, 11]  # PB, switch on = grounded
RUN_LED = ("C", 13)  # active low
ERR_LED = ("B", 5)  # active high
# The board's digital outputs, out 1 first (active high): the "jog live" LED, then
# 0x6A00:1 bits 0..6 (crates/handwheel-board/src/pins.rs).
OUTPUT_PINS = (("A", 8), ("A", 15), ("B", 3), ("B", 4), ("A", 9), ("A", 10), ("B", 2), ("C", 14))
# JTAG's pins out of reset (JTDI, JTDO, NJTRST): the GPIO drives them only once AFIO's SWJ_CFG
# has released them (RM0008 9.3.5, table 41).
JTAG_PINS = {("A", 15), ("B", 3), ("B", 4)}
# Edges per detent and the time between two edges of `turn` (a brisk hand: 4 detents/10 ms).
EDGES_PER_DETENT = 4
EDGE_CYCLES = 600 * cortex.CORE_HZ // 1_000_000  # 600 us
SETTLE_CYCLES = 25 * cortex.CORE_HZ // 1000  # 25 ms


@dataclass
class LedChange:
    ms: float
    led: str
    on: bool


@dataclass
class Stats:
    resets: list[str] = field(default_factory=list)
    slices: int = 0


class Machine:
    """The board flashed with `elf` (the application: a path or a loaded `Image`, None for
    none) and `loader` (the resident loader, likewise; None: the application alone, started
    as the loader would). `flash_file` holds the whole flash across power cycles and boards
    (None: kept in memory only)."""

    def __init__(
        self,
        elf: str | Image | None,
        flash_file: str | None = None,
        unique_id: bytes | None = None,
        cut_seed: int = 1,
        loader: str | Image | None = None,
    ):
        self.app = self._load(elf, APPLICATION)
        self.loader = self._load(loader, LOADER)
        if self.app is None and self.loader is None:
            raise ValueError("a board needs an application or a loader image")
        # The image the tools look at (symbols, handlers): the application if there is one.
        self.image = self.app or self.loader
        memory = self.memory = self.image.memory
        # The whole main flash (RM0008 3.3.3), which the FPEC manages.
        self.flash = Region("MAIN", memory.flash_base, memory.flash_end - memory.flash_base)
        self.ram = memory.sram
        self.flash_file = flash_file
        self.unique_id = unique_id or bytes.fromhex("3a0035000d5731343932353c")
        self.now = 0
        self.nvic = cortex.Nvic()
        self.uc = uc = cortex.make_uc()
        self._flash_out = None  # the flash file, open for writing through
        content = self._stored_flash()
        for image in (self.loader, self.app):
            if image is not None:
                self._flash_image(content, image)
        self.fpec = periph.Fpec(self.flash.origin, content, cut_seed)
        self.fpec.on_change = self._flash_changed
        uc.mem_map(self.flash.origin, self.flash.length, UC_PROT_READ | UC_PROT_EXEC)
        uc.mem_write(self.flash.origin, bytes(content))
        # Before the core's hook for invalid accesses: a store into the flash is the FPEC's.
        uc.hook_add(
            UC_HOOK_MEM_WRITE_PROT,
            self._flash_store,
            begin=self.flash.origin,
            end=self.flash.end - 1,
        )
        self.save_flash()
        uc.mem_map(self.ram.origin, self.ram.length)
        uc.mem_map(SYSTEM_MEMORY, 0x1000, UC_PROT_READ)
        uc.mem_write(UNIQUE_ID, self.unique_id)
        size_kib = (memory.flash_end - memory.flash_base) // 1024
        uc.mem_write(FLASH_SIZE_REGISTER, size_kib.to_bytes(2, "little"))
        uc.mmio_map(PERIPH_BASE, PERIPH_SIZE, self._periph_read, None, self._periph_write, None)
        uc.mmio_map(BITBAND_BASE, BITBAND_SIZE, self._bb_read, None, self._bb_write, None)
        uc.mmio_map(PPB_BASE, PPB_SIZE, self._ppb_read, None, self._ppb_write, None)

        self.rcc = periph.Rcc()
        self.gpio = {
            "A": periph.Gpio("A", self._on_output),
            "B": periph.Gpio("B", self._on_output),
            "C": periph.Gpio("C", self._on_output),
        }
        self.afio = periph.Afio()
        self.exti = periph.Exti()
        self.iwdg = periph.Iwdg()
        self.can = periph.Bxcan(self._on_can_transmit)
        self.other: dict[int, int] = {}
        self.devices = {
            periph.RCC_BASE: ("rcc", self.rcc),
            periph.FLASH_IF_BASE: ("fpec", self.fpec),
            periph.GPIOA_BASE: ("gpio", self.gpio["A"]),
            periph.GPIOB_BASE: ("gpio", self.gpio["B"]),
            periph.GPIOC_BASE: ("gpio", self.gpio["C"]),
            periph.AFIO_BASE: ("afio", self.afio),
            periph.EXTI_BASE: ("exti", self.exti),
            periph.IWDG_BASE: ("iwdg", self.iwdg),
            periph.CAN_BASE: ("can", self.can),
        }
        self.core = cortex.Core(uc, self.nvic, self._vector)
        self.core.on_return = self.update_irqs

        # The world around the MCU.
        self.dip = 0  # switch n on = bit n-1
        # The wheel rests with A and B low (a detent at 00), where the interop suite's `ab`
        # sequences start.
        self.ab = 0
        self.axis = 0  # 0 off, 1..5
        self.mult = 0  # 0 none, 1, 10, 100
        self.leds: list[LedChange] = []
        self.led_state = {"run": None, "err": None}
        self.transmitted: list[tuple[float, periph.Frame]] = []
        self.on_frame = lambda frame: None  # frames the node put on the bus
        self.on_reset = lambda cause: None
        self.on_power_off = lambda: None  # the last moment SRAM can be read (the RTT log)
        self.on_handover = lambda: None  # VTOR written (the loader starting the application)
        # A reset begins: the last moment the image that ran is the one the PC is in.
        self.on_reset_start = lambda: None
        self.events: list[tuple[int, int, object]] = []  # (cycle, seq, callback)
        self.host_frames: list[tuple[int, periph.Frame]] = []  # (arrival cycle, frame)
        self.host_bus_free = 0
        self.delivery_results: list[str] = []
        self.stall_until = 0  # the CPU waits for the flash until then
        self._seq = 0
        self.storm_until = 0
        self.storm_started_ms = 0.0
        self.stats = Stats()
        self.slice = SLICE  # the next slice's length (`_next_slice`)
        self.accesses = 0  # peripheral and flash-store accesses of the CPU so far
        self.boot_cause = "PowerOn"
        self.power_on()

    # -- images and flash ---------------------------------------------------------------------

    @staticmethod
    def _load(image: str | Image | None, kind: str) -> Image | None:
        if image is None:
            return None
        image = image if isinstance(image, Image) else Image(image)
        if image.kind != kind:
            raise ValueError(f"{image.path} is the {image.kind} image, not the {kind}")
        return image

    def _stored_flash(self) -> bytearray:
        """The flash as the file holds it, erased where it says nothing."""
        return self.stored_flash(b"\xff" * self.flash.length)

    def stored_flash(self, base: bytes) -> bytearray:
        """`base` (the whole flash) with what the flash file holds over it: the whole flash,
        or (an older file) the parameter pages alone."""
        content = bytearray(base)
        if not self.flash_file or not os.path.exists(self.flash_file):
            return content
        with open(self.flash_file, "rb") as f:
            stored = f.read(self.flash.length + 1)
        storage = self.memory.storage
        if len(stored) == self.flash.length:
            content[:] = stored
        elif len(stored) <= storage.length:
            start = storage.origin - self.flash.origin
            content[start : start + len(stored)] = stored
        else:
            raise ValueError(
                f"{self.flash_file}: {len(stored)} bytes, neither the whole flash "
                f"({self.flash.length}) nor the parameter pages ({storage.length})"
            )
        return content

    def _flash_image(self, content: bytearray, image: Image) -> None:
        """Flashes `image` as a probe does: its pages erased, its segments written."""
        for page in image.pages():
            start = page - self.flash.origin
            content[start : start + 1024] = b"\xff" * 1024
        for address, data in image.segments:
            start = address - self.flash.origin
            content[start : start + len(data)] = data

    def _flash_store(self, _uc, _access, address, size, value, _user) -> bool:
        """A CPU store into the flash: the FPEC's to apply (a half-word program, or an
        error flag). Unicorn then leaves the flash as `_flash_changed` wrote it."""
        self.accesses += 1
        self.fpec.write_memory(address - self.flash.origin, size, value, self.now)
        return True

    def _flash_changed(self, offset: int, length: int) -> None:
        """The FPEC changed `length` bytes at `offset`: the CPU sees them (code translated
        from the old bytes dropped) and the flash file has them."""
        address = self.flash.origin + offset
        self.uc.mem_write(address, bytes(self.fpec.memory[offset : offset + length]))
        self.uc.ctl_remove_cache(address, address + length)
        if not self.flash_file:
            return
        if self._flash_file_open():
            # A syscall, not a new file per half-word: an update programs thousands.
            os.pwrite(self._flash_out.fileno(), self.fpec.memory[offset : offset + length], offset)
        else:
            self.save_flash()

    def write_flash(self, offset: int, data: bytes) -> None:
        """Writes flash content directly, not through the FPEC (a probe, a test crafting
        the flash): a running operation is forgotten."""
        self.fpec.pending = None
        self.fpec.memory[offset : offset + len(data)] = data
        self._flash_changed(offset, len(data))

    def running(self) -> str:
        """Which image the CPU is in, by its PC: `loader`, `application` or `none`."""
        pc = self.uc.reg_read(arm.UC_ARM_REG_PC)
        if self.memory.loader is not None and pc in self.memory.loader:
            return LOADER
        if pc in self.memory.slot:
            return APPLICATION
        return "none"

    # -- vectors and idle ---------------------------------------------------------------------

    def _vector(self, exception: int) -> int:
        base = self.nvic.vtor
        if base < self.flash.origin:
            base += self.flash.origin  # address 0 aliases the boot flash (RM0008 3.4)
        return int.from_bytes(self.uc.mem_read(base + 4 * exception, 4), "little")

    # -- memory-mapped I/O -------------------------------------------------------------------

    @staticmethod
    def _lanes(address: int, size: int, value: int) -> tuple[int, int, int]:
        shift = (address & 3) * 8
        mask = ((1 << (size * 8)) - 1) << shift
        return address & ~3, (value << shift) & mask, mask

    def _periph_read(self, _uc, offset, size, _user):
        self.accesses += 1
        address = PERIPH_BASE + offset
        word = self._read_word(address & ~3)
        return (word >> ((address & 3) * 8)) & ((1 << (size * 8)) - 1)

    def _read_word(self, address: int) -> int:
        base = address & ~0x3FF
        device = self.devices.get(base)
        if device is None:
            return self.other.get(address, 0)
        kind, model = device
        offset = address - base
        if kind in ("fpec", "iwdg"):
            return model.read(offset, self.now)
        return model.read(offset)

    def _periph_write(self, _uc, offset, size, value, _user):
        self.accesses += 1
        address, value, mask = self._lanes(PERIPH_BASE + offset, size, value)
        self._write_word(address, value, mask)

    def _write_word(self, address: int, value: int, mask: int) -> None:
        base = address & ~0x3FF
        device = self.devices.get(base)
        if device is None:
            self.other[address] = (self.other.get(address, 0) & ~mask) | value
            return
        kind, model = device
        offset = address - base
        if kind in ("fpec", "iwdg", "can"):
            model.write(offset, value, mask, self.now)
        else:
            model.write(offset, value, mask)
        if kind == "iwdg" and self.iwdg.running:
            self.rcc.regs[0x24] = self.rcc.regs.get(0x24, 0) | 1  # 19.3: LSI forced on
        if kind == "rcc" and offset in self.PERIPHERAL_RESETS:
            self._reset_peripherals(offset, value & mask)
        if kind in ("exti", "can"):
            self.update_irqs()

    # RM0008 7.3.4 APB2RSTR and 7.3.5 APB1RSTR: the bits of the modelled peripherals.
    PERIPHERAL_RESETS = {
        0x0C: {0: "afio", 2: "A", 3: "B", 4: "C"},
        0x10: {25: "can"},
    }

    def _reset_peripherals(self, offset: int, bits: int) -> None:
        """A reset bit set in APB2RSTR or APB1RSTR: that peripheral's registers go back to
        their reset values (the loader hands the application a bxCAN, GPIOB and AFIO as out
        of reset this way)."""
        for bit, name in self.PERIPHERAL_RESETS[offset].items():
            if not bits >> bit & 1:
                continue
            if name == "afio":
                self.afio.reset()
            elif name == "can":
                self.can.reset()
            else:
                self.gpio[name].reset()
        self._apply_inputs()
        self.update_irqs()

    def _bb_read(self, _uc, offset, _size, _user):
        self.accesses += 1
        address = PERIPH_BASE + (offset >> 5)
        bit = ((offset >> 2) & 7) + 8 * (address & 3)
        return (self._read_word(address & ~3) >> bit) & 1

    def _bb_write(self, _uc, offset, _size, value, _user):
        self.accesses += 1
        address = PERIPH_BASE + (offset >> 5)
        bit = ((offset >> 2) & 7) + 8 * (address & 3)
        word = address & ~3
        current = self._read_word(word)
        new = (current | 1 << bit) if value & 1 else (current & ~(1 << bit))
        self._write_word(word, new, 0xFFFF_FFFF)

    def _ppb_read(self, _uc, offset, size, _user):
        self.accesses += 1
        address = PPB_BASE + offset
        if 0xE000_E000 <= address < 0xE000_F000:
            word = self.nvic.read(address & ~3)
        else:
            word = self.other.get(address & ~3, 0)
        return (word >> ((address & 3) * 8)) & ((1 << (size * 8)) - 1)

    def _ppb_write(self, _uc, offset, size, value, _user):
        self.accesses += 1
        address, value, mask = self._lanes(PPB_BASE + offset, size, value)
        if address == cortex.SCB_VTOR:
            # The loader hands over: the last moment its RTT log is surely intact.
            self.on_handover()
        if 0xE000_E000 <= address < 0xE000_F000:
            self.nvic.write(address, value, mask)
        else:
            self.other[address] = (self.other.get(address, 0) & ~mask) | value

    def save_flash(self) -> None:
        """Writes the whole flash file anew (atomically: a board killed meanwhile leaves
        the old one) and keeps it open for the writes through (`_flash_changed`)."""
        if self.flash_file:
            tmp = self.flash_file + ".tmp"
            with open(tmp, "wb") as f:
                f.write(self.fpec.memory)
            os.replace(tmp, self.flash_file)
            if self._flash_out is not None:
                self._flash_out.close()
            self._flash_out = open(self.flash_file, "r+b", buffering=0)  # noqa: SIM115

    def _flash_file_open(self) -> bool:
        """Whether the open flash file is still the file, whole (a test may have written a
        file of the parameter pages in its place, or replaced it)."""
        out = self._flash_out
        if out is None:
            return False
        status = os.fstat(out.fileno())
        if status.st_nlink and status.st_size == self.flash.length:
            return True
        out.close()
        self._flash_out = None
        return False

    # -- interrupt lines ---------------------------------------------------------------------

    def update_irqs(self) -> None:
        """Level-sensitive lines: an asserted line pends its interrupt unless it is active
        (it pends again at the handler's return if still asserted)."""
        active = set(self.nvic.active_stack)
        for line in self.exti.irqs() | self.can.irqs():
            exception = cortex.IRQ_BASE + line
            if exception not in active:
                self.nvic.set_pending(exception)

    # -- outputs -----------------------------------------------------------------------------

    def _on_output(self, port: str, odr: int) -> None:
        for name, (led_port, bit), active_high in (("run", RUN_LED, False), ("err", ERR_LED, True)):
            if led_port != port:
                continue
            gpio = self.gpio[port]
            if not gpio.output_mask() >> bit & 1:
                continue
            on = bool(odr >> bit & 1) == active_high
            if self.led_state[name] != on:
                self.led_state[name] = on
                self.leds.append(LedChange(self.ms(), name, on))

    def outputs(self) -> int:
        """The board's digital outputs driven high now: bit n = output n + 1. A pin drives
        only as a GPIO output; a JTAG pin only once SWJ_CFG released it."""
        value = 0
        for n, (port, bit) in enumerate(OUTPUT_PINS):
            gpio = self.gpio[port]
            if (port, bit) in JTAG_PINS and not self.afio.jtag_released():
                continue
            if gpio.output_mask() >> bit & gpio.odr >> bit & 1:
                value |= 1 << n
        return value

    def _on_can_transmit(self, frame: periph.Frame) -> None:
        self.transmitted.append((self.ms(), frame))
        self.on_frame(frame)

    def ms(self) -> float:
        return self.now * 1000 / cortex.CORE_HZ

    # -- inputs ------------------------------------------------------------------------------

    def _apply_inputs(self) -> None:
        a = self.gpio["A"]
        levels = 0xFFFF
        if self.axis:
            levels &= ~(1 << AXIS_PINS[self.axis - 1])
        if self.mult:
            levels &= ~(1 << MULT_PINS[self.mult])
        a.levels = levels
        b = self.gpio["B"]
        levels = 0xFFFF
        for switch, pin in enumerate(DIP_PINS):
            if self.dip >> switch & 1:
                levels &= ~(1 << pin)
        levels = levels & ~(3 << WHEEL_A) | (self.ab & 1) << WHEEL_A | (self.ab >> 1 & 1) << WHEEL_B
        b.levels = levels

    def set_ab(self, ab: int) -> None:
        """New wheel levels: each changed line is an edge on its EXTI line (RM0008 10.2.3)
        when AFIO routes that line to port B."""
        old = self.ab
        self.ab = ab & 3
        self._apply_inputs()
        for line, bit in ((WHEEL_A, 0), (WHEEL_B, 1)):
            if (old ^ self.ab) >> bit & 1 and self.afio.port_of_line(line) == 1:
                self.exti.edge(line, rising=bool(self.ab >> bit & 1))
        self.update_irqs()

    def set_selectors(self, axis: int | None = None, mult: int | None = None) -> None:
        if axis is not None:
            self.axis = axis
        if mult is not None:
            self.mult = mult
        self._apply_inputs()

    def set_dip(self, dip: int) -> None:
        self.dip = dip & 0xFF
        self._apply_inputs()

    def schedule(self, delay_cycles: int, callback) -> None:
        self._seq += 1
        self.events.append((self.now + delay_cycles, self._seq, callback))
        self.events.sort()

    def turn(self, detents: int, done=None) -> None:
        """`detents` detents as quadrature edges EDGE_CYCLES apart, forward = A leads B
        (Gray order 0, 1, 3, 2 of B:A, as `AbLevels::next_forward`)."""
        forward = [1, 3, 0, 2]
        reverse = [2, 0, 3, 1]
        edges = abs(detents) * EDGES_PER_DETENT
        table = forward if detents > 0 else reverse

        def step(left: int) -> None:
            if left == 0:
                if done:
                    # Done once the last edge has been handled and its feed frame is out
                    # (the TPDO's 2 ms inhibit time included).
                    self.schedule(SETTLE_CYCLES, done)
                return
            self.set_ab(table[self.ab])
            self.schedule(EDGE_CYCLES, lambda: step(left - 1))

        step(edges)

    def deliver(self, frame: periph.Frame) -> None:
        """A frame from the host goes onto the bus: it reaches the node's controller once
        its bits have passed (at the node's bit rate, after the host's previous frame), so a
        burst arrives frame by frame, as on a real bus."""
        rate = self.can.bus_bitrate or self.can.bitrate() or 1_000_000
        start = max(self.now, self.host_bus_free)
        self.host_bus_free = start + int(frame.bits() * cortex.CORE_HZ / rate)
        self.host_frames.append((self.host_bus_free, frame))

    def _deliver_due(self) -> None:
        while self.host_frames and self.host_frames[0][0] <= self.now:
            _, frame = self.host_frames.pop(0)
            if self.can.dominant(self.now):
                # The host's controller cannot send on a dominant bus: the frame is lost.
                self.can.dropped_offline += 1
                self.delivery_results.append("dominant")
            else:
                self.delivery_results.append(self.can.deliver(frame))

    # -- resets ------------------------------------------------------------------------------

    def power_cut(self) -> bool:
        """The supply fails and comes back: a flash operation still running is left half
        done (`Fpec.cut`), then a power-on reset. Returns whether an operation was cut."""
        half = self.fpec.cut(self.now)
        self.save_flash()
        self.power_on()
        return half

    def power_on(self) -> None:
        """Power-on reset: SRAM content lost, PORRSTF and PINRSTF (RM0008 7.1.2)."""
        self.on_power_off()
        self.uc.mem_write(self.ram.origin, bytes(self.ram.length))
        self.rcc.csr_flags = periph.Rcc.PORRSTF | periph.Rcc.PINRSTF
        self._reset("PowerOn")

    def pin_reset(self) -> None:
        self.rcc.csr_flags |= periph.Rcc.PINRSTF
        self._reset("Pin")

    def _reset(self, cause: str) -> None:
        """System reset (RM0008 7.1.2): every register to its reset value but RCC_CSR's
        flags; SRAM keeps its content; the CPU starts from the vector table."""
        self.on_reset_start()
        self.stats.resets.append(f"{self.ms():.1f} ms {cause}")
        self.last_reset_ms = self.ms()
        self.nvic.reset()
        if self.loader is None:
            # No loader: the application starts as the loader would start it.
            self.nvic.vtor = self.app.table_address
        # A pend during a slice is taken at its end, or in precise mode before the next
        # instruction (stopping unicorn from a memory callback would make it run the storing
        # instruction again).
        self.nvic.now = self.now
        self.rcc.reset()
        for gpio in self.gpio.values():
            gpio.reset()
        self.afio.reset()
        self.exti.reset()
        self.iwdg.reset()
        self.fpec.reset()
        self.can.reset()
        self.other = {}
        self.storm_until = 0
        self.stall_until = 0
        self.led_state = {"run": None, "err": None}
        self.core.locked_up = False
        uc = self.uc
        for r in range(13):
            uc.reg_write(getattr(arm, f"UC_ARM_REG_R{r}"), 0)
        uc.reg_write(arm.UC_ARM_REG_PRIMASK, 0)
        uc.reg_write(arm.UC_ARM_REG_BASEPRI, 0)
        uc.reg_write(arm.UC_ARM_REG_CONTROL, 0)
        uc.reg_write(arm.UC_ARM_REG_SP, self._vector(0))
        uc.reg_write(arm.UC_ARM_REG_LR, 0xFFFF_FFFF)
        uc.reg_write(arm.UC_ARM_REG_PC, self._vector(1) | 1)
        uc.reg_write(arm.UC_ARM_REG_XPSR, 1 << 24)
        self._apply_inputs()
        self.boot_cause = cause
        self.on_reset(cause)

    # -- time --------------------------------------------------------------------------------

    def next_event(self) -> int:
        """The next cycle at which something outside the CPU happens."""
        candidates = [self.now + 10 * cortex.CORE_HZ // 1000]  # at most 10 ms ahead
        tick = self.nvic.next_systick()
        if tick is not None:
            candidates.append(tick)
        bus = self.can.next_event(self.now)
        if bus is not None:
            candidates.append(bus)
        dog = self.iwdg.expiry()
        if dog is not None:
            candidates.append(dog)
        if self.events:
            candidates.append(self.events[0][0])
        if self.host_frames:
            candidates.append(self.host_frames[0][0])
        if self.stall_until > self.now:
            candidates.append(self.stall_until)
        if self.can.bus_off:
            candidates.append(self.now + cortex.CORE_HZ // 10_000)
        return max(self.now + 1, min(candidates))

    def _advance_to(self, cycle: int) -> None:
        """Moves the world (not the CPU) to `cycle`."""
        self.nvic.now = self.now
        self.nvic.advance_systick(cycle)
        self.now = cycle
        self.nvic.now = cycle
        dog = self.iwdg.expiry()
        if dog is not None and self.now >= dog:
            self.rcc.csr_flags |= periph.Rcc.IWDGRSTF
            self._reset("IndependentWatchdog")
            return
        while self.events and self.events[0][0] <= self.now:
            _, _, callback = self.events.pop(0)
            callback()
        self._deliver_due()
        self.can.advance(self.now)
        if self.storm_until and self.now < self.storm_until:
            # An interrupt storm on TIM2's vector (`feed_due`, priority 3): the CAN task
            # (priority 2) never runs, as when a handler hangs.
            self.nvic.set_pending(cortex.IRQ_BASE + 28)
        self.update_irqs()
        if self.nvic.reset_requested:
            self.rcc.csr_flags |= periph.Rcc.SFTRSTF
            self._reset("Software")

    def step(self, idle_jump: bool = True) -> bool:
        """One slice of the CPU (or a jump over idle, a flash stall or a lock-up). Returns
        whether the CPU went idle: thread mode's YIELD with nothing it would take; then time
        jumps to the next event (with `idle_jump`; else it stays where the CPU stopped)."""
        target = self.next_event()
        if self.core.locked_up or self.stall_until > self.now:
            # A lock-up, or the CPU waiting for a flash operation (PM0075 2.3.1): time
            # passes, the peripherals work, no instruction runs, no exception is taken.
            self._advance_to(max(target, self.now + 1))
            return False
        before = self.core.cycles
        self.core.check_preemption()
        count = min(self.slice, target - self.now)
        accesses = self.accesses
        self.core.run(count)
        self.stats.slices += 1
        self.slice = self._next_slice(count, self.accesses != accesses)
        # The whole slice, or in precise mode what its instructions and exception entries
        # and returns took.
        elapsed = self.core.cycles - before
        # The idle task's `spin_loop` (YIELD) in thread mode: the CPU has nothing to do,
        # unless the slice started a flash operation, whose stall (or armed cut) comes first.
        if (
            self.core.stop_reason == "yield"
            and not self.nvic.active_stack
            and not self.fpec.stall
            and not self.fpec.cut_requested
        ):
            primask, basepri = self.core.mask_levels()
            if self.nvic.preempting(primask, basepri) is None:
                # Idle until the next event: nothing else can happen before it.
                if idle_jump:
                    target = max(target, self.now + max(elapsed, 1))
                else:
                    target = self.now + elapsed
                self._advance_to(target)
                return True
        if self.core.stop_reason == "return":
            self.update_irqs()
        self._advance_to(self.now + elapsed)
        stall = self.fpec.take_stall()
        if self.fpec.cut_requested:
            # An armed cut (`Fpec.arm`): the supply fails at that operation.
            self.power_cut()
            return False
        if stall:
            self.stall_until = self.now + stall
        return False

    def _next_slice(self, count: int, accessed: bool) -> int:
        """The next slice's length: doubled after a whole slice of the loader's (real-time
        mode) that touched no peripheral, with no exception pending; else SLICE. The loader
        takes no interrupts; a pending exception could be let in by an MSR, which is no
        access."""
        if (
            accessed
            or count < self.slice
            or self.core.stop_reason
            or self.core.cost is not None
            or self.nvic.pending
            or self.running() != LOADER
        ):
            return SLICE
        return min(2 * self.slice, LONG_SLICE)

    def interrupt_due(self) -> bool:
        """An exception would preempt what the CPU runs now (after an idle `step`: an event
        at the slice's end woke it)."""
        primask, basepri = self.core.mask_levels()
        return self.nvic.preempting(primask, basepri) is not None

    def idle_until(self, cycle: int) -> None:
        """Lets time pass to `cycle` (no later than the next event) with the CPU idle, after
        a `step(idle_jump=False)` that returned idle: its caller decides how far (the board
        emulator: as far as the wall clock has gone). No time passes if an interrupt is due:
        the CPU is not idle any more, and a second event (a wheel edge) before it ran would
        be merged with the first."""
        cycle = min(cycle, self.next_event())
        if cycle > self.now and not self.interrupt_due():
            self._advance_to(cycle)

    def run_until(self, cycle: int) -> None:
        while self.now < cycle:
            self.step()

    def run_ms(self, ms: float) -> None:
        self.run_until(self.now + int(ms * cortex.CORE_HZ / 1000))

    # -- RTT ---------------------------------------------------------------------------------

    def rtt_read(self) -> bytes:
        """Takes what the firmware wrote to RTT up-channel 0 (the defmt log): SEGGER's
        control block is `_SEGGER_RTT`: id[16], max_up, max_down, then 24-byte channel
        descriptors (name, buffer, size, write, read, flags)."""
        image = {LOADER: self.loader, APPLICATION: self.app}.get(self.running())
        cb = image.symbols.get("_SEGGER_RTT") if image is not None else None
        if cb is None or bytes(self.uc.mem_read(cb, 10)) != b"SEGGER RTT":
            # No log, or not set up yet (right after the loader's jump, the application's
            # control block still holds what the loader left there).
            return b""
        raw = bytes(self.uc.mem_read(cb + 24, 24))
        _name, buf, size, write, read, _flags = (
            int.from_bytes(raw[i : i + 4], "little") for i in range(0, 24, 4)
        )
        if not size or write == read or buf not in self.ram:
            return b""
        if write > read:
            data = bytes(self.uc.mem_read(buf + read, write - read))
        else:
            data = bytes(self.uc.mem_read(buf + read, size - read))
            data += bytes(self.uc.mem_read(buf, write))
        self.uc.mem_write(cb + 24 + 16, write.to_bytes(4, "little"))
        return data
