"""The wiring diagram and the pin maps it must agree with.

`docs/wiring/handwheel.yml` (WireViz) is the one source of `docs/wiring/handwheel.svg`. This
module reads the three pin maps into `{signal: pin}`: the firmware's (the table in the module
doc of `crates/handwheel-board/src/pins.rs`, the single source of the pin map), the README's
("Pin map") and
the diagram's (the board connector's pins and labels); and it stamps the SVG with a digest of
the YAML it was rendered from, so that a stale picture is found without Graphviz.

Standard library only: `render.py` and `test_wiring.py` add WireViz and PyYAML.
"""

from __future__ import annotations

import hashlib
import html
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE_PINS = ROOT / "crates" / "handwheel-board" / "src" / "pins.rs"
# The code that sets the DIP switch's pins up (the board crate's `read_dip_switch!`), and the
# two images that must read the same node-ID and bit rate through it.
DIP_CODE = FIRMWARE_PINS
IMAGES = {
    "application": ROOT / "src" / "board" / "mod.rs",
    "loader": ROOT / "loader" / "src" / "main.rs",
}
# How an image reads the DIP switch: the board crate's macro, and nothing of its own.
DIP_READ = "handwheel_board::read_dip_switch!(gpiob)"
README = ROOT / "README.md"
SOURCE = ROOT / "docs" / "wiring" / "handwheel.yml"
SVG = ROOT / "docs" / "wiring" / "handwheel.svg"
# The board's designator in the YAML.
BOARD = "X1"

# An STM32F103 port pin: PA0..PE15.
PORT_PIN = re.compile(r"P[A-E](?:1[0-5]|[0-9])")
# The line `render.py` puts into the SVG, and the test reads back.
STAMP = "<!-- wiring source: docs/wiring/handwheel.yml sha256 {digest} -->"
STAMP_RE = re.compile(r"<!-- wiring source: docs/wiring/handwheel\.yml sha256 ([0-9a-f]{64}) -->")


class PinMapError(ValueError):
    """A pin table that cannot be read as one signal per pin."""


def table_rows(lines: list[str]) -> list[list[str]]:
    """The body rows (cells stripped) of the first Markdown table in `lines` whose header
    starts `| signal | pin |`."""
    rows = None
    for line in lines:
        text = line.strip()
        if not text.startswith("|"):
            if rows is not None:
                break
            continue
        cells = [c.strip() for c in text.strip("|").split("|")]
        if rows is None:
            if [c.lower() for c in cells[:2]] == ["signal", "pin"]:
                rows = []
            continue
        if all(set(c) <= set("-: ") for c in cells):
            continue  # the separator row
        rows.append(cells)
    if not rows:
        raise PinMapError("no `| signal | pin |` table found")
    return rows


def expand_row(signal: str, pins: str) -> list[tuple[str, str]]:
    """One table row as (signal, pin) pairs.

    The signal cell names one signal or a group: `CAN RX / TX` (the last word of the first
    item varies), `axis X, Y, Z, W, V`, `DIP 1..5 (...)` or `DIP 1-5: ...` (a numbered
    range); parentheses and anything after a colon are comments. The pin cell lists as many
    pins, separated by `,` or `/`. A single name with several pins (the README's `SWD`) is
    kept as one entry whose pin is the list joined by ` / `.
    """
    name = re.sub(r"\s*\([^)]*\)", "", signal).split(":")[0].strip()
    pin_list = [p.strip() for p in re.split(r"[,/]", pins)]
    for pin in pin_list:
        if not PORT_PIN.fullmatch(pin):
            raise PinMapError(f"row `{signal} | {pins}`: `{pin}` is not a port pin")
    numbered = re.fullmatch(r"(.*\S)\s+(\d+)\s*(?:-|\.\.)\s*(\d+)", name)
    if numbered:
        first, last = int(numbered[2]), int(numbered[3])
        names = [f"{numbered[1]} {n}" for n in range(first, last + 1)]
    elif re.search(r"[,/]", name):
        parts = [p.strip() for p in re.split(r"[,/]", name)]
        prefix, first_item = parts[0].rsplit(" ", 1)
        names = [f"{prefix} {item}" for item in [first_item, *parts[1:]]]
    else:
        names = [name]
    if len(names) == 1 and len(pin_list) > 1:
        return [(names[0], " / ".join(pin_list))]
    if len(names) != len(pin_list):
        raise PinMapError(f"row `{signal} | {pins}`: {len(names)} signals but {len(pin_list)} pins")
    return list(zip(names, pin_list))


def pin_map(rows: list[list[str]]) -> dict[str, str]:
    """`{signal: pin}` from table rows; a signal or pin named twice is an error."""
    result: dict[str, str] = {}
    owner: dict[str, str] = {}
    for row in rows:
        if len(row) < 2:
            raise PinMapError(f"row {row}: fewer than two cells")
        for signal, pin in expand_row(row[0], row[1]):
            if signal in result:
                raise PinMapError(f"signal `{signal}` named twice")
            if pin in owner:
                raise PinMapError(f"pin {pin} carries `{owner[pin]}` and `{signal}`")
            result[signal] = pin
            owner[pin] = signal
    return result


def firmware_pin_map(rust_source: str) -> dict[str, str]:
    """The pin map in the module doc (`//!` lines) of `crates/handwheel-board/src/pins.rs`."""
    doc = [line.strip()[3:] for line in rust_source.splitlines() if line.strip().startswith("//!")]
    return pin_map(table_rows(doc))


def dip_pins_in_code(rust_source: str) -> list[str]:
    """The DIP switch's pins as the code sets them up, switch 1 first: the pins of the
    `let dip_pins = [...]` array (`gpiob.pb12.into_pull_up_input(...)`, ...)."""
    array = re.search(r"let dip_pins = \[(.*?)\];", rust_source, re.S)
    if array is None:
        raise PinMapError("no `let dip_pins = [...]` array")
    return [f"P{port.upper()}{n}" for port, n in re.findall(r"\bgpio([a-e])\.p\1(\d+)\.", array[1])]


def reads_dip_switch_through_the_board(rust_source: str) -> bool:
    """Whether an image's code reads the DIP switch with the board crate's macro and sets up
    no DIP pin array of its own."""
    return DIP_READ in rust_source and "let dip_pins" not in rust_source


def readme_pin_map(readme: str) -> dict[str, str]:
    """The table of the README's "Pin map" section (a heading of any level)."""
    lines = readme.splitlines()
    for i, line in enumerate(lines):
        if re.match(r"#+ Pin map\b", line):
            level = len(line) - len(line.lstrip("#"))
            section = []
            for following in lines[i + 1 :]:
                heading = re.match(r"(#+) ", following)
                if heading and len(heading[1]) <= level:
                    break
                section.append(following)
            return pin_map(table_rows(section))
    raise PinMapError('the README has no "Pin map" heading')


def diagram_pin_map(harness: dict) -> dict[str, str]:
    """`{label: pin}` of the board connector's port pins in the parsed WireViz YAML (power
    pins such as 5V, 3V3 and GND carry no signal and are left out)."""
    board = harness["connectors"][BOARD]
    pins = [str(p) for p in board["pins"]]
    labels = [str(label) for label in board.get("pinlabels", [])]
    if len(labels) != len(pins):
        raise PinMapError(f"{BOARD}: {len(pins)} pins but {len(labels)} pinlabels")
    result: dict[str, str] = {}
    for pin, label in zip(pins, labels):
        if PORT_PIN.fullmatch(pin):
            if label in result:
                raise PinMapError(f"{BOARD}: `{label}` on {result[label]} and {pin}")
            result[label] = pin
    return result


def differences(expected: dict[str, str], actual: dict[str, str]) -> list[str]:
    """What `actual` gets wrong against `expected`, one line per signal (empty: they agree)."""
    lines = []
    for signal in sorted(expected.keys() | actual.keys()):
        want, got = expected.get(signal), actual.get(signal)
        if want != got:
            lines.append(f"{signal}: {want or 'absent'} expected, {got or 'absent'} found")
    return lines


def digest(source: str) -> str:
    """SHA-256 of the YAML text (line endings normalised)."""
    return hashlib.sha256(source.replace("\r\n", "\n").encode("utf-8")).hexdigest()


def stamp(svg: str, source_digest: str) -> str:
    """`svg` with the stamp line after its XML declaration (an older stamp is replaced)."""
    svg = re.sub(STAMP_RE.pattern + r"\n?", "", svg)
    line = STAMP.format(digest=source_digest)
    if svg.startswith("<?xml"):
        end = svg.index("?>") + 2
        return f"{svg[:end]}\n{line}{svg[end:]}"
    return f"{line}\n{svg}"


def svg_digest(svg: str) -> str | None:
    """The digest stamped into `svg`, or None."""
    match = STAMP_RE.search(svg)
    return match[1] if match else None


def svg_texts(svg: str) -> set[str]:
    """Every `<text>` element's content in a Graphviz SVG, unescaped."""
    return {html.unescape(t) for t in re.findall(r"<text\b[^>]*>(.*?)</text>", svg, re.S)}
