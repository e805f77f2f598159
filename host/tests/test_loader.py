"""The component with a device in its resident loader (docs/FIRMWARE-UPDATE.md): the core's
decisions, the configuration's shell steps, and the component on the virtual bus with a loader
that is then replaced by the application's boot-up (an update), as after a device reset."""

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


# Another master's update while the component runs -------------------------------------------------

SDO_REQUEST, SDO_ANSWER = 0x600 + NODE, 0x580 + NODE


def sdo_read(index: int, sub: int) -> bytes:
    return bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])


def program_control(value: int) -> bytes:
    """An expedited write of 0x1F51:1 (one byte)."""
    return bytes([0x2F, 0x51, 0x1F, 0x01, value, 0, 0, 0])


WRITTEN = bytes([0x60, 0x51, 0x1F, 0x01, 0, 0, 0, 0])
REFUSED = bytes([0x80, 0x51, 0x1F, 0x01]) + (0x0800_0022).to_bytes(4, "little")


def test_another_masters_sdo_exchange_holds_the_components_requests_back():
    """An update reads the device, then sends NMT pre-operational: the session drops, but
    the configuration (which would end with an NMT start and take the other master's
    answers) waits until that master has sent no SDO request for FOREIGN_SDO_QUIET; logged
    once."""
    r = Run()
    r.frame(SDO_REQUEST, sdo_read(0x1000, 0))
    r.hb(core.PRE_OPERATIONAL, dt=0.05)
    assert not r.c.configured
    for _ in range(60):  # 3 s of requests, 0.05 s apart
        r.frame(SDO_REQUEST, sdo_read(0x1F57, 1), dt=0.05)
        assert r.c.next_action(r.at()) is None
    r.c.tick(r.at(core.FOREIGN_SDO_QUIET - 0.01))
    assert r.c.next_action(r.at()) is None
    log = r.c.take_log()
    assert sum("another master is exchanging SDO with node 16" in line for line in log) == 1
    r.c.tick(r.at(0.02))
    assert isinstance(r.c.next_action(r.at()), Configure)


def answer_read(index: int, sub: int, value: int = 0, expedited: bool = True) -> bytes:
    """The device's answer to an upload of index:sub: expedited (4 bytes), or the initiate of
    a segmented upload."""
    head = bytes([0x43 if expedited else 0x41]) + index.to_bytes(2, "little") + bytes([sub])
    return head + value.to_bytes(4, "little")


def test_another_masters_answered_read_ends_the_hold_at_once():
    """An HMI polling 0x1001 once a second: each expedited read is over with its answer, so
    the component's configuration (and its probes) never wait 2 s behind it."""
    r = Run()
    r.hb(core.PRE_OPERATIONAL, dt=0.05)
    for _ in range(3):
        r.frame(SDO_REQUEST, sdo_read(0x1001, 0), dt=1.0)
        assert r.c.next_action(r.at()) is None, "held while the read is under way"
        r.frame(SDO_ANSWER, answer_read(0x1001, 0), dt=0.001)
        assert r.c.next_action(r.at(core.FOREIGN_READ_QUIET - 0.01)) is None, "a short quiet"
        action = r.c.next_action(r.at(0.02))
        assert isinstance(action, Configure), "the read answered: free again"
        r.c.done(action, False, None, r.at())
    assert not any("another master" in line for line in r.c.take_log()), "not logged"


@pytest.mark.parametrize(
    "request_, answer, why",
    [
        (sdo_read(0x1F57, 1), answer_read(0x1F57, 1), "a program download's object"),
        (sdo_read(0x1018, 1), answer_read(0x1018, 1, expedited=False), "a segmented upload"),
        (sdo_read(0x1018, 1), answer_read(0x1018, 2), "an answer for another object"),
        (
            bytes([0x2F, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0]),
            bytes([0x60, 0x17, 0x10, 0, 0, 0, 0, 0]),
            "a write",
        ),
    ],
)
def test_other_exchanges_keep_the_hold(request_, answer, why):
    r = Run()
    r.hb(core.PRE_OPERATIONAL, dt=0.05)
    r.frame(SDO_REQUEST, request_, dt=1.0)
    r.frame(SDO_ANSWER, answer, dt=0.001)
    assert r.c.next_action(r.at(core.FOREIGN_READ_QUIET + 0.01)) is None, why
    r.c.tick(r.at(core.FOREIGN_SDO_QUIET))
    assert isinstance(r.c.next_action(r.at()), Configure)


def test_an_answer_the_component_may_be_waiting_for_keeps_the_hold():
    """Another master reads 0x2000 while the component's own 0x2000 write is under way: the
    answer may be the component's, so the hold stays."""
    r = Run()
    r.c.set_enable(True)
    r.record(0, flags=0)
    action = r.c.next_action(r.at())
    assert action == core.WriteFeed(1)
    r.frame(SDO_REQUEST, sdo_read(0x2000, 0), dt=0.001)
    r.frame(SDO_ANSWER, answer_read(0x2000, 0), dt=0.001)
    r.c.done(action, True, None, r.at())
    r.c.tick(r.at(r.c.cfg.retry))
    r.record(0, flags=0, dt=0.001)
    assert r.c.next_action(r.at()) is None
    r.c.tick(r.at(core.FOREIGN_SDO_QUIET))
    r.record(0, flags=0, dt=0.001)
    assert r.c.next_action(r.at()) == core.WriteFeed(1)


def test_the_feed_enable_waits_too():
    r = Run()
    r.c.set_enable(True)
    r.record(0, flags=0)
    r.frame(SDO_REQUEST, sdo_read(0x1018, 1))
    for _ in range(19):  # records every 0.1 s (the event timer)
        r.record(0, flags=0, dt=0.1)
        assert r.c.next_action(r.at()) is None
    r.record(0, flags=0, dt=0.1)
    assert r.c.next_action(r.at()) == core.WriteFeed(1)


def test_a_stop_confirmed_to_another_master_makes_the_next_boot_up_the_loaders():
    """0x1F51:1 = 0 written by another master and confirmed by the device: the boot-up that
    follows is the loader's (in-loader, logged, no request to it, whatever the time); the
    start (0x1F51:1 = 1) confirmed and the application's boot-up: configured once the other
    master is quiet, in-loader false, jogging again."""
    r = Run()
    r.c.set_enable(True)
    r.record(0)
    r.record(2)
    assert r.counts()["x"] == 2
    r.frame(SDO_REQUEST, sdo_read(0x2000, 0))
    r.hb(core.PRE_OPERATIONAL)
    r.frame(SDO_REQUEST, program_control(0))
    r.frame(SDO_ANSWER, WRITTEN, dt=0.001)
    r.hb(core.BOOTUP, dt=0.02)
    assert r.c.in_loader and r.c.pins().in_loader and not r.c.configured
    log = r.c.take_log()
    assert any("is in its loader (another master stopped its program" in line for line in log)
    for _ in range(40):  # the download
        r.frame(SDO_REQUEST, bytes([0x00]) + bytes(7), dt=0.05)
        assert r.c.next_action(r.at()) is None
    r.hb(core.PRE_OPERATIONAL, dt=1.0)
    r.c.tick(r.at(10.0))
    assert r.c.next_action(r.at()) is None  # a loader is never asked on a timer
    r.frame(SDO_REQUEST, program_control(1))
    r.frame(SDO_ANSWER, WRITTEN, dt=0.001)
    r.hb(core.BOOTUP, dt=0.05)
    assert not any("in its loader" in line for line in r.c.take_log())  # once per stay
    r.frame(SDO_REQUEST, sdo_read(0x1F56, 1), dt=0.01)
    assert r.c.next_action(r.at()) is None
    r.c.tick(r.at(core.FOREIGN_SDO_QUIET))
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure)
    r.c.done(a, True, None, r.at(), result(a))
    assert r.c.configured and not r.c.pins().in_loader
    r.record(10)
    r.record(13)
    assert r.counts()["x"] == 5


@pytest.mark.parametrize(
    "answer, delay",
    [(REFUSED, 0.02), (None, 0.02), (WRITTEN, core.FOREIGN_SDO_QUIET + 1.0)],
    ids=["refused", "unanswered", "boot-up long after"],
)
def test_a_boot_up_without_a_stop_just_confirmed_is_asked(answer, delay):
    """A stop the device refused or did not answer, or a boot-up long after the stop: the
    boot-up is not taken for the loader's; the component asks the device once the other
    master is quiet."""
    r = Run()
    r.frame(SDO_REQUEST, program_control(0))
    if answer is not None:
        r.frame(SDO_ANSWER, answer, dt=0.001)
    r.hb(core.BOOTUP, dt=delay)
    assert not r.c.in_loader
    r.c.tick(r.at(core.FOREIGN_SDO_QUIET))
    assert isinstance(r.c.next_action(r.at()), Configure)


def test_a_start_or_another_object_confirmed_is_no_stop():
    for request in (program_control(1), bytes([0x2F, 0x51, 0x1F, 0x02, 0, 0, 0, 0])):
        r = Run()
        r.frame(SDO_REQUEST, request)
        r.frame(SDO_ANSWER, bytes([0x60]) + request[1:4] + bytes(4), dt=0.001)
        r.hb(core.BOOTUP, dt=0.02)
        assert not r.c.in_loader


def test_the_component_beside_another_masters_stop_and_start(capfd):
    """The shell hands the SDO channel's frames to the core: on the virtual bus, another
    master stops the application (0x1F51:1 = 0, confirmed) and the device boots up: the
    component shows the loader without asking it anything while that master works; after
    its start and the boot-up, and FOREIGN_SDO_QUIET without its requests, the component
    configures and starts the application."""
    channel = f"hwm-{time.monotonic_ns()}"
    app = Device(channel)
    running = Running(channel)
    comp = running.comp
    other = canopen.Network()
    other.connect(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        node = other.add_node(NODE, canopen.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = 1.0
        wait(lambda: app.seen(0x000, bytes([1, NODE])), what="configured and started")
        mark = len(app.seen(SDO_REQUEST))
        node.sdo.upload(0x1000, 0)
        node.sdo.download(0x1F51, 1, b"\x00")
        app.network.send_message(0x700 + NODE, bytes([core.BOOTUP]))  # the loader's
        wait(lambda: comp["in-loader"], what="in-loader")
        for _ in range(20):  # its download, 1 s
            node.sdo.upload(0x1000, 0)
            time.sleep(0.05)
        node.sdo.download(0x1F51, 1, b"\x01")
        started = time.monotonic()
        app.network.send_message(0x700 + NODE, bytes([core.BOOTUP]))  # the application's
        wait(lambda: not comp["in-loader"], timeout=5, what="in-loader false")
        assert time.monotonic() - started >= core.FOREIGN_SDO_QUIET - 0.1
        wait(lambda: len(app.seen(0x000, bytes([1, NODE]))) == 2, what="NMT start")
        mine = [d for d in app.seen(SDO_REQUEST)[mark:] if d[:4] != b"\x40\x00\x10\x00"]
        assert mine[0] == program_control(0)[:5] + bytes(3)  # python-canopen's own padding
        later = [d[:4] for d in mine[1:]]
        assert later[0] == program_control(1)[:4] and later[1] == b"\x40\x02\x20\x00", later
    finally:
        other.disconnect()
        running.end()
        app.close()
    err = capfd.readouterr().err
    assert "is in its loader (another master stopped its program" in err
    assert "another master is exchanging SDO with node 16" in err
    assert "the device runs its application again" in err
