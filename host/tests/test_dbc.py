"""The DBC `cargo xtask dbc` writes from the object table (eds/handwheel.dbc), read by cantools
as CAN tools read it: every feed record decodes to the fields `core.Record` gives, and the
unit-step byte to what the decoder says."""

from pathlib import Path

import cantools
from hypothesis import given
from hypothesis import strategies as st

from canopen_handwheel import core, decode
from canopen_handwheel.record import Record

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "eds" / "handwheel.dbc"
NODE = 16


def database():
    return cantools.database.load_file(str(DBC))


def dbc_agrees(db, data: bytes) -> list:
    """Where cantools' decoding of the 8 bytes of a TPDO1 differs from `core.Record`'s (an
    empty list: nowhere)."""
    signals = db.get_message_by_frame_id(0x180 + NODE).decode(data, decode_choices=False)
    host = decode.record_signals(Record.decode(data))
    return [
        f"{k}: {signals.get(k)} by the DBC, {v} by Record"
        for k, v in host.items()
        if signals.get(k) != v
    ] + sorted(set(signals) - set(host))


def test_the_dbc_names_the_tpdos_of_the_default_node():
    db = database()
    tpdo1 = db.get_message_by_frame_id(0x190)
    tpdo2 = db.get_message_by_frame_id(0x290)
    assert (tpdo1.name, tpdo1.length, tpdo2.name, tpdo2.length) == ("TPDO1", 8, "TPDO2", 1)
    position = tpdo1.get_signal_by_name("PositionValue")
    assert position.is_signed and position.length == 32 and position.scale == 1
    choices = tpdo1.get_signal_by_name("Multiplier").choices
    assert {int(k): str(v) for k, v in choices.items()} == {0: "x1", 1: "x10", 2: "x100"}


@given(st.binary(min_size=8, max_size=8))
def test_every_record_decodes_as_the_host_decodes_it(data):
    assert dbc_agrees(database(), data) == []


def test_named_values_read_as_the_decoder_prints_them():
    db = database()
    data = Record(-5, 2, 10, 2, core.STATUS_ENABLED, 1, 4660).encode()
    named = db.get_message_by_frame_id(0x190).decode(data)
    assert (named["Axis"], named["Multiplier"], named["PositionValue"]) == ("Y", "x10", -5)
    assert "axis Y, x10" in decode.Describer(core.Config()).describe(
        decode.captures.Frame(0.0, 0x190, data)
    )
    step = db.get_message_by_frame_id(0x290).decode(bytes([0x1B]))
    assert (step["UnitStepAxis"], step["UnitStepForward"], step["UnitStepCounter"]) == ("W", 1, 1)
    assert decode.unit_step(0x1B) == "unit step: axis W, forward, counter 1"
