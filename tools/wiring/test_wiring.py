"""The wiring diagram against the firmware's pin map (run by `cargo xtask test` and
`cargo xtask docs --check`; no Graphviz needed).

- The firmware's pin map is the table in the module doc of
  `crates/handwheel-board/src/pins.rs`. The README's
  "Pin map" table and the board connector of `docs/wiring/handwheel.yml` must give every
  signal of it the same pin, and no other.
- Every signal's wire in the diagram ends where the hardware needs it (the transceiver's TXD
  for CAN TX, the DIP switch's pole n for DIP n, ...), as WireViz itself reads the YAML.
- The committed SVG was rendered from this YAML: its stamp is the YAML's digest, and every pin
  and pin label of the YAML is a text of the picture.
"""

from __future__ import annotations

import pytest
import yaml
from wireviz.wireviz import parse

import wiring

# Where each firmware signal's wire must end in the diagram: (connector, pin).
PEERS = {
    "CAN TX": ("U1", "D"),
    "CAN RX": ("U1", "R"),
    "wheel A": ("WHEEL", "A"),
    "wheel B": ("WHEEL", "B"),
    **{f"axis {a}": ("S1", a) for a in "XYZWV"},
    **{f"multiplier {m}": ("S2", m) for m in ("x1", "x10", "x100")},
    **{f"DIP {n}": ("S3", n) for n in range(1, 9)},
    "ERR LED": ("R1", 1),
    **{f"out {n}": ("X2", n) for n in range(1, 9)},
}
# Signals the board itself wires (the RUN LED is the Blue Pill's PC13 LED).
ON_BOARD = {"RUN LED"}
# The other wires the diagram must have, as unordered pairs of (connector, pin).
OTHER_WIRES = [
    (("X1", "5V"), ("PSU", "+5V")),
    (("X1", "GND"), ("PSU", "0V")),
    (("X1", "3V3"), ("U1", "3V3")),
    (("X1", "GND"), ("U1", "GND")),
    (("U1", "CANH"), ("BUS", "CAN_H")),
    (("U1", "CANL"), ("BUS", "CAN_L")),
    (("U1", "GND"), ("BUS", "CAN_GND")),
    (("X1", "5V"), ("WHEEL", "+5V")),
    (("X1", "GND"), ("WHEEL", "0V")),
    (("X1", "GND"), ("S1", "C")),
    (("X1", "GND"), ("S2", "C")),
    (("X1", "GND"), ("S3", "C")),
    (("R1", 2), ("D1", "A")),
    (("X1", "GND"), ("D1", "K")),
    (("X1", "GND"), ("X2", "GND")),
]


@pytest.fixture(scope="module")
def source() -> str:
    return wiring.SOURCE.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def firmware() -> dict[str, str]:
    return wiring.firmware_pin_map(wiring.FIRMWARE_PINS.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def wires(source) -> set[frozenset]:
    """Every wire and direct mate of the diagram as WireViz parses it: {end, end} pairs."""
    harness = parse(yaml.safe_load(source), return_types="harness")
    result = set()
    for cable in harness.cables.values():
        for c in cable.connections:
            assert c.from_name and c.to_name, f"{cable.name}: a wire with a free end"
            result.add(frozenset({(c.from_name, c.from_pin), (c.to_name, c.to_pin)}))
    for mate in harness.mates:
        result.add(frozenset({(mate.from_name, mate.from_pin), (mate.to_name, mate.to_pin)}))
    return result


def test_rows_of_both_table_styles_expand_to_one_signal_per_pin():
    firmware_style = wiring.pin_map(
        [
            ["CAN RX / TX", "PB8 / PB9"],
            ["axis X, Y, Z", "PA0, PA1, PA2"],
            ["DIP 6..8 (bit-rate code bits 0..2)", "PB1, PB10, PB11"],
            ["ERR LED (red)", "PB5"],
        ]
    )
    assert firmware_style == {
        "CAN RX": "PB8",
        "CAN TX": "PB9",
        "axis X": "PA0",
        "axis Y": "PA1",
        "axis Z": "PA2",
        "DIP 6": "PB1",
        "DIP 7": "PB10",
        "DIP 8": "PB11",
        "ERR LED": "PB5",
    }
    readme_style = wiring.pin_map(
        [["DIP 1-2: node-ID bits 0-1", "PB12, PB13"], ["SWD", "PA13 / PA14"]]
    )
    assert readme_style == {"DIP 1": "PB12", "DIP 2": "PB13", "SWD": "PA13 / PA14"}


@pytest.mark.parametrize(
    "rows",
    [
        [["wheel A / B", "PB6"]],  # two signals, one pin
        [["wheel A", "PB6"], ["wheel B", "PB6"]],  # one pin, two signals
        [["wheel A", "PB6"], ["wheel A", "PB7"]],  # one signal, two pins
        [["wheel A", "PB16"]],  # no such pin
    ],
)
def test_unreadable_or_ambiguous_rows_are_refused(rows):
    with pytest.raises(wiring.PinMapError):
        wiring.pin_map(rows)


def test_a_moved_pin_is_reported_by_signal():
    assert wiring.differences({"wheel A": "PB6", "wheel B": "PB7"}, {"wheel A": "PB4"}) == [
        "wheel A: PB6 expected, PB4 found",
        "wheel B: PB7 expected, absent found",
    ]


def test_firmware_table_names_the_signals_the_diagram_wires(firmware):
    assert set(firmware) == set(PEERS) | ON_BOARD


def test_readme_pin_map_is_the_firmware_pin_map(firmware):
    readme = wiring.readme_pin_map(wiring.README.read_text(encoding="utf-8"))
    # The README also shows the SWD pins, which the firmware leaves to the probe.
    assert readme.pop("SWD", None) == "PA13 / PA14"
    wrong = wiring.differences(firmware, readme)
    assert not wrong, "README pin map: " + "; ".join(wrong)


def test_diagram_board_pins_are_the_firmware_pin_map(firmware, source):
    diagram = wiring.diagram_pin_map(yaml.safe_load(source))
    wrong = wiring.differences(firmware, diagram)
    assert not wrong, "docs/wiring/handwheel.yml, board X1: " + "; ".join(wrong)


def test_every_signal_is_wired_where_the_hardware_needs_it(firmware, wires):
    board_ends = {}
    for wire in wires:
        for end in wire:
            if end[0] == wiring.BOARD:
                board_ends.setdefault(end[1], []).extend(e for e in wire if e != end)
    wrong = []
    for signal, pin in firmware.items():
        want = [] if signal in ON_BOARD else [PEERS[signal]]
        if board_ends.get(pin, []) != want:
            wrong.append(f"{signal} ({pin}): wired to {board_ends.get(pin, [])}, not {want}")
    assert not wrong, "; ".join(wrong)


def test_supply_ground_bus_and_led_wires(wires):
    missing = [pair for pair in OTHER_WIRES if frozenset(pair) not in wires]
    assert not missing, f"wires missing: {missing}"


def test_svg_was_rendered_from_this_description(source):
    svg = wiring.SVG.read_text(encoding="utf-8")
    assert wiring.svg_digest(svg) == wiring.digest(source), (
        "docs/wiring/handwheel.svg is not rendered from docs/wiring/handwheel.yml: "
        "run `cargo xtask docs`"
    )


def test_svg_shows_every_pin_and_label_of_the_description(source):
    texts = wiring.svg_texts(wiring.SVG.read_text(encoding="utf-8"))
    for name, connector in yaml.safe_load(source)["connectors"].items():
        for item in [*connector["pins"], *connector.get("pinlabels", [])]:
            assert str(item) in texts, f"{name}: `{item}` not in the SVG"


def test_stamp_replaces_an_older_one_and_reads_back():
    svg = '<?xml version="1.0"?>\n<svg><text x="1">PB6</text></svg>\n'
    once = wiring.stamp(svg, "a" * 64)
    twice = wiring.stamp(once, "b" * 64)
    assert wiring.svg_digest(once) == "a" * 64
    assert wiring.svg_digest(twice) == "b" * 64
    assert twice.count("wiring source") == 1
    assert twice.replace(wiring.STAMP.format(digest="b" * 64) + "\n", "") == svg
    assert wiring.svg_texts(twice) == {"PB6"}


def test_the_board_crate_reads_the_dip_switch_on_the_pin_maps_pins(firmware):
    code = wiring.dip_pins_in_code(wiring.DIP_CODE.read_text(encoding="utf-8"))
    assert code == [firmware[f"DIP {n}"] for n in range(1, 9)]


@pytest.mark.parametrize("image", sorted(wiring.IMAGES))
def test_both_images_read_the_dip_switch_through_the_board_crate(image):
    """The loader reads the DIP switch for the node-ID and bit rate it answers at: both
    images read it with the board crate's one macro, so a pin moved there moves in both, and
    neither has pins of its own that could stay behind."""
    source = wiring.IMAGES[image].read_text(encoding="utf-8")
    assert wiring.reads_dip_switch_through_the_board(source)
    own = source.replace(wiring.DIP_READ, "let dip_pins = [gpiob.pb12.into_pull_up_input()];")
    assert not wiring.reads_dip_switch_through_the_board(own)


def test_a_dip_pin_moved_in_the_code_is_seen():
    source = wiring.DIP_CODE.read_text(encoding="utf-8")
    moved = source.replace("gpiob.pb13.into_pull_up_input", "gpiob.pb4.into_pull_up_input")
    assert wiring.dip_pins_in_code(moved)[1] == "PB4"
    with pytest.raises(wiring.PinMapError):
        wiring.dip_pins_in_code(source.replace("let dip_pins", "let switches"))
