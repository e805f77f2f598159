"""The firmware images and the memory they were linked for: the one loader of every tool.

`Image(elf)` reads the ELF with pyelftools: its loadable segments at their load
addresses (the firmware's reset handler copies .data to RAM itself), the symbols with their
sizes, the vector table (`.vector_table`) and the name of the handler each vector points at.
The memory map is the linker script's MEMORY command (the root `memory.x`,
docs/FIRMWARE-UPDATE.md "Memory map": LOADER, HEADER, FLASH, STORAGE, RAM and HANDOFF; the
map from before the loader, FLASH, STORAGE and RAM alone, is read too), checked against the
ELF. An image is one of two kinds, told by where its vector table is: the **loader** (at
LOADER's origin, its segments inside LOADER) or the **application** (at FLASH's origin, its
segments inside its slot, HEADER and FLASH). Both must have flip-link's RAM layout (the
images are linked by it, see `memory.x`): the initial stack pointer (`_stack_start`) inside
RAM with all static RAM between it and RAM's end, so that the stack grows down towards RAM's
start. Nothing of the map is written again here; the chip's fixed addresses (peripherals,
system memory) are in `machine.py` with their RM0008 sections.
"""

from __future__ import annotations

import ast
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

# The two kinds of image (docs/FIRMWARE-UPDATE.md).
LOADER = "loader"
APPLICATION = "application"
# The flash page (RM0008 3.3.3: 1 KiB in a medium-density part): what a probe erases.
PAGE_SIZE = 1024


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


# The flash regions in address order, each following the one before it when present.
FLASH_REGIONS = ("LOADER", "HEADER", "FLASH", "STORAGE")


def _expression(text: str, regions: dict[str, Region]) -> int:
    """An ld expression of a MEMORY entry: numbers (decimal, 0x hex, a K or M suffix),
    `ORIGIN(NAME)` and `LENGTH(NAME)` of a region above it, + - * / and parentheses."""

    def region(match: re.Match) -> str:
        name = match.group(2)
        if name not in regions:
            raise ValueError(f"{match.group(0)} names no region above it")
        r = regions[name]
        return str(r.origin if match.group(1).upper() == "ORIGIN" else r.length)

    text = re.sub(r"\b(ORIGIN|LENGTH)\s*\(\s*(\w+)\s*\)", region, text, flags=re.I)

    def number(match: re.Match) -> str:
        scale = {"": 1, "K": 1024, "M": 1024 * 1024}[match.group(2).upper()]
        return str(int(match.group(1), 0) * scale)

    text = re.sub(r"\b(0[xX][0-9a-fA-F]+|\d+)([KkMm]?)\b", number, text)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        raise ValueError(f"`{text.strip()}` is not an expression this parser knows") from None

    def value(node: ast.AST) -> int:
        if isinstance(node, ast.Expression):
            return value(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, int):
            return node.value
        if isinstance(node, ast.BinOp):
            ops = {ast.Add: int.__add__, ast.Sub: int.__sub__, ast.Mult: int.__mul__}
            ops[ast.Div] = int.__floordiv__
            op = ops.get(type(node.op))
            if op is not None:
                return op(value(node.left), value(node.right))
        raise ValueError(f"`{text.strip()}` is not an expression this parser knows")

    return value(tree)


@dataclass(frozen=True)
class MemoryMap:
    """FLASH (the application's code and data), STORAGE (the parameter pages after it) and
    RAM; with the resident loader (docs/FIRMWARE-UPDATE.md) also LOADER (its image), HEADER
    (the application's image header, before FLASH) and HANDOFF (the words after RAM that ask
    the loader to stay)."""

    flash: Region
    storage: Region
    ram: Region
    loader: Region | None = None
    header: Region | None = None
    handoff: Region | None = None

    @classmethod
    def parse(cls, text: str) -> MemoryMap:
        """The MEMORY command of a GNU ld script: `NAME [(attrs)] : ORIGIN = o, LENGTH = l`
        a line, o and l expressions (`_expression`)."""
        text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
        block = re.search(r"MEMORY\s*\{(.*?)\}", text, flags=re.S)
        if block is None:
            raise ValueError("no MEMORY command in the linker script")
        regions: dict[str, Region] = {}
        entry = re.compile(
            r"^\s*(\w+)\s*(?:\([^)]*\))?\s*:\s*(?:ORIGIN|org|o)\s*=\s*(.+?)\s*,"
            r"\s*(?:LENGTH|len|l)\s*=\s*(.+?)\s*$",
            flags=re.I,
        )
        for line in block.group(1).splitlines():
            if not line.strip():
                continue
            match = entry.match(line)
            if match is None:
                raise ValueError(f"`{line.strip()}` is not a MEMORY entry")
            name, origin, length = match.groups()
            regions[name] = Region(name, _expression(origin, regions), _expression(length, regions))
        missing = [n for n in ("FLASH", "STORAGE", "RAM") if n not in regions]
        if missing:
            raise ValueError(f"the linker script has no {', '.join(missing)} region")
        chain = [regions[n] for n in FLASH_REGIONS if n in regions]
        for before, after in zip(chain, chain[1:]):
            if after.origin != before.end:
                raise ValueError(f"the {after.name} region does not follow {before.name}")
        handoff = regions.get("HANDOFF")
        if handoff is not None and handoff.origin != regions["RAM"].end:
            raise ValueError("the HANDOFF region does not follow RAM")
        return cls(
            regions["FLASH"],
            regions["STORAGE"],
            regions["RAM"],
            regions.get("LOADER"),
            regions.get("HEADER"),
            handoff,
        )

    @classmethod
    def load(cls, path: Path | str = MEMORY_X) -> MemoryMap:
        return cls.parse(Path(path).read_text())

    @property
    def flash_base(self) -> int:
        """The start of the flash array: the loader's pages, or FLASH without a loader."""
        return (self.loader or self.header or self.flash).origin

    @property
    def flash_end(self) -> int:
        """The end of the flash array: the STORAGE pages are its last."""
        return self.storage.end

    @property
    def slot(self) -> Region:
        """The application's slot: HEADER and FLASH (FLASH alone without a header)."""
        start = (self.header or self.flash).origin
        return Region("SLOT", start, self.flash.end - start)

    @property
    def sram(self) -> Region:
        """The chip's SRAM: RAM and the HANDOFF words after it."""
        end = self.handoff.end if self.handoff else self.ram.end
        return Region("SRAM", self.ram.origin, end - self.ram.origin)


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
    the memory map it was linked for, its kind (`LOADER` or `APPLICATION`, by where its
    vector table is) and the flash region it lives in (`region`)."""

    def __init__(self, path: str, memory: MemoryMap | None = None) -> None:
        self.path = str(path)
        self.memory = memory or MemoryMap.load()
        with open(path, "rb") as f:
            elf = ELFFile(f)
            segments = [
                (seg["p_paddr"], seg.data())
                for seg in elf.iter_segments()
                if seg["p_type"] == "PT_LOAD" and seg["p_filesz"] > 0
            ]
            symbols: dict[str, int] = {}
            sizes: dict[str, int] = {}
            symtab = elf.get_section_by_name(".symtab")
            if symtab is None:
                raise ValueError(f"{path} has no symbol table")
            for sym in symtab.iter_symbols():
                if sym.name:
                    symbols.setdefault(sym.name, sym["st_value"])
                    sizes.setdefault(sym.name, sym["st_size"])
            section = elf.get_section_by_name(".vector_table")
            if section is None:
                raise ValueError(f"{path} has no .vector_table")
            table_address = section["sh_addr"]
            data = section.data()
            # Static RAM: the allocated sections the linker placed in RAM (.data, .bss, ...).
            statics = [
                (sec.name, sec["sh_addr"], sec["sh_size"])
                for sec in elf.iter_sections()
                if sec["sh_flags"] & SHF_ALLOC
                and sec["sh_size"] > 0
                and sec["sh_addr"] in self.memory.ram
            ]
        self._setup(segments, symbols, sizes, statics, table_address, data)

    @classmethod
    def from_segments(
        cls, segments: list[tuple[int, bytes]], table_address: int, memory: MemoryMap
    ) -> Image:
        """An image of raw bytes at their addresses (no symbols, no static RAM), its vector
        table at `table_address`: a hand-assembled test program, a binary file. Checked as
        an ELF is."""
        image = cls.__new__(cls)
        image.path = f"<{len(segments)} segments>"
        image.memory = memory
        table = next(
            (
                data[table_address - a :]
                for a, data in segments
                if a <= table_address < a + len(data)
            ),
            None,
        )
        if table is None:
            raise ValueError(f"no segment holds the vector table at {table_address:#x}")
        image._setup(segments, {}, {}, [], table_address, table[: 4 * 16])
        return image

    def _setup(self, segments, symbols, sizes, statics, table_address: int, data: bytes) -> None:
        self.segments: list[tuple[int, bytes]] = segments
        self.symbols: dict[str, int] = symbols
        self.sizes: dict[str, int] = sizes
        self.statics: list[tuple[str, int, int]] = statics
        self.table_address = table_address
        # Index = exception number; [0] is the initial SP.
        self.vectors = [int.from_bytes(data[i : i + 4], "little") for i in range(0, len(data), 4)]
        self.initial_sp = self.vectors[0]
        self._check()
        default = self.symbols.get("DefaultHandler")
        self.handlers: dict[int, str] = {}
        for exception, vector in enumerate(self.vectors):
            if exception < 2 or vector == 0:
                continue
            if default is not None and vector & ~1 == default & ~1:
                continue
            self.handlers[exception] = self._name(exception, vector & ~1)
        self._functions: list[tuple[int, str]] | None = None

    def _check(self) -> None:
        memory = self.memory
        path = self.path
        if self.table_address == memory.flash.origin:
            self.kind, self.region = APPLICATION, memory.slot
        elif memory.loader is not None and self.table_address == memory.loader.origin:
            self.kind, self.region = LOADER, memory.loader
        else:
            where = "FLASH's" + (" or LOADER's" if memory.loader else "")
            raise ValueError(f"{path}: the vector table is not at {where} origin")
        try:
            check_stack_layout(memory, self.initial_sp, self.statics)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        region = self.region
        for address, data in self.segments:
            if address not in region or address + len(data) > region.end:
                raise ValueError(f"{path}: a load segment at {address:#x} is outside {region.name}")

    def pages(self, page_size: int = PAGE_SIZE) -> list[int]:
        """The addresses of the flash pages its segments cover (what a probe erases)."""
        pages = set()
        for address, data in self.segments:
            first = address - address % page_size
            pages.update(range(first, address + len(data), page_size))
        return sorted(pages)

    def _name(self, exception: int, address: int) -> str:
        names = [n for n, a in self.symbols.items() if a & ~1 == address and not n.startswith("$")]
        # Prefer the vector's own name (e.g. EXTI9_5) over aliases and mangled names.
        plain = sorted(n for n in names if n.isidentifier() and not n.startswith("_"))
        return plain[0] if plain else f"exception {exception}"

    def function_at(self, address: int) -> str:
        """The name of the function symbol that contains `address` (demangled roughly)."""
        if self._functions is None:
            region = self.region
            self._functions = sorted(
                (a & ~1, n) for n, a in self.symbols.items() if self.sizes.get(n) and a in region
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
