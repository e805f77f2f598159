"""Captures (`--capture`), their decoding and their replay: the component on python-can's
virtual bus and on an SLCAN line writes what it read and sent; `decode.replay` runs the capture
through the core and must end on the pins the component wrote; the decoder names every frame
in CANopen terms."""

import json
import os
import signal
import time
from pathlib import Path

import can
import pytest

import records
from canopen_handwheel import capture, cli, component, core, decode
from canopen_handwheel.record import Record
from test_component import NODE, Device, Running, SlcanFeed, pin_changes, wait

TPDO1, EMCY, HB = 0x180 + NODE, 0x080 + NODE, 0x700 + NODE


def hal_changes(log: Path):
    """(time, pin, value) of every pin change in a fake_hal log."""
    out = []
    for line in log.read_text().splitlines():
        t, pin, value = line.split(" ")
        out.append((float(t), pin, value))
    return out


def session_on_a_virtual_bus(tmp_path: Path, monkeypatch, name: str):
    """A short session of the component with `--capture tmp_path/name`: configured, the feed
    enabled, X turned (+3, -10), a duplicate, a short frame, an EMCY set and cleared, Y
    selected; returns (capture path, the fake_hal log of the pin changes)."""
    log = tmp_path / "hal.log"
    log.write_text("")
    monkeypatch.setenv("FAKE_HAL_LOG", str(log))
    path = tmp_path / name
    channel = f"cap-{time.monotonic_ns()}"
    dev = Device(channel)
    running = Running(channel, "--capture", str(path))
    comp = running.comp
    try:
        wait(lambda: dev.seen(0x000, bytes([1, NODE])), what="NMT start")
        wait(lambda: dev.record(100, epoch=2) or comp["connected"], what="connected")
        comp["enable"] = True
        wait(lambda: dev.node.sdo[0x2000].raw == 1, what="0x2000 = 1")
        dev.record(100, status=1, epoch=3)
        dev.record(103, status=1, epoch=3)
        dev.record(93, status=1, epoch=3)
        wait(lambda: comp["axis.x.jog-counts"] == -7, what="x counts")
        seq = dev.seq
        dev.network.send_message(TPDO1, records.rec(93, seq=seq, epoch=3, session=dev.session))
        dev.network.send_message(TPDO1, b"\x01\x02")
        wait(lambda: comp["frames-bad"] == 1, what="the short frame counted")
        dev.network.send_message(EMCY, bytes.fromhex("3081110100000000"))
        wait(lambda: comp["emcy-code"] == 0x8130, what="EMCY code")
        dev.network.send_message(EMCY, bytes(8))
        wait(lambda: comp["emcy-code"] == 0, what="EMCY reset")
        dev.record(93, axis=2, status=1, epoch=4)
        wait(lambda: comp["halui.axis.y.select"], what="Y selected")
        dev.record(95, axis=2, status=1, epoch=4)
        wait(lambda: comp["axis.y.jog-counts"] == 2, what="y counts")
    finally:
        running.end()
        dev.close()
    return path, log


@pytest.mark.parametrize("name", ["session.log", "session.asc", "session.blf"])
def test_a_capture_replays_to_the_pins_the_component_wrote(tmp_path, monkeypatch, name):
    path, log = session_on_a_virtual_bus(tmp_path, monkeypatch, name)
    f = capture.read(path)
    assert f.notes is not None and f.config["axes"] == "xyz"
    sent = [fr for fr in f.frames if not fr.rx]
    assert any(fr.id == 0x701 and fr.data == b"\x05" for fr in sent), "the heartbeat"
    assert any(fr.id == 0x000 and fr.data == bytes([1, NODE]) for fr in sent), "NMT start"
    assert any(fr.id == 0x600 + NODE for fr in sent) and all(
        fr.rx for fr in f.frames if fr.id == TPDO1
    )
    r = decode.replay([f])
    assert r.differences(hal_changes(log)) == []
    assert r.pins["axis.x.jog-counts"] == -7 and r.pins["axis.y.jog-counts"] == 2
    assert r.pins["frames-bad"] == 1 and not r.mismatches
    kinds = [line.verdict.kind for line in r.lines if line.verdict is not None]
    assert kinds.count(decode.CREDITED) == 3
    assert decode.DUPLICATE in kinds and decode.IMPOSSIBLE in kinds
    # The core's time: every record of the device at the time the component handed it over.
    times = [fr.t for fr in f.frames]
    assert times == sorted(times)


def test_a_replay_that_differs_from_the_live_pins_says_where(tmp_path, monkeypatch):
    path, log = session_on_a_virtual_bus(tmp_path, monkeypatch, "session.log")
    r = decode.replay([capture.read(path)])
    changes = hal_changes(log)
    wrong = [(t, p, "-8" if p == "axis.x.jog-counts" and v == "-7" else v) for t, p, v in changes]
    problems = r.differences(wrong)
    assert any(p.startswith("axis.x.jog-counts: -8 live, -7 replayed") for p in problems), problems


def test_the_decoder_names_every_frame_and_the_rules_verdicts(tmp_path, monkeypatch, capsys):
    path, _ = session_on_a_virtual_bus(tmp_path, monkeypatch, "session.log")
    assert cli.main(["decode", str(path)]) == 0
    out = capsys.readouterr().out
    for text in (
        "NMT start, node 16",
        "heartbeat of node 1: operational",
        "SDO request to node 16: download 0x2002:0 (Feed session) = 1 (0x01)",
        "upload 0x1800:5 (TPDO1 communication parameter: Event timer) = 100 (0x0064)",
        "EMCY of node 16: 0x8130 monitored heartbeat lost",
        "EMCY of node 16: 0x0000 error reset",
        "feed record: position 103, axis X, x1, epoch 3, flags enabled, session 1, sequence",
        "credited X +3 (moved 3)",
        "credited X -10 (moved -10)",
        "the newest record again (a duplicate): nothing",
        "2 bytes: a record the device cannot send",
        "credited Y +2",
        "host   the host asks: configure",
        "host   configure: done, session 1 (0x2002 was 0)",
        "host   inputs: enable True",
        "  1 axis X: credited -7 in 2 record(s)",
        "  2 axis Y: credited +2 in 1 record(s)",
        "host side: the component's host notes",
    ):
        assert text in out, text
    assert cli.main(["decode", "--records", str(path)]) == 0
    records_only = capsys.readouterr().out
    assert "SDO" not in records_only and "credited X +3" in records_only


def test_without_notes_the_host_side_is_inferred_from_the_bus(tmp_path, monkeypatch):
    """A capture without its notes (as candump would take it): the configuration from the
    confirmed write of 0x2002, the feed as enabled; the rule credits the same counts."""
    path, _ = session_on_a_virtual_bus(tmp_path, monkeypatch, "session.log")
    r = decode.replay([capture.read(path, notes=None)])
    assert not r.notes
    assert r.pins["axis.x.jog-counts"] == -7 and r.pins["axis.y.jog-counts"] == 2
    assert any("configuration: session 1 (0x2002 written), taken" in e for _, e in r.events), (
        r.events
    )


def test_a_capture_that_starts_inside_a_session_adopts_it(tmp_path):
    """No configuration in the capture at all: the first record's session is taken as the
    host's; a copy of an earlier record is still a copy."""
    path = tmp_path / "cut.log"
    base = 1000.0
    frames = [(TPDO1, records.rec(10, seq=s, epoch=1, session=3), base + s * 0.01) for s in (1, 2)]
    frames += [(TPDO1, records.rec(12, seq=3, epoch=1, session=3), base + 0.03)]
    frames += [(TPDO1, records.rec(10, seq=2, epoch=1, session=3), base + 0.04)]  # a copy
    frames += [(TPDO1, records.rec(15, seq=4, epoch=1, session=3), base + 0.05)]
    with can.Logger(str(path)) as log:
        for cob, data, t in frames:
            msg = can.Message(arbitration_id=cob, data=data, timestamp=t, is_extended_id=False)
            log.on_message_received(msg)
    r = decode.replay([capture.read(path)])
    kinds = [line.verdict.kind for line in r.lines]
    assert kinds == [
        decode.BASELINE,
        decode.AT_REST,
        decode.CREDITED,
        decode.COPY,
        decode.CREDITED,
    ], [line.verdict.text for line in r.lines]
    assert r.pins["axis.x.jog-counts"] == 5 and r.pins["frames-bad"] == 1


def test_rotation_keeps_the_capture_within_its_bound(tmp_path):
    """2 kB files, 3 kept: after thousands of frames only NAME.log, NAME.1.log and NAME.2.log
    remain (each with its notes), none much over 2 kB, and each reads back on its own, its
    notes lined up with its frames."""
    clock = [100.0]
    path = tmp_path / "wheel.log"
    cap = capture.Capture(str(path), core.Config(), max_bytes=2000, files=3, clock=lambda: clock[0])
    for i in range(3000):
        clock[0] += 0.001
        msg = can.Message(arbitration_id=TPDO1, data=records.rec(i, seq=i), is_extended_id=False)
        cap.received(msg, lambda: clock[0], clock[0] - 0.2, judged=True)  # a late drain: noted
        if i % 100 == 0:
            cap.inputs(clock[0], enable=bool(i % 200))
    cap.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [
        "wheel.1.log",
        "wheel.1.log.host",
        "wheel.2.log",
        "wheel.2.log.host",
        "wheel.log",
        "wheel.log.host",
    ]
    for p in tmp_path.iterdir():
        assert p.stat().st_size < 2000 + 200, (p.name, p.stat().st_size)
    files = [capture.read(p) for p in capture.files_of(path)]
    assert [f.path.name for f in files] == ["wheel.2.log", "wheel.1.log", "wheel.log"]
    positions = [Record.decode(fr.data).position for f in files for fr in f.frames]
    assert positions == list(range(positions[0], 3000))
    for f in files:
        drains = [n for n in f.notes if "drained" in n.fields]
        # One note per record, 0.2 s before it, in the frames' own time base.
        assert len(drains) == len(f.frames)
        for n in drains:
            assert n.t == pytest.approx(f.frames[n.at].t - 0.2, abs=2e-6)


def test_a_note_before_the_first_frame_lines_up_with_it(tmp_path):
    clock = [5.0]
    path = tmp_path / "early.log"
    cap = capture.Capture(str(path), core.Config(), clock=lambda: clock[0])
    cap.inputs(5.0, enable=True)
    clock[0] = 5.25
    beat = can.Message(arbitration_id=HB, data=b"\x05", is_extended_id=False)
    cap.received(beat, lambda: clock[0], None, judged=True)
    cap.close()
    f = capture.read(path)
    assert [n.fields for n in f.notes] == [{"input": {"enable": True}}, {"drained": None}]
    assert f.notes[0].t == pytest.approx(f.frames[0].t - 0.25, abs=2e-6)
    header = json.loads(capture.notes_path(path).read_text().splitlines()[0])
    assert header["config"]["node"] == 16


def test_the_capture_options(capsys):
    a = component.parse_args(
        ["--capture", "x.asc", "--capture-max-mb", "2", "--capture-files", "3"]
    )
    assert (a.capture, a.capture_max_mb, a.capture_files) == ("x.asc", 2, 3)
    assert component.parse_args([]).capture is None
    for bad, message in (
        (["--capture", "x.txt"], "the extension names the format"),
        (["--capture", "x.log", "--capture-files", "1"], "--capture-files must be 2..100"),
        (["--capture", "x.log", "--capture-max-mb", "0"], "--capture-max-mb must be 1..4096"),
    ):
        with pytest.raises(SystemExit):
            component.parse_args(bad)
        assert message in capsys.readouterr().err


def test_frames_in_canopen_terms():
    d = decode.Describer(core.Config(), {(0x2000, 0): "Feed enable"})

    def text(cob, data, **kw):
        return d.describe(capture.Frame(t=0.0, id=cob, data=bytes.fromhex(data), **kw))

    assert text(0x000, "8110") == "NMT reset node, node 16"
    assert text(0x000, "0100") == "NMT start, all nodes"
    assert text(HB, "7f") == "heartbeat of node 16: pre-operational"
    assert text(HB, "00") == "heartbeat of node 16: boot-up"
    assert text(0x610, "2f00200001000000") == (
        "SDO request to node 16: download 0x2000:0 (Feed enable) = 1 (0x01)"
    )
    assert text(0x590, "80002000220000 08".replace(" ", "")) == (
        "SDO reply of node 16: abort 0x2000:0 (Feed enable): 0x08000022 data cannot be "
        "transferred or stored because of the present device state"
    )
    assert text(0x590, "8000100111000906").endswith("0x06090011 sub-index does not exist")
    assert text(EMCY, "0081110100000000").startswith(
        "EMCY of node 16: 0x8100 frames could not reach the bus for 100 ms"
    )
    assert text(EMCY, "1050000000000000").startswith("EMCY of node 16: 0x5010 device hardware")
    assert text(0x290, "1b") == "unit step: axis W, forward, counter 1"
    assert text(TPDO1, "fbffffff 4a 29 3412".replace(" ", "")) == (
        "feed record: position -5, axis Y, x10, epoch 2, flags enabled|master lost, session 1, "
        "sequence 4660"
    )
    assert text(0x7E5, "4c00000000000000") == "LSS request cs 0x4c"
    assert text(0x123, "", remote=True) == "remote request (RTR) for 0x123"


def test_a_frozen_component_shows_its_backlog_in_the_replay(tmp_path):
    """A frozen component in a capture: the component stopped (SIGSTOP) while records wait
    in its socket. The replay judges them as the component did (baselines from a backlog,
    nothing credited), by the notes of when it last found its receive path empty, and ends on
    the same pins."""
    path = tmp_path / "frozen.log"
    feed = SlcanFeed(tmp_path, "--capture", str(path))
    try:
        feed.wait_started()
        feed.ticking.set()
        time.sleep(0.2)
        for _ in range(2):
            time.sleep(0.02)
            feed.record(1)
        feed.wait_counts(2)
        feed.proc.send_signal(signal.SIGSTOP)
        frozen = time.monotonic()
        for _ in range(10):
            time.sleep(0.015)
            feed.record(1)
        time.sleep(max(0.0, frozen + 1.0 - time.monotonic()))
        feed.proc.send_signal(signal.SIGCONT)
        resumed = time.monotonic()
        time.sleep(0.5)
        assert [c for c in pin_changes(feed.log, "axis.x.jog-counts") if c[0] > resumed] == []
        feed.record(3)
        feed.wait_counts(5)
        time.sleep(0.1)
    finally:
        err = feed.close()
    assert "Traceback" not in err, err
    r = decode.replay([capture.read(path)])
    assert r.differences(hal_changes(feed.log)) == []
    backlog = [line for line in r.lines if line.verdict and "from a backlog" in line.verdict.text]
    assert backlog, "no record judged as from a backlog"
    assert all(not line.verdict.credited for line in backlog)
    assert r.pins["axis.x.jog-counts"] == 5


def test_the_decode_command_reports_a_missing_file(tmp_path, capsys):
    assert cli.main(["decode", str(tmp_path / "none.log")]) == 1
    assert "none.log" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "none.log.host")


def test_a_restarted_component_keeps_the_last_capture(tmp_path):
    """A second start with the same `--capture` moves the first one's file to NAME.1.EXT
    instead of overwriting it; replayed together, the second start begins a new core (its
    records are not judged against the first one's)."""
    path = tmp_path / "wheel.log"
    clock = [0.0]

    def now() -> float:
        return clock[0]

    for start, positions in enumerate(((1, 2, 3), (50, 51))):
        clock[0] = 10.0 * start
        cap = capture.Capture(str(path), core.Config(), clock=now)
        for seq, position in enumerate(positions, start=1):
            clock[0] += 0.01
            data = records.rec(position, seq=seq, epoch=1, session=2)
            msg = can.Message(arbitration_id=TPDO1, data=data, is_extended_id=False)
            cap.received(msg, now, clock[0], judged=True)
        cap.close()
    files = [capture.read(p) for p in capture.files_of(path)]
    assert [f.path.name for f in files] == ["wheel.1.log", "wheel.log"]
    assert files[0].run != files[1].run
    r = decode.replay(files)
    assert any("started again" in e for _, e in r.events)
    positions = [Record.decode(line.frame.data).position for line in r.lines]
    assert positions == [1, 2, 3, 50, 51]


def test_a_capture_that_cannot_be_written_stops_the_component(tmp_path, capfd):
    args = component.parse_args(["--capture", str(tmp_path / "no-such-folder" / "c.log")])
    assert component.run(args, hal_module=object()) == 1
    assert "cannot write the capture" in capfd.readouterr().err
