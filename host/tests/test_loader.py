"""The component with a device in its resident loader (issue 36): the core's decisions, the
configuration's shell steps, and the component on the virtual bus with a loader that is then
replaced by the application's boot-up (an update), as after a device reset."""

import time

import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fake_hal
from canopen_handwheel import component, core
from canopen_handwheel.core import Configure, Configured
from records import EN, HB, TPDO1, rec
from test_component import NODE, Device, FakeLink, FakeSdo, Running, SlcanDevice, wait
from test_core import Run, result

LOADER = Configured(loader=True)


def loader_found(r: Run, first_reply_at=None):
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure)
    r.c.done(a, True, None, r.at(0.01), Configured(loader=True, first_reply_at=first_reply_at))
    return a


def test_a_device_in_its_loader_is_reported_and_left_alone():
    """The first configuration finds the loader: the pin and one log line; no session,
    nothing asked of the device again (an SDO request could break a download under way),
    whatever time passes or heartbeats come."""
    r = Run(configured=False)
    loader_found(r)
    assert r.c.in_loader and r.c.pins().in_loader and not r.c.configured
    assert r.c.shutdown_action() is None  # nothing to disable; no request at exit
    log = r.c.take_log()
    assert len(log) == 1 and "node 16 is in its loader" in log[0] and "no jogging" in log[0]
    for _ in range(50):
        r.hb(core.PRE_OPERATIONAL, dt=1.0)
        assert r.c.next_action(r.at()) is None
    assert r.c.take_log() == [] and r.c.pins().state == core.PRE_OPERATIONAL
    assert not r.c.pins().connected and not any(r.c.pins().jog_enable.values())


def test_the_applications_boot_up_after_an_update_configures_it_again():
    r = Run(configured=False)
    loader_found(r)
    r.c.take_log()
    r.hb(core.BOOTUP, dt=5.0)  # the new application
    assert r.c.pins().in_loader  # until the device says otherwise
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure)
    r.c.done(a, True, None, r.at(), result(a))
    assert r.c.configured and not r.c.in_loader and not r.c.pins().in_loader
    assert r.c.take_log() == ["the device runs its application again (it left its loader)"]
    r.c.set_enable(True)
    r.record(100, flags=EN)
    r.record(103, flags=EN)
    assert r.counts()["x"] == 3  # jogging as before


def test_a_loader_boot_up_makes_the_same_check_and_stays_in_the_loader():
    """A reset of the loader (or a failed start): boot-up, the check again, still the loader:
    logged only once per stay."""
    r = Run(configured=False)
    loader_found(r)
    r.c.take_log()
    r.hb(core.BOOTUP, dt=1.0)
    loader_found(r)
    assert r.c.in_loader and r.c.take_log() == []


def test_a_loader_answer_from_before_a_boot_up_is_asked_again():
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    first = r.at(0.005)
    r.hb(core.BOOTUP)
    r.c.done(a, True, None, r.at(0.02), Configured(loader=True, first_reply_at=first))
    assert not r.c.in_loader and isinstance(r.c.next_action(r.at()), Configure)


def test_a_record_or_a_reopened_bus_asks_a_loader_again():
    """Signs that an application may run although its boot-up was not seen: a feed record
    (a loader sends none), or the component's own bus coming back."""
    r = Run(configured=False)
    loader_found(r)
    r.record(5, flags=EN)
    assert isinstance(r.c.next_action(r.at()), Configure)
    r = Run(configured=False)
    loader_found(r)
    r.c.reconnected(r.at(1.0))
    assert isinstance(r.c.next_action(r.at()), Configure)
    # Without the loader, a reconnect changes nothing.
    r = Run()
    r.c.reconnected(r.at(1.0))
    assert r.c.next_action(r.at()) is None


def test_a_configured_device_reset_into_its_loader_unseen_is_found():
    """The device went into its loader without the component seeing the boot-up: the
    loader's Pre-operational heartbeat drops the session; the configuration finds BOOT."""
    r = Run()
    r.c.set_enable(True)
    r.record(0)
    r.record(2)
    assert r.counts()["x"] == 2
    r.hb(core.PRE_OPERATIONAL, dt=0.5)
    assert not r.c.configured
    loader_found(r)
    assert r.c.pins().in_loader and not any(r.c.pins().jog_enable.values())


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["rec", "hb", "tick"]),
            st.integers(-1000, 1000),
            st.integers(0, 7),
            st.integers(0, 255),
        ),
        max_size=60,
    )
)
def test_nothing_is_credited_while_the_device_is_in_its_loader(events):
    """Whatever frames arrive while the core holds the device for its loader (records of
    any session, heartbeats other than a boot-up), no count moves and no gate opens."""
    r = Run(configured=False)
    r.c.set_enable(True)
    loader_found(r)
    for kind, position, session, byte in events:
        if kind == "rec":
            r.frame(TPDO1, rec(position, 1 + byte % 5, 1, EN, byte, 1 + byte % 7, session))
        elif kind == "hb" and byte & 0x7F:
            r.frame(HB, bytes([byte]))
        else:
            r.c.tick(r.at(byte / 100))
        action = r.c.next_action(r.at())
        if action is not None:  # a record asked it again: still the loader
            assert isinstance(action, Configure)
            r.c.done(action, True, None, r.at(), Configured(loader=True))
        pins = r.c.publish(r.at())[-1]
        assert set(pins.jog_counts.values()) == {0}
        assert not any(pins.jog_enable.values()) and pins.in_loader


# The shell's configuration ----------------------------------------------------------------------


class LoaderSdo(FakeSdo):
    """A loader's object dictionary: no 0x2002 (abort "object does not exist")."""

    def upload(self, index, sub):
        if (index, sub) not in self.objects:
            self.log.append(("upload", index, sub))
            raise canopen.SdoAbortedError(0x0602_0000)
        return super().upload(index, sub)


def test_the_configuration_reads_0x1000_when_0x2002_is_refused(capfd):
    sdo = LoaderSdo({(0x1000, 0): (core.LOADER_DEVICE_TYPE, 4)})
    action = core.Configure(1, 500, None, tokens=(1,))
    ok, abort, report = component.carry_out(FakeLink(sdo), NODE, action)
    assert ok and abort is None and report == Configured(first_reply_at=1.5, loader=True)
    assert sdo.log == [("upload", 0x2002, 0), ("upload", 0x1000, 0)]
    assert capfd.readouterr().err == ""


def test_a_refused_0x2002_of_an_application_fails_as_before(capfd):
    sdo = LoaderSdo({(0x1000, 0): (0x0000_0191, 4)})
    ok, abort, report = component.carry_out(
        FakeLink(sdo), NODE, core.Configure(1, 500, None, tokens=(1,))
    )
    assert not ok and abort == 0x0602_0000 and not report.loader
    assert "configuring the device: SDO abort 0x06020000" in capfd.readouterr().err


def test_an_application_is_configured_with_no_0x1000_read():
    sdo = FakeSdo(dict(SlcanDevice.OBJECTS))
    ok, _, report = component.carry_out(
        FakeLink(sdo), NODE, core.Configure(1, 500, None, tokens=(1,))
    )
    assert ok and not report.loader and ("upload", 0x1000, 0) not in sdo.log


# The component on the virtual bus ----------------------------------------------------------------


class LoaderNode:
    """A loader on the virtual bus: python-canopen's SDO server with the loader's objects
    only (0x1000 = BOOT, 0x1018, 0x1F51, 0x1F56, 0x1F57), its boot-up and heartbeats."""

    def __init__(self, channel: str) -> None:
        import can
        from canopen import objectdictionary as odm

        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(self.bus)
        od = odm.ObjectDictionary()
        var = odm.ODVariable("device type", 0x1000)
        var.data_type, var.access_type, var.default = odm.UNSIGNED32, "ro", core.LOADER_DEVICE_TYPE
        od.add_object(var)
        for index, dt, value in ((0x1F51, odm.UNSIGNED8, 0), (0x1F57, odm.UNSIGNED32, 2)):
            record = odm.ODRecord(f"0x{index:04X}", index)
            var = odm.ODVariable("value", index, 1)
            var.data_type, var.access_type, var.default = dt, "rw", value
            record.add_member(var)
            od.add_object(record)
        self.node = canopen.LocalNode(NODE, od)
        self.network.add_node(self.node)
        self.requests = []  # the SDO requests it received
        self.network.subscribe(0x600 + NODE, lambda i, d, t: self.requests.append(bytes(d)))
        self.network.connect()

    def send(self, state: int) -> None:
        self.network.send_message(0x700 + NODE, bytes([state]))

    def close(self) -> None:
        self.network.disconnect()


def test_the_component_reports_a_loader_then_reconnects_after_an_update(capfd):
    channel = f"hwl-{time.monotonic_ns()}"
    loader = LoaderNode(channel)
    running = Running(channel)
    comp = running.comp
    app = None
    try:
        loader.send(core.BOOTUP)
        wait(lambda: comp["in-loader"], what="in-loader")
        loader.send(core.PRE_OPERATIONAL)
        wait(lambda: comp["state"] == core.PRE_OPERATIONAL, what="the loader's heartbeat")
        assert not comp["connected"]
        # 0x2002 (refused), 0x1000: then nothing more asked of a loader, whatever the time.
        assert [r[:4] for r in loader.requests] == [
            bytes([0x40, 0x02, 0x20, 0]),
            b"\x40\x00\x10\x00",
        ]
        time.sleep(1.2)
        assert len(loader.requests) == 2
        loader.close()
        loader = None
        # The update started the application: its boot-up, then the component configures it.
        app = Device(channel)
        app.network.send_message(0x700 + NODE, bytes([core.BOOTUP]))
        wait(lambda: app.seen(0x000, bytes([1, NODE])), what="NMT start")
        wait(lambda: not comp["in-loader"], what="in-loader false")
        comp["enable"] = True
        wait(lambda: app.record(0, epoch=1) or comp["connected"], what="connected")
    finally:
        running.end()
        if loader is not None:
            loader.close()
        if app is not None:
            app.close()
    err = capfd.readouterr().err
    assert err.count("is in its loader") == 1 and "0x2000 not written" not in err
    assert "the device runs its application again" in err
    requests = [line for line in err.splitlines() if "configuring the device: SDO abort" in line]
    assert requests == []


@pytest.mark.parametrize("pin", ["in-loader"])
def test_the_pin_exists_from_the_start(pin):
    """False until a configuration finds the loader."""
    args = component.parse_args(["--axes", "xz"])
    pins = component.HalPins(fake_hal, "hwp", component.config_from(args))
    assert pins.comp[pin] is False
