"""`canopen-handwheel update` as a whole: its options, the file refused before the bus, and
the update through python-canopen on python-can's virtual bus against the device model of
program_device.py behind python-canopen's SDO server (segmented download, aborts, boot-ups
after the answer as the device sends them), which refuses block download (0x05040001 at its
initiate, as the loader did before it had block download), or with program_device.py's
block download server in front of it (CRC-16, lost segments, aborts)."""

import io
import threading
import time
from typing import Optional

import can
import canopen
import pytest
from canopen import objectdictionary as odm

from canopen_handwheel import bus, cli, update, update_cli
from program_device import (
    PRE_OPERATIONAL,
    TRIAL_FAILS,
    Abort,
    BlockDownloadServer,
    ProgramDevice,
    crc16_xmodem,
    update_file,
)

NODE = 16
OLD = update_file(3)
NEW = update_file(4, size=2000)


class BusDevice:
    """`ProgramDevice` on the virtual bus `channel`: every read and write of its objects goes
    to the model; a write that resets the device is answered first, then the boot-up.
    python-canopen's LocalNode SDO server aborts a block download's initiate with 0x05040001;
    with `block` (a `BlockDownloadServer` into the model), the node's SDO requests go to that
    server for a block download's initiate and while its transfer runs."""

    def __init__(
        self,
        channel: str,
        model: ProgramDevice,
        damage: bool = False,
        block: Optional[BlockDownloadServer] = None,
    ) -> None:
        self.model = model
        self.damage = damage
        self.block = block
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
        if block is not None:
            self.network.unsubscribe(0x600 + NODE, self.node.sdo.on_request)
            self.network.subscribe(0x600 + NODE, self._sdo_request)
        self.network.connect()

    def _sdo_request(self, can_id, data, timestamp) -> None:
        assert self.block is not None
        if self.block.busy or data[0] & 0xE0 == 0xC0:  # a block download's (ccs 6)
            answer = self.block.request(bytes(data))
            if answer is not None:
                self.network.send_message(0x580 + NODE, answer)
        else:
            self.node.sdo.on_request(can_id, data, timestamp)

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
    assert a.sdo_transfer == update.AUTO == "auto"
    for transfer in ("auto", "block", "segmented"):
        assert update_cli.parse_args(["fw.bin", "--sdo-transfer", transfer]).sdo_transfer == (
            transfer
        )
    for bad in (
        [],
        ["fw.bin", "--sdo-transfer", "fast"],
        ["fw.bin", "--node", "0"],
        ["fw.bin", "--node", "128"],
        ["fw.bin", "--retries", "11"],
        ["fw.bin", "--sdo-timeout", "nan"],
        ["fw.bin", "--boot-timeout", "0"],
    ):
        with pytest.raises(SystemExit) as stopped:
            update_cli.parse_args(bad)
        assert stopped.value.code == 2


def test_the_help_names_the_sdo_transfer(capsys):
    with pytest.raises(SystemExit):
        update_cli.parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--sdo-transfer {auto,block,segmented}" in text
    assert "'auto', block where the device offers it, else segmented" in text


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
    # python-canopen's LocalNode has no block download: the first attempt goes segmented.
    lines = err.splitlines()
    first = lines.index(
        "canopen-handwheel update: downloading 2512 bytes by SDO block download (attempt 1 of 3)"
    )
    assert lines[first + 1 : first + 3] == [
        "canopen-handwheel update: node 16 does not offer SDO block download (its initiate "
        "answered SDO abort 0x05040001 (command specifier not valid or unknown)): downloading "
        "segmented",
        "canopen-handwheel update: downloading 2512 bytes by segmented SDO download (attempt 1 "
        "of 3)",
    ]
    assert "attempt 2" not in err
    bars = [line for line in err.splitlines() if line.startswith("[")]
    assert bars[0].startswith("[....") and " 100 % 2512/2512 B" in bars[-1]
    assert len(bars) == 11  # 0 %, then every 10 % (stderr is not a terminal here)
    assert [e[:2] for e in model.log if e[0] == "download"] == [("download", 2512)]


def test_python_canopens_local_node_refuses_block_download_at_its_initiate():
    """The premise of `auto` against BusDevice without `block`: python-canopen's LocalNode
    SDO server aborts a block download's initiate with 0x05040001, and python-canopen raises
    it from `SdoClient.open` itself (no stream: the abort came at the initiate)."""
    channel = channel_name()
    model = ProgramDevice(None)
    dev = BusDevice(channel, model)
    network = canopen.Network(can.Bus(interface="virtual", channel=channel))
    try:
        network.connect()
        node = network.add_node(canopen.RemoteNode(NODE, odm.ObjectDictionary()))
        with pytest.raises(canopen.SdoAbortedError) as refused:
            node.sdo.open(0x1F50, 1, "wb", buffering=0, size=len(NEW), block_transfer=True)
        assert refused.value.code == 0x0504_0001
    finally:
        network.disconnect()
        dev.close()
    assert model.log == []


def block_server(model: ProgramDevice, **faults) -> BlockDownloadServer:
    return BlockDownloadServer(0x1F50, 1, model.download, **faults)


def run_update(channel: str, model: ProgramDevice, path, *more: str, block=None) -> int:
    dev = BusDevice(channel, model, block=block)
    try:
        return cli.main(["update", str(path), *options(channel, *more)])
    finally:
        dev.close()


def between_initiates(log, n: int):
    """The block server's log from its n-th initiate (from 0) to the next."""
    starts = [i for i, e in enumerate(log) if e[0] == "initiate"] + [len(log)]
    return log[starts[n] : starts[n + 1]]


def test_the_block_servers_crc_is_crc16_xmodem():
    assert crc16_xmodem(b"123456789") == 0x31C3  # the catalogue's check value
    assert crc16_xmodem(b"") == 0


def test_a_full_update_by_block_download(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD, status_polls=2)
    server = block_server(model)
    code = run_update(channel, model, path, block=server)
    out, err = capsys.readouterr()
    assert code == 0, err
    assert not model.loader and model.crc() == update_cli.UpdateImage.parse(NEW).crc
    assert out.startswith("node 16 updated: version 3 -> 4, CRC 0x")
    assert "downloading 2512 bytes by SDO block download (attempt 1 of 3)" in err
    assert "segmented" not in err and "attempt 2" not in err
    bars = [line for line in err.splitlines() if line.startswith("[")]
    assert bars[0].startswith("[....") and " 100 % 2512/2512 B" in bars[-1]
    assert len(bars) == 11
    # 359 segments (the last with 6 bytes) in sub-blocks of 127, the size indicated, the CRC
    # asked for and right; the model got the whole file once.
    assert server.log == [
        ("initiate", True, 2512),
        ("ack", 127, 127),
        ("ack", 127, 127),
        ("ack", 105, 127),
        ("end", 1, crc16_xmodem(NEW)),
        ("done", 2512),
    ]
    assert [e[:2] for e in model.log if e[0] == "download"] == [("download", 2512)]


def test_a_lost_segment_is_sent_again_from_the_last_one_acknowledged(tmp_path, capsys):
    """The 50th segment of the first sub-block never arrives: the device takes no segment
    after it, acknowledges the 49th, and python-canopen sends from the 50th again, in the next
    sub-block; one attempt, the right image."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    server = block_server(model, lose={50})
    code = run_update(channel, model, path, block=server)
    err = capsys.readouterr().err
    assert code == 0, err
    assert model.crc() == update_cli.UpdateImage.parse(NEW).crc and model.version() == 4
    assert "attempt 2" not in err
    assert server.log == [
        ("initiate", True, 2512),
        ("lost", 50),
        ("ack", 49, 127),
        ("ack", 127, 127),  # segments 50-176 of the file
        ("ack", 127, 127),
        ("ack", 56, 127),  # the last, 359
        ("end", 1, crc16_xmodem(NEW)),
        ("done", 2512),
    ]


def test_a_lost_segment_in_the_last_sub_block_costs_an_attempt(tmp_path, capsys):
    """python-canopen 2.4.1 cannot send again segments of the last sub-block (its
    `_retransmit` goes through `write`, which raises RuntimeError after the last segment was
    sent): the command aborts the transfer, without its end request, and the next attempt
    from clear takes the image."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    server = block_server(model, lose={300})  # the 46th of the third sub-block
    code = run_update(channel, model, path, block=server)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "python-canopen could not send again the segments of the last sub-block" in err
    assert "downloading 2512 bytes by SDO block download (attempt 2 of 3)" in err
    assert between_initiates(server.log, 0) == [
        ("initiate", True, 2512),
        ("ack", 127, 127),
        ("ack", 127, 127),
        ("lost", 46),
        ("ack", 45, 127),
        ("client abort", update_cli.ABORT_GENERAL),
    ]
    assert between_initiates(server.log, 1)[-1] == ("done", 2512)
    assert model.crc() == update_cli.UpdateImage.parse(NEW).crc


def test_a_crc_mismatch_is_aborted_and_the_attempt_fails(tmp_path, capsys):
    """A byte changed on its way (here: by the device's side): the end's CRC does not match,
    the device aborts with 0x05040004 and keeps nothing; each attempt fails so, and the
    device, cleared in its loader, takes the next update."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    server = block_server(model, damage=700)
    code = run_update(channel, model, path, "--retries", "1", block=server)
    err = capsys.readouterr().err
    assert code == update.EXIT_FAILED == 1
    assert "the download failed 2 times; the last: download of 0x1F50:1: SDO abort " in err
    assert "0x05040004 (CRC error); 0x1F57" in err and "without a valid application" in err
    assert "to retry:" in err and "does not offer" not in err
    for attempt in (0, 1):
        assert between_initiates(server.log, attempt)[-2:] == [
            ("end", 1, crc16_xmodem(NEW)),
            ("abort", 0x0504_0004),
        ]
    assert not any(e[0] == "download" for e in model.log) and model.loader
    server.damage = None
    assert run_update(channel, model, path, block=server) == 0
    assert not model.loader and model.version() == 4


def test_a_block_download_aborted_by_the_device_gets_no_end_request(tmp_path, capsys):
    """The device aborts in place of a sub-block's acknowledgement (here 0x06060000, a flash
    write error): a failed attempt; python-canopen's end request (which its `close` sends,
    also from the garbage collector) never follows: it would be answered 0x05040001."""
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    server = block_server(model, abort_block=(2, 0x0606_0000))
    code = run_update(channel, model, path, "--retries", "0", block=server)
    err = capsys.readouterr().err
    assert code == update.EXIT_FAILED
    assert "download of 0x1F50:1: SDO abort 0x06060000" in err and "attempt 2" not in err
    assert server.log == [("initiate", True, 2512), ("ack", 127, 127), ("abort", 0x0606_0000)]
    assert len(server.frames) == 1 + 2 * 127  # the initiate and two sub-blocks, no end request


def test_block_only_fails_on_a_device_without_block_download(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    code = run_update(channel, model, path, "--sdo-transfer", "block", "--retries", "0")
    err = capsys.readouterr().err
    assert code == update.EXIT_FAILED
    assert "0x05040001 (command specifier not valid or unknown) at the block download's " in err
    assert "--sdo-transfer auto or segmented" in err
    assert "segmented SDO download" not in err and "downloading segmented" not in err
    assert f"to retry: canopen-handwheel update {path} " in err and "--sdo-transfer block" in err
    assert not any(e[0] == "download" for e in model.log)


def test_segmented_is_segmented_on_a_device_with_block_download(tmp_path, capsys):
    path = tmp_path / "fw.bin"
    path.write_bytes(NEW)
    channel = channel_name()
    model = ProgramDevice(OLD)
    server = block_server(model)
    code = run_update(channel, model, path, "--sdo-transfer", "segmented", block=server)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "downloading 2512 bytes by segmented SDO download (attempt 1 of 3)" in err
    assert "block" not in err and server.log == [] and model.version() == 4


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
