"""The shell: options, pins, and the whole component on python-can's in-process `virtual`
bus against a python-canopen `LocalNode` standing in for the device (its SDO server, the
test sending the feed records), with the `hal` stand-in of fake_hal.py."""

import threading
import time
from pathlib import Path

import can
import canopen
import pytest

import fake_hal
from canopen_handwheel import component, core

ROOT = Path(__file__).resolve().parents[2]
NODE = 16


def test_shipped_eds_is_the_repository_one():
    shipped = Path(component.default_eds())
    repo = ROOT / "eds" / "handwheel.eds"
    if not repo.exists():
        pytest.skip("not in the repository")
    assert shipped.read_bytes() == repo.read_bytes(), (
        "copy eds/handwheel.eds to host/src/canopen_handwheel/"
    )


def test_defaults_and_option_errors(capsys):
    a = component.parse_args([])
    assert (a.interface, a.channel, a.node, a.name, a.scale) == (
        "socketcan",
        "can0",
        16,
        "handwheel",
        0.001,
    )
    cfg = component.config_from(a)
    assert (cfg.axes, cfg.master) == ("xyzwv", 1)
    assert cfg.consumer_timeout_ms == 500 and cfg.stale_after == pytest.approx(0.3)
    assert cfg.max_detents_per_s == 2000
    cfg = component.config_from(component.parse_args(["--max-detents-per-s", "800"]))
    assert cfg.max_detents_per_s == 800
    for bad in (
        ["--master-node", "16"],
        ["--axes", "xq"],
        ["--node", "0"],
        ["--scale", "0"],
        ["--scale", "nan"],
        ["--scale", "inf"],
        ["--heartbeat-ms", "5"],
        ["--event-timer-ms", "70000"],
        ["--max-detents-per-s", "0"],
        ["--max-detents-per-s", "many"],
    ):
        with pytest.raises(SystemExit):
            component.parse_args(bad)


def test_pins_have_the_table_types():
    pins = component.HalPins(
        fake_hal,
        "hw",
        component.config_from(component.parse_args(["--axes", "xz", "--scale", "0.01"])),
    )
    comp = pins.comp
    assert comp.is_ready and comp.name == "hw"
    assert comp.types["axis.x.jog-counts"] == "s32" and comp.dirs["enable"] == "in"
    assert comp["axis.z.jog-scale"] == 0.01 and comp["axis.z.jog-vel-mode"] is False
    assert set(comp.pins) == {n for n, _, _ in core.pin_table("xz")}
    c = core.Core(core.Config(axes="xz"))
    pins.write(c.pins())  # every value fits its pin's type


class Device:
    """A stand-in device on the virtual bus: python-canopen's SDO server (LocalNode with the
    EDS) and a recorder of what the component sends."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(self.bus)
        self.frames = []
        self.lock = threading.Lock()
        rec = self

        class Rec(can.Listener):
            def on_message_received(self, msg):
                with rec.lock:
                    rec.frames.append((msg.arbitration_id, bytes(msg.data)))

        self.network.listeners.append(Rec())
        self.node = canopen.LocalNode(NODE, component.default_eds())
        self.network.add_node(self.node)
        self.network.connect()
        self.seq = 0

    def seen(self, cob_id, data=None):
        with self.lock:
            return [d for (i, d) in self.frames if i == cob_id and (data is None or d == data)]

    def record(self, position, axis=1, mult=1, status=0, epoch=0):
        self.seq = (self.seq + 1) & 0xFF
        status |= epoch << 5
        self.network.send_message(
            0x180 + NODE,
            (position & 0xFFFFFFFF).to_bytes(4, "little") + bytes([axis, mult, status, self.seq]),
        )

    def close(self):
        self.network.disconnect()


def wait(pred, timeout=5.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f"no {what} within {timeout} s"
        time.sleep(0.01)


def test_component_on_a_virtual_bus(tmp_path):
    channel = f"hw-{time.monotonic_ns()}"
    dev = Device(channel)
    made = {}

    class Hal:  # fake_hal, keeping the component it makes
        def __getattr__(self, name):
            return getattr(fake_hal, name)

        def component(self, name):
            made["comp"] = fake_hal.component(name)
            return made["comp"]

    args = component.parse_args(
        ["--interface", "virtual", "--channel", channel, "--axes", "xyz", "--name", "hw"]
    )
    dev.node.sdo[0x2000].raw = 1  # left on by a component before this one
    stop = threading.Event()
    thread = threading.Thread(
        target=component.run, args=(args,), kwargs=dict(hal_module=Hal(), stop=stop), daemon=True
    )
    thread.start()
    try:
        # Heartbeat of master 1 first, then the consumer entry, feed off and NMT start.
        wait(lambda: dev.seen(0x701, b"\x05"), what="master heartbeat")
        wait(lambda: dev.seen(0x000, bytes([1, NODE])), what="NMT start")
        assert dev.node.sdo[0x1016][1].raw == 0x0001_01F4
        assert dev.node.sdo[0x2000].raw == 0
        comp = made["comp"]
        # Records with the feed off; enable pin off: nothing to write.
        dev.record(100, epoch=2)
        wait(lambda: comp["connected"], what="connected")
        assert comp["axis"] == 1 and comp["position"] == 100 and not comp["feed-enabled"]
        comp["enable"] = True
        wait(lambda: dev.node.sdo[0x2000].raw == 1, what="0x2000 = 1")
        dev.record(100, status=1, epoch=3)
        dev.record(103, status=1, epoch=3)
        dev.record(93, status=1, epoch=3)
        wait(lambda: comp["axis.x.jog-counts"] == -7, what="x counts")
        assert comp["axis.x.jog-enable"] and not comp["axis.y.jog-enable"]
        assert comp["halui.axis.x.select"] and comp["feed-enabled"]
        # Bad data: a short record, an unknown axis, a jump no wheel makes.
        dev.network.send_message(0x180 + NODE, b"\x01\x02")
        dev.record(500, axis=9, status=1, epoch=3)
        wait(lambda: comp["frames-bad"] == 2, what="bad frames counted")
        assert comp["axis"] == 0 and not comp["axis.x.jog-enable"]
        dev.record(93, status=1, epoch=3)
        dev.record(1_000_093, status=1, epoch=3)
        wait(lambda: comp["frames-bad"] == 3, what="implausible motion counted")
        assert comp["axis.x.jog-counts"] == -7
        # EMCY shown and cleared.
        dev.network.send_message(0x080 + NODE, bytes.fromhex("3081110100000000"))
        wait(lambda: comp["emcy-code"] == 0x8130, what="EMCY code")
        dev.network.send_message(0x080 + NODE, bytes(8))
        wait(lambda: comp["emcy-code"] == 0, what="EMCY reset")
        # Silence: disconnected within three periods.
        dev.record(500, axis=2, status=1, epoch=4)
        wait(lambda: comp["halui.axis.y.select"], what="y selected")
        t0 = time.monotonic()
        wait(lambda: not comp["connected"], what="disconnect")
        assert time.monotonic() - t0 < 0.5
        assert not comp["axis.y.jog-enable"]
        # Enable off: 0x2000 = 0.
        dev.record(500, axis=2, status=1, epoch=4)
        comp["enable"] = False
        wait(lambda: dev.node.sdo[0x2000].raw == 0, what="0x2000 = 0")
    finally:
        stop.set()
        thread.join(5)
        dev.close()
    assert not thread.is_alive()
    assert made["comp"].exited


def test_readme_pin_table_is_the_components():
    readme = ROOT / "README.md"
    if not readme.exists():
        pytest.skip("not in the repository")
    text = readme.read_text()
    section = text[text.index("## Use with LinuxCNC") :]
    section = section[: section.index("\n## ", 5)]
    rows = {
        line.split("|")[1].strip().strip("`"): (
            line.split("|")[2].strip(),
            line.split("|")[3].strip(),
        )
        for line in section.splitlines()
        if line.startswith("| `N.")
    }
    expected = {"N." + n.replace("{L}", "L"): (t, d) for n, t, d, _ in core.AXIS_PINS}
    expected.update({"N." + n: (t, d) for n, t, d, _ in core.COMPONENT_PINS})
    assert rows == expected
