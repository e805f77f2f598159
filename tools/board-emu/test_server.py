"""The control line's commands on a machine with the release image, without sockets or
the wall clock: a command goes to the server as a line would, the test moves emulated time
on and reads the replies. Needs the release ELF (as test_machine.py)."""

import pytest

import server
from stm32emu import machine
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
