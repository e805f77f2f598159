"""The control line's flash commands (`cut`, `flash-ops`, `mode`, `peek`, `reload`,
`corrupt`) on a board with a hand-assembled loader that rewrites a function of the
application's slot (stm32emu/test_boot.py): no firmware build needed."""

import pytest

import server
from stm32emu import machine, test_boot


class Client:
    def __init__(self) -> None:
        self.sent = b""
        self.buffer = b""

    def send(self, data: bytes) -> None:
        self.sent += data

    def take(self) -> str:
        sent, self.sent = self.sent.decode(), b""
        return sent


@pytest.fixture
def board(tmp_path):
    path, content = test_boot.flash_with_f(tmp_path)
    m = machine.Machine(None, str(path), loader=test_boot.loader_rewriting_f())
    s = server.Server(m, 0, 0, None)  # port 0: any free port, never connected here
    yield m, s, Client(), path
    s.sel.close()
    s.can_listener.close()
    s.stim_listener.close()


def command(s, client: Client, line: str) -> str:
    client.buffer += line.encode() + b"\n"
    s._stim_input(client)
    return client.take()


def test_a_cut_inside_a_program_of_the_slot_and_the_counters(board):
    """`cut 2 inside`: the erase of F's page runs, the first half-word program of F is cut
    half done; the board powers on again in the loader. `flash-ops` counts both."""
    m, s, client, _ = board
    assert command(s, client, "flash-ops") == (
        "flash-ops ops=0 erases=0 programs=0 cuts=0 armed=-\nok\n"
    )
    assert command(s, client, "cut 2 inside") == "ok\n"
    assert command(s, client, "flash-ops").startswith("flash-ops ops=0 erases=0 ") and (
        "armed=2" in command(s, client, "status")
    )
    while len(m.stats.resets) < 2:
        m.step()
    assert command(s, client, "flash-ops") == (
        "flash-ops ops=2 erases=1 programs=1 cuts=1 armed=-\nok\n"
    )
    assert command(s, client, "mode") == "mode loader\nok\n"
    reply = command(s, client, f"peek {test_boot.F:#x} 4")
    data = bytes.fromhex(reply.split()[1])
    assert reply.endswith("ok\n") and data[2:] == b"\xff\xff"
    half = int.from_bytes(data[:2], "little")
    assert half not in (0xFFFF, 0x2002) and half & 0x2002 == 0x2002, "some bits cleared"
    status = dict(kv.split("=") for kv in command(s, client, "status").split()[1:-1])
    assert (status["run"], status["vtor"], status["boot"]) == ("loader", "0x00000000", "PowerOn")
    assert status["handoff"] == "00" * 8


def test_peek_reads_flash_and_sram_only(board):
    _, s, client, _ = board
    assert command(s, client, "peek 0x0800f800 4") == f"data {b'HWP2'.hex()}\nok\n"
    assert command(s, client, "peek 0x20004ff8 8") == "data 0000000000000000\nok\n"
    for bad in ("peek 0x0800fffe 4", "peek 0x40022000 4", "peek 0x08000000 0", "peek 1"):
        assert command(s, client, bad).startswith("err "), bad
    assert command(s, client, "peek 0x08000000 4097") == "err out of range\n"


def test_reload_of_a_parameter_page_file_replaces_only_the_parameter_pages(board):
    """A test that writes a file of the parameter pages alone (as before the whole flash
    was kept) and reloads: the loader and the slot stay as they are."""
    m, s, client, path = board
    before = bytes(m.fpec.memory)
    path.write_bytes(b"HWP2" + b"\x22" * 2044)
    assert command(s, client, "reload") == "ok\n"
    flash = bytes(m.fpec.memory)
    assert flash[0xF800:] == b"HWP2" + b"\x22" * 2044
    assert flash[:0xF800] == before[:0xF800]
    assert path.read_bytes() == flash and m.stats.resets[-1].endswith("PowerOn")
    whole = bytearray(flash)
    whole[0x5000:0x5004] = bytes.fromhex("0320 7047")
    path.write_bytes(bytes(whole))
    assert command(s, client, "reload") == "ok\n"
    assert bytes(m.uc.mem_read(test_boot.F, 4)) == bytes.fromhex("0320 7047")


def test_corrupt_flips_a_bit_of_the_parameter_page(board):
    m, s, client, path = board
    assert command(s, client, "corrupt") == "ok\n"
    assert bytes(m.fpec.memory[0xF808:0xF809]) == b"\xfe"
    assert path.read_bytes()[0xF808] == 0xFE and m.uc.mem_read(0x0800_F808, 1) == b"\xfe"
