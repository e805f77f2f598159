"""The outputs LinuxCNC drives on the board through the component (host/README.md,
"Outputs"): `handwheel.machine-on`, netted to `halui.machine.is-on` in handwheel.hal, lights
the board's output 2; `handwheel.out-N` its output N + 2; and output 1, "jog live", which the
device decides itself, is on exactly when a detent moves an axis.

The board's outputs come from the emulated board's control line (`status`: `outputs=0x..`,
bit n = board output n + 1, and `jog=`), polled from this process; LinuxCNC's pin changes
from the display's `watch`, on the same monotonic clock. The tests skip while the board
does not report its outputs (firmware and emulator from before RPDO1).
"""

import threading
import time

import pytest

from conftest import SCALE, moved
from rig import HEARTBEAT, NMT_START, NMT_STOP, NODE_ID, OPERATIONAL, STOPPED

MACHINE_ON_OUTPUT = 2
JOG_LIVE_OUTPUT = 1
RPDO1 = 0x200 + NODE_ID
# From LinuxCNC switching the machine on or off to the board's output (host/README.md).
LATENCY = 0.05


def lit(mask: int, output: int) -> bool:
    return bool(mask >> (output - 1) & 1)


def outputs(machine) -> int:
    """The board's outputs now (bit n = board output n + 1)."""
    try:
        mask, _ = machine.board.outputs()
    except (AttributeError, KeyError):
        pytest.skip("the emulated board does not report its outputs (`status outputs=`)")
    return mask


def wait_output(machine, output: int, on: bool, timeout: float = 2.0) -> float:
    """Waits until the board's `output` is `on`; the time it was seen so."""
    deadline = time.monotonic() + timeout
    while True:
        mask = outputs(machine)
        seen = time.monotonic()
        if lit(mask, output) == on:
            return seen
        assert seen < deadline, f"output {output} not {'on' if on else 'off'}: {mask:#04x}"
        time.sleep(0.005)


def steady_output(machine, output: int, seconds: float = 0.3) -> bool:
    """The board's `output`, which must not change for `seconds`."""
    first = lit(outputs(machine), output)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        assert lit(outputs(machine), output) == first, f"output {output} changes"
        time.sleep(0.02)
    return first


class OutputPoller:
    """Polls the board's outputs in a thread while LinuxCNC's command blocks this one:
    [(time before the poll, time after it, outputs)]."""

    def __init__(self, machine) -> None:
        self.machine = machine
        self.samples = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            before = time.monotonic()
            mask, _ = self.machine.board.outputs()
            self.samples.append((before, time.monotonic(), mask))

    def first(self, output: int, on: bool, after: float) -> float:
        """The end of the first poll begun after `after` that saw `output` so: the board's
        output changed before that."""
        self.stop.set()
        self.thread.join(5)
        for before, end, mask in self.samples:
            if before >= after and lit(mask, output) == on:
                return end
        raise AssertionError(f"output {output} never {'on' if on else 'off'}: {self.samples}")


def test_machine_on_lights_output_2_within_50_ms(machine):
    """Machine off and on twice: the board's output 2 follows `halui.machine.is-on` within
    50 ms (the time from LinuxCNC's pin change to the end of the first poll of the board
    that shows it: an upper bound; one of the four may take up to 150 ms, below), and so
    does RPDO1 on the bus; `outputs-live` stays true (the device stays Operational, only
    the byte changes)."""
    machine.select("x", 1)
    machine.ready_to_jog("x")
    outputs(machine)
    wait_output(machine, MACHINE_ON_OUTPUT, True)
    assert machine.pins()["outputs-live"] and machine.pins()["machine-on"]
    figures = []
    try:
        measure_machine_on(machine, figures)
    finally:
        print("machine on/off -> board output 2 (s), RPDO1 on the bus (s):", figures)
        machine.cnc.must("on")  # the next tests want it on, whatever failed
    machine.ready_to_jog("x")


def measure_machine_on(machine, figures) -> None:
    for command, on in [("off", False), ("on", True)] * 2:
        mark = machine.frames.mark()
        machine.watch(5, "halui.machine.is-on")
        poller = OutputPoller(machine)
        machine.cnc.must(command)
        samples = machine.watched(quiet=0.3)
        changed = next(t for t, value in samples if bool(value) == on)
        seen = poller.first(MACHINE_ON_OUTPUT, on, changed)
        frame = next(f.t for f in machine.frames.frames(RPDO1, mark) if bool(f.data[0] & 1) == on)
        figures.append((command, seen - changed, frame - changed))
        assert machine.pins()["outputs-live"]
    # Each transition within LATENCY, but for one that may take up to 3 x LATENCY: on the
    # loaded 2-core CI machine one in about ten runs had a single transition at 52-55 ms
    # (the component's send held up by the machine, the RPDO frame itself that late). That
    # the outputs go at once on a change, not at the next period (100 ms), is the schedule's
    # rule, host-tested (host/tests/test_outputs.py); this measures the whole path.
    delays = sorted(seen for _, seen, _ in figures)
    assert delays[-2] <= LATENCY and delays[-1] <= 3 * LATENCY, figures


def test_each_out_pin_drives_its_board_output(machine):
    """`setp handwheel.out-N 1` (N = 1..6) lights the board's output N + 2 and no other
    output changes; 0 puts it out."""
    base = outputs(machine)
    for n in range(1, 7):
        machine.setp(f"handwheel.out-{n}", 1)
        wait_output(machine, n + 2, True)
        assert outputs(machine) & ~1 == (base | 1 << (n + 1)) & ~1  # output 1: the device's
        machine.setp(f"handwheel.out-{n}", 0)
        wait_output(machine, n + 2, False)


def test_jog_live_is_on_exactly_when_a_detent_moves_the_axis(machine):
    """The board's output 1 in each state, then a detent turned: with the machine on, the
    feed enabled and X selected it is on and X moves; with the axis switch off, and with the
    machine off (X selected), it is off and nothing moves."""
    outputs(machine)

    def check(what: str, axis: str, machine_on: bool) -> bool:
        machine.select(axis, 1)
        if machine_on and axis != "off":
            machine.ready_to_jog(axis)
        elif machine_on:
            machine.wait(lambda s: s["pins"]["feed-enabled"], 5, "feed on")
        else:
            machine.wait(lambda s: not s["pins"]["feed-enabled"], 5, "feed off")
        live = steady_output(machine, JOG_LIVE_OUTPUT)
        start = machine.pos()
        machine.stim.turn(2)
        if live:
            machine.wait_pos(moved(start, axis, 2 * SCALE))
        else:
            machine.assert_still(start, 1.0)
        moves = any(abs(a - b) > SCALE / 2 for a, b in zip(machine.pos(), start))
        assert live == moves, f"{what}: jog live {live}, moved {moves}"
        assert steady_output(machine, JOG_LIVE_OUTPUT, 0.1) == live
        return live

    assert check("machine on, feed enabled, X selected", "x", True)
    assert not check("axis switch off", "off", True)
    machine.cnc.must("off")
    try:
        assert not check("machine off, X selected", "x", False)
    finally:
        machine.cnc.must("on")
    assert check("machine on again, X selected", "x", True)


def test_a_stopped_device_gets_no_outputs_and_holds_its_error_values(machine):
    """NMT stop from another node: the component sees the Stopped heartbeat, `outputs-live`
    drops and no RPDO1 follows it (but one already under way); the device applies its error
    values (0x6A06 = 0xFF, 0x6A07 = 0: every output off). NMT start: the outputs come back
    at once."""
    machine.select("x", 1)
    machine.ready_to_jog("x")
    wait_output(machine, MACHINE_ON_OUTPUT, True)
    mark = machine.nmt(NMT_STOP)
    machine.frames.wait_id(HEARTBEAT, bytes([STOPPED]), since=mark)
    machine.wait(lambda s: not s["pins"]["outputs-live"], 2, "outputs-live off")
    wait_output(machine, MACHINE_ON_OUTPUT, False)
    stopped_at = next(f.t for f in machine.frames.frames(HEARTBEAT, mark) if f.data[0] == STOPPED)
    time.sleep(0.5)
    late = [f.t - stopped_at for f in machine.frames.frames(RPDO1, mark) if f.t > stopped_at]
    assert all(t < 0.05 for t in late), late  # the loop's round before it saw the heartbeat
    assert outputs(machine) >> 1 == 0
    mark = machine.nmt(NMT_START)
    machine.frames.wait_id(HEARTBEAT, bytes([OPERATIONAL]), since=mark)
    machine.wait(lambda s: s["pins"]["outputs-live"], 5, "outputs-live again")
    wait_output(machine, MACHINE_ON_OUTPUT, True)
    machine.ready_to_jog("x")
