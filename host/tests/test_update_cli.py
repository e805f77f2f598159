"""`canopen-handwheel update` as a whole: its options, the file refused before the bus, and
the update through python-canopen on python-can's virtual bus against the device model of
program_device.py behind python-canopen's SDO server (segmented download, aborts, boot-ups
after the answer as the device sends them)."""

import io
import threading
import time

import can
import canopen
import pytest
from canopen import objectdictionary as odm

from canopen_handwheel import bus, cli, update, update_cli
from program_device import PRE_OPERATIONAL, TRIAL_FAILS, Abort, ProgramDevice, update_file

NODE = 16
OLD = update_file(3)
NEW = update_file(4, size=2000)


class BusDevice:
    """`ProgramDevice` on the virtual bus `channel`: every read and write of its objects goes
    to the model; a write that resets the device is answered first, then the boot-up."""

    def __init__(self, channel: str, model: ProgramDevice, damage: bool = False) -> None:
        self.model = model
        self.damage = damage
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(self.bus)
        od = odm.ObjectDictionary()
        for index, dt in ((0x1000, odm.UNSIGNED32), (0x2000, odm.UNSIGNED8)):
            var = odm.ODVariable(f"0x{index:04X}", index)
            var.data_type, var.access_type = dt, "rw"
            od.add_object(var)
        for index, subs in (
            (0x1018, {1: odm.UNSIGNED32, 2: odm.UNSIGNED32, 3: odm.UNSIGNED32}),
            (0x1F50, {1: odm.DOMAIN}),
            (0x1F51, {1: odm.UNSIGNED8}),
            (0x1F56, {1: odm.UNSIGNED32}),
            (0x1F57, {1: odm.UNSIGNED32}),
        ):
            record = odm.ODRecord(f"0x{index:04X}", index)
            for sub, dt in subs.items():
                var = odm.ODVariable("value", index, sub)
                var.data_type, var.access_type = dt, "rw"
                record.add_member(var)
            od.add_object(record)
        self.node = canopen.LocalNode(NODE, od)
        self.node.add_read_callback(self._read)
        self.node.add_write_callback(self._write)
        self.network.add_node(self.node)
        self.network.subscribe(0x000, self._nmt)
        self.network.connect()

    def _nmt(self, can_id, data, timestamp) -> None:
        if len(data) == 2 and data[1] in (0, NODE) and data[0] == 0x80:
            self.model.nmt(PRE_OPERATIONAL)

    def _read(self, index, subindex, od):
        try:
            return self.model.read(index, subindex)
        except Abort as e:
            raise canopen.SdoAbortedError(e.code) from None

    def _write(self, index, subindex, od, data):
        try:
            if index == 0x1F50:
                data = bytearray(data)
                if self.damage:
                    data[700] ^= 0xFF
                self.model.download(bytes(data))
            else:
                self.model.write(index, subindex, int.from_bytes(data, "little"))
        except Abort as e:
            raise canopen.SdoAbortedError(e.code) from None
        if self.model.take_reset():
            threading.Timer(0.02, self._reset).start()

    def _reset(self) -> None:
        self.model.boot()
        self.network.send_message(0x700 + NODE, b"\x00")

    def close(self) -> None:
        self.network.disconnect()


def options(channel: str, *more: str):
    return ["--interface", "virtual", "--channel", channel, "--sdo-timeout", "0.3", *more]


def channel_name() -> str:
    return f"upd-{time.monotonic_ns()}"


def test_options_and_their_limits():
    a = update_cli.parse_args(["fw.bin"])
    assert (a.file, a.interface, a.channel, a.bitrate, a.node) == (
        "fw.bin",
        "socketcan",
        "can0",
        None,
        16,
    )
    assert (a.retries, a.sdo_timeout, a.boot_timeout, a.status_timeout) == (2, 1.0, 5.0, 10.0)
    for bad in (
        [],
        ["fw.bin", "--node", "0"],
        ["fw.bin", "--node", "128"],
        ["fw.bin", "--retries", "11"],
        ["fw.bin", "--sdo-timeout", "nan"],
        ["fw.bin", "--boot-timeout", "0"],
    ):
        with pytest.raises(SystemExit) as stopped:
            update_cli.parse_args(bad)
        assert stopped.value.code == 2


@pytest.mark.parametrize(
    "content, why",
    [(None, "cannot read"), (b"\x7fELF" + bytes(600), "not b'HWIM'"), (NEW[:-1], "the file has")],
)
def test_a_bad_file_is_refused_before_the_bus(tmp_path, monkeypatch, capsys, content, why):
    path = tmp_path / "fw.bin"
    if content is not None:
        path.write_bytes(content)
    monkeypatch.setattr(bus, "open_bus", lambda *a: pytest.fail("the bus was opened"))
    assert cli.main(["update", str(path)]) == update.EXIT_BAD_FILE == 4
    assert why in capsys.readouterr().err


def test_a_full_update_over_python_canopen(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD, status_polls=2)
    dev = BusDevice(channel, model)
    try:
        code = cli.main(["update", str(path), *options(channel)])
    finally:
        dev.close()
    out, err = capsys.readouterr()
    new_crc = update_cli.UpdateImage.parse(NEW).crc
    assert code == 0, err
    assert not model.loader and model.crc() == new_crc and model.version() == 4
    assert out.startswith("node 16 updated: version 3 -> 4, CRC 0x")
    assert out.rstrip().endswith(f"-> 0x{new_crc:08X}")
    assert "node 16 is in its loader" in err and "node 16 runs its application" in err
    assert "downloading 2512 bytes (attempt 1 of 3)" in err
    bars = [line for line in err.splitlines() if line.startswith("[")]
    assert bars[0].startswith("[....") and " 100 % 2512/2512 B" in bars[-1]
    assert len(bars) == 11  # 0 %, then every 10 % (stderr is not a terminal here)
    assert [e[:2] for e in model.log if e[0] == "download"] == [("download", 2512)]


def test_a_device_that_refuses_the_image_fails_with_codes_and_the_retry_line(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    dev = BusDevice(channel, model, damage=True)
    try:
        code = cli.main(["update", str(path), *options(channel, "--retries", "1")])
    finally:
        dev.close()
    _, err = capsys.readouterr()
    assert code == update.EXIT_FAILED == 1
    assert "the download failed 2 times" in err
    assert "SDO abort 0x08000020" in err and "code 3, data format error" in err
    assert "without a valid application" in err
    retry = f"to retry: canopen-handwheel update {path} --interface virtual --channel {channel}"
    assert retry in err and "--retries 1" in err
    assert model.loader and model.slot is None  # in the loader, answering, for the next one
    # ... which takes it.
    dev = BusDevice(channel, model)
    try:
        assert cli.main(["update", str(path), *options(channel)]) == 0
    finally:
        dev.close()
    assert not model.loader and model.version() == 4


def test_the_feed_enabled_refuses(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD, feed=1)
    dev = BusDevice(channel, model)
    try:
        code = cli.main(["update", str(path), *options(channel)])
    finally:
        dev.close()
    assert code == update.EXIT_REFUSED == 3
    err = capsys.readouterr().err
    assert "refused: node 16 has its feed enabled (0x2000 = 1)" in err
    assert "to retry" not in err and not model.loader
    assert [e for e in model.log if e[0] == "write"] == []


def test_no_device_fails_with_a_hint(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    code = update_cli.main([str(path), *options(channel, "--sdo-timeout", "0.05")])
    assert code == update.EXIT_FAILED
    err = capsys.readouterr().err
    assert "no answer from node 16 reading the device type 0x1000" in err
    assert "The device was not changed." in err and "to retry:" in err


def test_an_image_that_never_became_healthy_says_how_to_recover_not_to_retry(tmp_path, capsys):
    """The new image fails its trial boot (the loader stays with 0x1F57 code 64): exit 5,
    what happened, and the way back (a good image), never the same command again."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    crc = update_cli.UpdateImage.parse(NEW).crc
    model = ProgramDevice(OLD, health={crc: TRIAL_FAILS})
    dev = BusDevice(channel, model)
    try:
        code = cli.main(["update", str(path), *options(channel, "--trial-timeout", "1")])
    finally:
        dev.close()
    err = capsys.readouterr().err
    assert code == update.EXIT_UNHEALTHY == 5, err
    assert "unhealthy: the new image never became healthy" in err
    assert "code 64" in err and "update with a good image" in err
    assert "to retry" not in err
    assert model.loader, "the loader answers, for the good image"


def test_rescue_sends_the_loaders_request_until_it_is_answered(tmp_path, capsys):
    """`--rescue` repeats 0x1F51:1 = 0 until it is answered (here by the application, which
    resets into its loader; on a board that never answers, by the loader's window at the
    power-on), then updates."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    dev = BusDevice(channel, model)
    try:
        code = cli.main(["update", str(path), *options(channel, "--rescue")])
    finally:
        dev.close()
    err = capsys.readouterr().err
    assert code == 0, err
    assert "rescue: switch node 16 off and on now" in err and "rescue: node 16 answered" in err
    assert not model.loader and model.version() == 4
    a = update_cli.parse_args(["fw.bin", "--rescue", "--rescue-timeout", "5"])
    assert (a.rescue, a.rescue_timeout, a.trial_timeout) == (True, 5.0, 15.0)


def test_the_progress_bar_on_a_terminal_redraws_one_line():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    now = [0.0]
    p = update_cli.Progress(700, out, clock=lambda: now[0])
    for done in range(0, 701, 7):
        now[0] += 0.01
        p.show(done)
    text = out.getvalue()
    assert text.count("\n") == 1 and text.endswith("700/700 B 1 s\n")
    assert 9 <= text.count("\r") <= 12  # at most every 0.1 s, and the last
