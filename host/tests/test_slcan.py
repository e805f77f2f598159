"""The SLCAN codec (`canopen_handwheel.slcan`): every frame kind at every length through
`encode` and `decode` and back, the lines that are no frame, the stream cut into lines
however it arrives, and the lines read and written by python-can's own `slcan` interface."""

from __future__ import annotations

import socket

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from canopen_handwheel import slcan
from canopen_handwheel.slcan import Frame, LineSplitter, decode, encode

KINDS = {  # letter: (extended, remote)
    "t": (False, False),
    "T": (True, False),
    "r": (False, True),
    "R": (True, True),
}


def frame_of(kind: str, length: int, timestamp=None) -> Frame:
    """A frame of `kind` with `length` bytes (data frames: 0x11, 0x22, ...; remote frames: the
    DLC) and a high identifier of its format."""
    extended, remote = KINDS[kind]
    can_id = 0x1ABCDEF5 if extended else 0x6A5
    if remote:
        return Frame(can_id, b"", extended, True, length, timestamp)
    return Frame(
        can_id, bytes(0x11 * (i + 1) for i in range(length)), extended, False, None, timestamp
    )


@pytest.mark.parametrize("timestamp", [None, 0, 0x1234, 59_999])
@pytest.mark.parametrize("length", range(9))
@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_and_length_round_trips(kind, length, timestamp):
    frame = frame_of(kind, length, timestamp)
    line = encode(frame)
    assert line[:1] == kind.encode() and line.endswith(b"\r") and line.count(b"\r") == 1
    width = 8 if frame.extended else 3
    body = 0 if frame.remote else 2 * length
    assert len(line) == 1 + width + 1 + body + (0 if timestamp is None else 4) + 1
    assert decode(line[:-1]) == frame
    assert frame.length == length


@pytest.mark.parametrize(
    "line, frame",
    [
        (b"t7101" + b"00", Frame(0x710, b"\x00")),
        (b"t19080102030405060708", Frame(0x190, bytes(range(1, 9)))),
        (b"t19080a0B0c0D0e0F1011", Frame(0x190, bytes.fromhex("0a0b0c0d0e0f1011"))),
        (b"t0000", Frame(0x000, b"")),
        (b"t7FF0", Frame(0x7FF, b"")),
        (b"T01ABCDEF2BEEF", Frame(0x1ABCDEF, b"\xbe\xef", extended=True)),
        (b"T1fffffff0", Frame(0x1FFFFFFF, b"", extended=True)),
        (b"r6108", Frame(0x610, b"", remote=True, dlc=8)),
        (b"R000001233", Frame(0x123, b"", extended=True, remote=True, dlc=3)),
        (b"t19010AEA5F", Frame(0x190, b"\x0a", timestamp=59_999)),
        (b"r61080000", Frame(0x610, b"", remote=True, dlc=8, timestamp=0)),
    ],
)
def test_frame_lines_decode(line, frame):
    assert decode(line) == frame


@pytest.mark.parametrize(
    "line",
    [
        b"",
        b"O",
        b"C",
        b"S8",
        b"z",
        b"Z",
        b"V0101",
        b"\x07",
        b"\x07t0000",  # BELs are the splitter's to remove
        b"t19",  # cut in the identifier
        b"t190",  # no DLC
        b"t1908010203",  # fewer bytes than the DLC
        b"t190101020",  # more, and not a timestamp
        b"t19010102030",  # more, and one digit more than a timestamp
        b"t1901010",  # an odd digit
        b"t1909" + b"00" * 9,  # DLC 9
        b"t8001" + b"00",  # beyond 11 bits
        b"T200000001" + b"00",  # beyond 29 bits
        b"t19G100",  # not hex
        b"t1901zz",
        b"t 901AA",  # what int() would take: a space, a sign, an underscore
        b"t+901AA",
        b"t1_01AA",
        b"t1901A A",
        b"t1901\xc1\xc1",  # not ASCII
        b"r6108" + b"00",  # a remote frame with data (two digits: no timestamp)
        b"t1901AAEA60",  # a timestamp of 60 000
        b"t1901AA\r",  # the terminator belongs to the splitter
        b"x19010A",  # CANdapter's extended letter, and CAN FD frames: not spoken here
        b"d1901AA",
    ],
)
def test_other_lines_are_no_frames(line):
    assert decode(line) is None


def test_encode_writes_upper_case_hex_as_the_board_does():
    assert encode(Frame(0x190, bytes.fromhex("0a0b0c0d0e0f1011"))) == b"t19080A0B0C0D0E0F1011\r"
    assert encode(Frame(0x1ABCDEF, b"", extended=True, timestamp=0xBEE)) == b"T01ABCDEF00BEE\r"


@pytest.mark.parametrize(
    "frame",
    [
        Frame(0x800, b""),  # beyond 11 bits
        Frame(0x2000_0000, b"", extended=True),
        Frame(-1, b""),
        Frame(0x190, bytes(9)),
        Frame(0x610, b"\x00", remote=True, dlc=1),
        Frame(0x610, b"", remote=True, dlc=9),
        Frame(0x190, b"\x00", dlc=2),  # a data frame's DLC is its length
        Frame(0x190, b"", timestamp=60_000),
        Frame(0x190, b"", timestamp=-1),
    ],
)
def test_encode_refuses_what_no_line_carries(frame):
    with pytest.raises(ValueError):
        encode(frame)


def test_a_data_frame_may_name_its_own_length_as_dlc():
    assert encode(Frame(0x190, b"\x01\x02", dlc=2)) == encode(Frame(0x190, b"\x01\x02"))


def test_acks_follow_the_identifier_format():
    assert slcan.ack(Frame(0x190, b"")) == slcan.ack(Frame(0x190, b"", remote=True)) == b"z\r"
    assert slcan.ack(Frame(0x190, b"", extended=True)) == b"Z\r"
    assert slcan.ack(Frame(0x190, b"", extended=True, remote=True, dlc=0)) == b"Z\r"


def test_bit_rates_are_the_s_commands():
    assert slcan.BITRATES[0] == 10_000 and slcan.BITRATES[8] == 1_000_000
    assert len(slcan.BITRATES) == 9


def test_to_message_is_python_can_s_frame():
    msg = slcan.to_message(Frame(0x1ABCDEF, b"", extended=True, remote=True, dlc=5), 12.5)
    assert (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc) == (
        0x1ABCDEF,
        True,
        True,
        5,
    )
    assert msg.timestamp == 12.5 and bytes(msg.data) == b""
    msg = slcan.to_message(Frame(0x190, b"\x01\x02"), 1.0)
    assert (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc) == (
        0x190,
        False,
        False,
        2,
    )
    assert bytes(msg.data) == b"\x01\x02"


# Cutting the stream into lines -----------------------------------------------------------------


def test_lines_split_across_reads_and_bells_dropped():
    split = LineSplitter()
    assert split.feed(b"t71010") == []
    assert split.feed(b"0\r\x07t00") == [b"t710100"]
    assert split.feed(b"0\r\rz\r") == [b"t000", b"", b"z"]
    assert split.feed(b"\x07\x07") == []
    assert split.feed(b"\r") == [b""]
    assert split.feed(b"") == []


def test_without_a_bound_lines_grow_as_long_as_they_come():
    split = LineSplitter()
    assert split.feed(b"x" * 10_000) == []
    assert split.feed(b"\rO\r") == [b"x" * 10_000, b"O"]
    assert split.overflows == 0


def test_an_overlong_line_is_dropped_to_its_end_and_counted():
    split = LineSplitter(longest=8)
    assert split.feed(b"O\rt12345678") == [b"O"]  # 9 bytes unfinished: over the bound
    assert split.overflows == 1
    assert split.feed(b"t0000") == []  # still the overlong line
    assert split.feed(b"\rt0000\rt00") == [b"t0000"]  # its tail was dropped with its `\r`
    assert split.overflows == 1
    assert split.feed(b"00\r") == [b"t0000"]
    assert split.feed(b"12345678") == []  # 8 bytes unfinished: within the bound
    assert split.feed(b"\r") == [b"12345678"]
    assert split.overflows == 1


def test_a_complete_line_is_returned_whatever_its_length():
    # Only the unfinished rest is bounded (the memory kept between reads); a long line that
    # arrived whole is the caller's to refuse, as any line that is no frame.
    split = LineSplitter(longest=8)
    assert split.feed(b"t0000" * 4 + b"\r") == [b"t0000" * 4]
    assert split.overflows == 0


# Properties ------------------------------------------------------------------------------------


@st.composite
def frames(draw, timestamps=True) -> Frame:
    """Any frame a line can carry."""
    extended, remote = draw(st.sampled_from(list(KINDS.values())))
    can_id = draw(st.integers(0, (1 << (29 if extended else 11)) - 1))
    timestamp = draw(st.none() | st.integers(0, 59_999)) if timestamps else None
    if remote:
        return Frame(can_id, b"", extended, True, draw(st.integers(0, 8)), timestamp)
    return Frame(can_id, draw(st.binary(max_size=8)), extended, False, None, timestamp)


@given(frames(), st.data())
def test_any_frame_round_trips_in_either_case(frame, data):
    line = encode(frame)[:-1]
    assert decode(line) == frame
    # Hex digits in any case: the letter stays, so only the digits after it are changed.
    lower = data.draw(st.lists(st.booleans(), min_size=len(line), max_size=len(line)))
    mixed = line[:1] + bytes(
        c | 0x20 if low and chr(c) in "ABCDEF" else c for c, low in zip(line[1:], lower[1:])
    )
    assert decode(mixed) == frame


def mutations(line: bytes) -> st.SearchStrategy:
    """`line` with one byte dropped, changed or added: near misses of a frame."""
    at = st.integers(0, max(0, len(line) - 1))
    byte = st.integers(0, 255).map(lambda b: bytes([b]))
    return st.one_of(
        at.map(lambda i: line[:i] + line[i + 1 :]),
        st.tuples(at, byte).map(lambda p: line[: p[0]] + p[1] + line[p[0] + 1 :]),
        st.tuples(at, byte).map(lambda p: line[: p[0]] + p[1] + line[p[0] :]),
    )


@given(st.one_of(st.binary(max_size=40), frames().map(lambda f: encode(f)[:-1]).flatmap(mutations)))
def test_any_line_decodes_to_a_frame_that_writes_it_back_or_to_none(line):
    frame = decode(line)
    if frame is not None:
        assert encode(frame)[:-1] == line[:1] + line[1:].upper()


@given(
    st.lists(st.tuples(frames(), st.integers(0, 2)), max_size=20),
    st.lists(st.integers(0, 400), max_size=10),
)
def test_a_stream_cut_anywhere_gives_its_frames(sent, cuts):
    """Frames (each after 0..2 BELs, an adapter's refusals) written to a stream that arrives in
    pieces of any size: every frame comes out once, in order."""
    stream = b"".join(slcan.ERROR * bells + encode(frame) for frame, bells in sent)
    split = LineSplitter(longest=64)
    got = []
    start = 0
    for cut in sorted(cuts) + [len(stream)]:
        got += split.feed(stream[start:cut])
        start = max(start, cut)
    assert [decode(line) for line in got] == [frame for frame, _ in sent]
    assert split.overflows == 0


# python-can's own `slcan` interface ---------------------------------------------------------------

# Every kind at every length: what python-can writes and reads (no timestamps: it writes none).
INTEROP_FRAMES = [frame_of(kind, length) for kind in KINDS for length in range(9)]


@pytest.fixture
def line():
    """python-can's `slcan` bus on a TCP line (`socket://`) and the other end of the line."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    bus = can.Bus(
        interface="slcan",
        channel=f"socket://127.0.0.1:{server.getsockname()[1]}",
        sleep_after_open=0,
    )
    peer, _ = server.accept()
    peer.settimeout(5)
    yield bus, peer
    bus.shutdown()
    peer.close()
    server.close()


def same(msg: can.Message, frame: Frame) -> bool:
    return (
        msg.arbitration_id == frame.id
        and msg.is_extended_id == frame.extended
        and msg.is_remote_frame == frame.remote
        and msg.dlc == frame.length
        and bytes(msg.data or b"") == frame.data
    )


def test_python_can_reads_the_lines_encode_writes(line):
    bus, peer = line
    for frame in INTEROP_FRAMES:
        peer.sendall(encode(frame))
        msg = bus.recv(5)
        assert msg is not None and same(msg, frame), (frame, msg)


def test_decode_reads_the_lines_python_can_writes(line):
    bus, peer = line
    for frame in INTEROP_FRAMES:
        bus.send(slcan.to_message(frame, 0.0))
    split = LineSplitter()
    got = []  # `O`, the bus opening, decodes to None
    while len(got) < len(INTEROP_FRAMES):
        got += [f for f in map(decode, split.feed(peer.recv(4096))) if f is not None]
    assert got == INTEROP_FRAMES
