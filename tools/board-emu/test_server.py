"""The control line's commands and the SLCAN port on a machine with the release image,
without sockets or the wall clock: a command goes to the server as a line would, the test
moves emulated time on and reads the replies. Needs the release ELF (as test_machine.py)."""

import pytest

import server
from stm32emu import machine, periph
from stm32emu.test_machine import ELF

pytestmark = pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")


class Client:
    """Collects what the server sends to a control client."""

    def __init__(self) -> None:
        self.sent = b""
        self.buffer = b""

    def send(self, data: bytes) -> None:
        self.sent += data


@pytest.fixture
def board():
    m = machine.Machine(str(ELF))
    s = server.Server(m, 0, 0, None)  # port 0: any free port, never connected here
    yield m, s
    s.sel.close()
    s.can_listener.close()
    s.stim_listener.close()


def command(s, client: Client, line: str) -> None:
    """`line` as it arrives on the control port."""
    client.buffer += line.encode() + b"\n"
    s._stim_input(client)


def steps_until(m, client: Client, replies: int, limit: int = 5000) -> None:
    for _ in range(limit):
        if client.sent.count(b"\n") >= replies:
            return
        m.step()
    raise AssertionError(f"{client.sent!r} after {limit} steps, at {m.ms():.3f} ms")


def test_a_turn_after_a_timed_hold_is_answered(board):
    """`hold <ms>` ends by itself, and the board runs on: a `turn` after it gets its `ok`
    (its edges and the settle time, 27.4 ms) and the feed record goes out."""
    m, s = board
    m.run_ms(50)
    client = Client()
    command(s, client, "hold 5")
    assert client.sent == b"ok\n" and m.can.bus_hold_until == m.now + 5 * 72_000
    m.run_ms(10)
    command(s, client, "turn 1")
    start = m.ms()
    steps_until(m, client, 2)
    assert client.sent == b"ok\nok\n"
    assert m.ms() - start == pytest.approx(27.4, abs=0.1)


def test_hold_and_dominant_take_ms_on_or_off(board):
    m, s = board
    client = Client()
    for name, attribute in (("hold", "bus_hold_until"), ("dominant", "bus_dominant_until")):
        command(s, client, f"{name} on")
        assert getattr(m.can, attribute) is None
        command(s, client, f"{name} off")
        assert getattr(m.can, attribute) == 0
        command(s, client, f"{name} 20")
        assert getattr(m.can, attribute) == m.now + 20 * 72_000
        command(s, client, f"{name} 60001")
    assert client.sent == b"ok\nok\nok\nerr out of range\n" * 2
    assert s.status()["mode"] == "sleep", "the CPU has not run: bxCAN as out of reset"


def test_trickle_takes_ms_or_off(board):
    m, s = board
    client = Client()
    command(s, client, "trickle 95")
    assert m.can.bus_trickle == 95 * 72_000 and m.can.bus_hold_until == m.now + 95 * 72_000
    command(s, client, "trickle off")
    assert m.can.bus_trickle == 0 and m.can.bus_hold_until == 0
    command(s, client, "trickle 0")
    assert client.sent == b"ok\nok\nerr out of range\n"


SAVE = (0x65766173).to_bytes(4, "little")


def sdo_saves(m, ms: int) -> None:
    """0x1017 = ms, then 0x1010:1 "save", as the master sends them (answers not awaited)."""
    m.deliver(periph_frame(0x610, bytes([0x2B, 0x17, 0x10, 0]) + ms.to_bytes(2, "little")))
    m.run_ms(20)
    m.deliver(periph_frame(0x610, bytes([0x23, 0x10, 0x10, 1]) + SAVE))
    m.run_ms(40)


def periph_frame(can_id: int, data: bytes):
    from stm32emu import periph

    return periph.Frame(can_id, data.ljust(8, b"\0"))


def test_cut_inside_a_flash_operation_reboots_with_the_old_record(board):
    """`cut 1 inside`: the next half-word program is left half done and the power fails;
    the board boots again (a second power-on) and the store before is what it finds."""
    m, s = board
    m.run_ms(50)
    sdo_saves(m, 250)
    client = Client()
    command(s, client, "cut 1 inside")
    assert s.status()["armed"] == 1
    sdo_saves(m, 300)
    m.run_ms(50)
    status = s.status()
    assert (status["cuts"], status["resets"], status["boot"]) == (1, 2, "PowerOn")
    assert status["armed"] == "-"
    before = len(m.transmitted)
    m.deliver(periph_frame(0x610, bytes([0x40, 0x17, 0x10, 0])))
    m.run_ms(20)
    replies = [f.data for _, f in m.transmitted[before:] if f.can_id == 0x590]
    assert int.from_bytes(replies[0][4:6], "little") == 250
    command(s, client, "cut 0 before")
    command(s, client, "cut off")
    assert client.sent == b"ok\nerr out of range\nok\n"


def test_power_never_kills_the_board_when_its_decoder_exits(board):
    """A log decoder that exits (as defmt-print did on a frame cut by a power cycle) is
    started again; `power` and the log go on."""
    m, s = board
    # `true` exits at once: every write meets a closed pipe.
    s.log_out = server.Decoder("true", {"application": str(ELF)}, "application")
    s.started = True
    client = Client()
    for _ in range(3):
        m.run_ms(30)
        command(s, client, "power")
        s.flush_log()
    assert client.sent == b"ok\n" * 3
    assert s.log_out.restarts >= 3 and m.stats.resets[-1].endswith("PowerOn")
    s.log_out.close()


def test_snapshot_and_rollback_restore_the_pages(board):
    m, s = board
    m.run_ms(50)
    client = Client()
    command(s, client, "rollback")
    command(s, client, "snapshot")
    before = bytes(m.fpec.memory)
    pages = slice(0xF800, 0x10000)  # the parameter pages in the flash
    assert before[pages] == b"\xff" * 2048
    sdo_saves(m, 250)
    assert bytes(m.fpec.memory[pages]) != b"\xff" * 2048
    command(s, client, "rollback")
    assert bytes(m.fpec.memory) == before
    assert bytes(m.uc.mem_read(0x0800_F800, 2048)) == b"\xff" * 2048, "what the CPU reads"
    assert client.sent == b"err no snapshot\nok\nok\n"


def test_an_idle_cpu_waits_in_wall_time_for_input(board, monkeypatch):
    """Idle, the board lets emulated time follow the wall clock until the next event or
    the host's input, whichever comes first; input 0.2 ms into the wait finds emulated
    time 0.2 ms on, not at the next event (which would hold the reply until the wall clock
    got there)."""
    m, s = board
    m.run_ms(50)
    while not m.step(idle_jump=False):
        pass
    wall = {"s": m.now / machine.cortex.CORE_HZ}
    monkeypatch.setattr(server.time, "monotonic", lambda: wall["s"])
    s.wall0 = 0.0

    def input_after_200_us(timeout):
        wall["s"] += min(timeout, 0.0002)
        return []

    monkeypatch.setattr(s.sel, "select", input_after_200_us)
    before, next_event = m.now, m.next_event()
    assert next_event - before > 14_400, "the next event is more than 0.2 ms away"
    s.idle()
    assert m.now - before == pytest.approx(14_400, abs=1)
    wall["s"] += 1.0  # the wall clock far ahead: time goes to the next event, no further
    s.idle()
    assert m.now == next_event
    # A wheel edge pends EXTI9_5: the CPU is not idle, no time passes before it runs.
    while not m.step(idle_jump=False):
        pass
    m.set_ab(m.ab ^ 1)
    before = m.now
    s.idle()
    assert m.now == before


# The SLCAN port ------------------------------------------------------------------------------


class Line:
    """The socket of a client of the SLCAN port: what the server sends it (what the
    client would read)."""

    def __init__(self) -> None:
        self.sent = b""

    def sendall(self, data: bytes) -> None:
        self.sent += data


def slcan_client(s) -> Line:
    """A client on the board's SLCAN port."""
    line = Line()
    s.can_client = server.Client(line, "can")
    return line


def test_commands_are_answered_and_frames_put_on_the_bus(board):
    m, s = board
    line = slcan_client(s)
    sdo = b"t6108" + b"4000100000000000"
    s._slcan_input(s.can_client, b"C\rO\rS4\r" + sdo + b"\rT000006101AA\rr6100\rV\rN\r")
    assert line.sent == b"\r\r\rz\rZ\rz\rV0101\rNBOARD\r"
    assert s.frames_in == 3 and s.slcan_open
    assert m.can.bus_bitrate == 125_000


def test_bad_lines_are_refused_and_lines_may_come_in_pieces(board):
    m, s = board
    line = slcan_client(s)
    for piece in (b"t61", b"08", b"00\rt6109\rt80", b"00\rS9\rQ\rC\n"):
        s._slcan_input(s.can_client, piece)
    # `t6108` + one byte: the DLC says 8; DLC 9; identifier beyond 11 bits; no S9; no Q.
    assert line.sent == b"\a\a\a\a\a\r"
    assert s.frames_in == 0 and not s.slcan_open


def test_a_line_that_never_ends_is_refused_once_with_its_tail(board):
    m, s = board
    line = slcan_client(s)
    s._slcan_input(s.can_client, b"O\r" + b"t" * 65)
    assert line.sent == b"\r\a"
    s._slcan_input(s.can_client, b"6100\rC\r")  # the rest of that line, then a command
    assert line.sent == b"\r\a\r"
    assert s.frames_in == 0 and not s.slcan_open


def test_the_node_s_frames_reach_the_client_as_lines(board):
    m, s = board
    line = slcan_client(s)
    m.run_ms(50)
    assert line.sent.startswith(b"t7101" + b"00\r"), line.sent  # the boot-up of node 16


def test_status_reports_the_digital_outputs(board):
    """`status` has `outputs` (bit n = board output n + 1) and `jog` (output 1, "jog live"):
    all off after reset; an SDO write of 0x6A00:1 = 0xFF drives outputs 2..8 (bits 0..6; bit
    7 has no pin) and not "jog live"; a JTAG pin drives nothing until SWJ_CFG releases it."""
    m, s = board
    m.run_ms(100)
    assert (s.status()["outputs"], s.status()["jog"]) == ("0x00", 0)
    write_outputs = bytes([0x2F, 0x00, 0x6A, 0x01, 0xFF, 0, 0, 0])
    m.deliver(periph.Frame(0x610, write_outputs))  # node 16's SDO server
    m.run_ms(20)
    assert (s.status()["outputs"], s.status()["jog"]) == ("0xfe", 0)
    # PA15, PB3 and PB4 (outputs 2..4) back to JTAG: they no longer drive.
    m.afio.regs[1] &= ~(0b111 << 24)
    assert s.status()["outputs"] == "0xf0"
