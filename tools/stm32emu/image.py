"""The firmware image and the memory it was linked for: the one loader of every tool.

`Image(elf)` reads the ELF with pyelftools: its loadable segments at their load
addresses (the firmware's reset handler copies .data to RAM itself), the symbols with their
sizes, the vector table (`.vector_table`) and the name of the handler each vector points at.
The memory map is the linker script's MEMORY command (the root `memory.x`: FLASH, STORAGE
and RAM), checked against the ELF: the vector table at FLASH's origin, every load segment
inside FLASH, and flip-link's RAM layout (the image is linked by it, see `memory.x`): the
initial stack pointer (`_stack_start`) inside RAM with all static RAM between it and RAM's
end, so that the stack grows down towards RAM's start. Nothing of the map is written again
here; the chip's fixed addresses (peripherals, system memory) are in `machine.py` with
their RM0008 sections.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass
from pathlib import Path

from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile

SHF_ALLOC = SH_FLAGS.SHF_ALLOC

ROOT = Path(__file__).resolve().parents[2]
# The board's linker memory map (the board emulator and the benchmark run the board image).
MEMORY_X = ROOT / "memory.x"

# Exceptions 2..6 are NMI and the faults: never taken by the firmware's own doing.
FAULTS = range(2, 7)


@dataclass(frozen=True)
class Region:
    """One MEMORY region of a linker script."""

    name: str
    origin: int
    length: int

    @property
    def end(self) -> int:
        return self.origin + self.length

    def __contains__(self, address: int) -> bool:
        return self.origin <= address < self.end


@dataclass(frozen=True)
class MemoryMap:
    """FLASH (the linker's code and data), STORAGE (the parameter page after it) and RAM."""

    flash: Region
    storage: Region
    ram: Region

    @classmethod
    def parse(cls, text: str) -> MemoryMap:
        """The MEMORY command of a GNU ld script: `NAME [(attrs)] : ORIGIN = o, LENGTH = l`,
        lengths with an optional K or M suffix."""
        text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
        block = re.search(r"MEMORY\s*\{(.*?)\}", text, flags=re.S)
        if block is None:
            raise ValueError("no MEMORY command in the linker script")
        regions = {}
        entry = re.compile(
            r"(\w+)\s*(?:\([^)]*\))?\s*:\s*ORIGIN\s*=\s*(0[xX][0-9a-fA-F]+|\d+)\s*,"
            r"\s*LENGTH\s*=\s*(0[xX][0-9a-fA-F]+|\d+)\s*([KM]?)"
        )
        for name, origin, length, unit in entry.findall(block.group(1)):
            scale = {"": 1, "K": 1024, "M": 1024 * 1024}[unit]
            regions[name] = Region(name, int(origin, 0), int(length, 0) * scale)
        missing = [n for n in ("FLASH", "STORAGE", "RAM") if n not in regions]
        if missing:
            raise ValueError(f"the linker script has no {', '.join(missing)} region")
        if regions["STORAGE"].origin != regions["FLASH"].end:
            raise ValueError("the STORAGE page does not follow FLASH")
        return cls(regions["FLASH"], regions["STORAGE"], regions["RAM"])

    @classmethod
    def load(cls, path: Path | str = MEMORY_X) -> MemoryMap:
        return cls.parse(Path(path).read_text())

    @property
    def flash_base(self) -> int:
        return self.flash.origin

    @property
    def flash_end(self) -> int:
        """The end of the flash array: FLASH and the STORAGE page after it."""
        return self.storage.end


def check_stack_layout(
    memory: MemoryMap, initial_sp: int, statics: list[tuple[str, int, int]]
) -> None:
    """flip-link's layout: the initial SP inside RAM and every static RAM section (name,
    address, size) between it and RAM's end, so that a stack overflow runs off RAM's start
    (and faults) instead of into the statics. Raises ValueError otherwise."""
    ram = memory.ram
    if not ram.origin < initial_sp <= ram.end:
        raise ValueError(f"the initial SP {initial_sp:#x} is not inside RAM")
    for name, address, size in statics:
        if address < initial_sp or address + size > ram.end:
            raise ValueError(
                f"{name} ({address:#x}, {size} B) is not between the initial SP "
                f"{initial_sp:#x} and RAM's end: not flip-link's layout"
            )


def readable(symbol: str) -> str:
    """A Rust symbol without its hash and mangling noise, short enough for a table."""
    name = re.sub(r"17h[0-9a-f]{16}E$", "", symbol)
    if name.startswith("_ZN"):
        parts = []
        rest = name[3:]
        while rest and rest[0].isdigit():
            length = int(re.match(r"\d+", rest).group())
            digits = len(str(length))
            parts.append(rest[digits : digits + length])
            rest = rest[digits + length :]
        name = "::".join(parts)
    for escape, char in (("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("..", "::"), ("$C$", ",")):
        name = name.replace(escape, char)
    return name


class Image:
    """What the tools need from the ELF: load segments, symbols, vector table, handler names,
    and the memory map it was linked for."""

    def __init__(self, path: str, memory: MemoryMap | None = None) -> None:
        self.path = str(path)
        self.memory = memory or MemoryMap.load()
        with open(path, "rb") as f:
            elf = ELFFile(f)
            self.segments: list[tuple[int, bytes]] = [
                (seg["p_paddr"], seg.data())
                for seg in elf.iter_segments()
                if seg["p_type"] == "PT_LOAD" and seg["p_filesz"] > 0
            ]
            self.symbols: dict[str, int] = {}
            self.sizes: dict[str, int] = {}
            symtab = elf.get_section_by_name(".symtab")
            if symtab is None:
                raise ValueError(f"{path} has no symbol table")
            for sym in symtab.iter_symbols():
                if sym.name:
                    self.symbols.setdefault(sym.name, sym["st_value"])
                    self.sizes.setdefault(sym.name, sym["st_size"])
            section = elf.get_section_by_name(".vector_table")
            if section is None:
                raise ValueError(f"{path} has no .vector_table")
            table_address = section["sh_addr"]
            data = section.data()
            # Static RAM: the allocated sections the linker placed in RAM (.data, .bss, ...).
            self.statics: list[tuple[str, int, int]] = [
                (sec.name, sec["sh_addr"], sec["sh_size"])
                for sec in elf.iter_sections()
                if sec["sh_flags"] & SHF_ALLOC
                and sec["sh_size"] > 0
                and sec["sh_addr"] in self.memory.ram
            ]
        # Index = exception number; [0] is the initial SP.
        self.vectors = [int.from_bytes(data[i : i + 4], "little") for i in range(0, len(data), 4)]
        self.initial_sp = self.vectors[0]
        self._check(path, table_address)
        default = self.symbols.get("DefaultHandler")
        self.handlers: dict[int, str] = {}
        for exception, vector in enumerate(self.vectors):
            if exception < 2 or vector == 0:
                continue
            if default is not None and vector & ~1 == default & ~1:
                continue
            self.handlers[exception] = self._name(exception, vector & ~1)
        self._functions: list[tuple[int, str]] | None = None

    def _check(self, path: str, table_address: int) -> None:
        memory = self.memory
        if table_address != memory.flash.origin:
            raise ValueError(f"{path}: the vector table is not at FLASH's origin")
        try:
            check_stack_layout(memory, self.initial_sp, self.statics)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        for address, data in self.segments:
            if address not in memory.flash or address + len(data) > memory.flash.end:
                raise ValueError(f"{path}: a load segment at {address:#x} is outside FLASH")

    def _name(self, exception: int, address: int) -> str:
        names = [n for n, a in self.symbols.items() if a & ~1 == address and not n.startswith("$")]
        # Prefer the vector's own name (e.g. EXTI9_5) over aliases and mangled names.
        plain = sorted(n for n in names if n.isidentifier() and not n.startswith("_"))
        return plain[0] if plain else f"exception {exception}"

    def function_at(self, address: int) -> str:
        """The name of the function symbol that contains `address` (demangled roughly)."""
        if self._functions is None:
            flash = self.memory.flash
            self._functions = sorted(
                (a & ~1, n) for n, a in self.symbols.items() if self.sizes.get(n) and a in flash
            )
            self._starts = [f[0] for f in self._functions]
        index = bisect.bisect_right(self._starts, address) - 1
        while index >= 0:
            start, name = self._functions[index]
            if start <= address < start + self.sizes[name]:
                return readable(name)
            index -= 1
        return f"{address:#010x}"

    def exception_of(self, name: str) -> int:
        for exception, handler in self.handlers.items():
            if handler == name:
                return exception
        raise KeyError(f"no vector points at {name}")
