#!/usr/bin/env python3
"""CPU cost and stack depth of the release firmware, measured on its machine code.

    python tools/machine-bench/bench.py ELF [--stack-report FILE]

Boots the ELF in the emulator of `machine.py`, drives it like a CNC and an operator would
(NMT start, SDO requests, the selector switches, wheel edges, bus errors, time), and prints:

- the EXTI9_5 handler (a wheel edge) from entry to return: the worst case over every
  (previous, new) A/B level pair, feed disabled and enabled, with a cycle estimate and its
  CPU share at 20 kHz;
- per priority level, the longest stretch an interrupt of that level was held off (PRIMASK,
  BASEPRI, or a handler of the same or higher priority running) and by what (the handler
  and the function that raised the mask), and from it the worst latency from a wheel edge
  to its port read; with the CAN side at its busiest (an SDO request, a TPDO and a log line
  every millisecond), the highest edge rate with no merged edge;
- the path from an SDO request in receive FIFO 0 (RX0 interrupt entry) to its reply written
  to a transmit mailbox, over a spread of requests;
- every handler's deepest stack use, by priority level.

`--stack-report FILE` writes the stack and edge figures for `cargo xtask`, which checks
them against the stack budget and the edge limits. Exit status 1 when the firmware
misbehaves under the scenarios (a reply is wrong, a handler never ran), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import cycles  # noqa: E402
import machine  # noqa: E402
import stm32  # noqa: E402

SYSCLK_HZ = 72_000_000
# The STM32F103 needs 2 flash wait states above 48 MHz.
WAIT_STATES = 2
# The fastest human spin (edges per second) the figures are quoted for.
EDGE_RATE_HZ = 20_000
# Limits on the worst edge (entry to return) and on the highest edge rate with no merged
# edge while the CAN side is at its busiest (a 600-PPR encoder at 10 rev/s);
# `cargo xtask test` enforces them from the report file.
GOAL_CYCLES = 120
RATE_GOAL_HZ = 24_000
GPIOB_IDR = stm32.GPIOB + 0x08
# Milliseconds of the busiest CAN side.
BUSY_MS = 40

NODE_ID = 16
SDO_REQUEST = 0x600 + NODE_ID
SDO_REPLY = 0x580 + NODE_ID
TPDO1 = 0x180 + NODE_ID
EMCY = 0x080 + NODE_ID
HEARTBEAT = 0x700 + NODE_ID

WHEEL_A_BIT = 6
WHEEL_B_BIT = 7
# Selector lines on GPIOA, active low.
AXIS_X_LINE = 0
MULTIPLIER_X10_LINE = 6
# One turn of the quadrature cycle, (A, B) levels.
GRAY = [(0, 0), (1, 0), (1, 1), (0, 1)]


class ScenarioError(Exception):
    """The firmware did not do what the scenario expects."""


@dataclass
class EdgeSample:
    feed: str
    previous: tuple[int, int]
    new: tuple[int, int]
    invocation: machine.Invocation

    @property
    def raised(self) -> bool:
        return bool(self.invocation.pended)


@dataclass
class PathSample:
    label: str
    reply: stm32.CanFrame
    instructions: int
    cycles: int
    wait_state_cycles: int
    handlers: list[str]


def exception_cycles(invocation: machine.Invocation) -> int:
    """A handler's zero-wait-state cycles from exception entry to the end of its return."""
    return cycles.EXCEPTION_ENTRY + invocation.cycles + cycles.EXCEPTION_EXIT


def wait_state_cycles(refetches: int, flash_reads: int, entries: int, exits: int) -> int:
    """Extra cycles with flash wait states: every refetch, flash data read, vector fetch and
    handler's first fetch, and the refetch after each exception return."""
    return WAIT_STATES * (refetches + flash_reads + 2 * entries + exits)


class Rig:
    """The emulated board with a CAN master, switches and a wheel around it."""

    def __init__(self, elf: str) -> None:
        self.image = machine.FirmwareImage(elf)
        self.m = machine.Machine(self.image)
        self.periph = self.m.periph
        self.exti = self.image.exception_of("EXTI9_5")
        self.wheel_priority = 0
        self.rx0 = self.image.exception_of("USB_LP_CAN_RX0")
        self.levels = (1, 1)  # pull-ups: both wheel lines high at boot
        self.boot_instructions = self.m.boot()
        self.m.traced.add(self.exti)
        self.m.mask_levels = tuple(
            sorted(
                {self.periph.priority(e) for e in self.image.handlers if e not in machine.FAULTS}
            )
        )
        self.m.watch_reads.add(GPIOB_IDR)
        self.wheel_priority = self.periph.priority(self.exti)
        self.log_entry = self.image.symbols.get("_defmt_acquire")
        if self.log_entry is not None:
            self.m.pc_counts[self.log_entry & ~1] = 0
        self.settle("boot")

    def log_lines(self) -> int:
        """defmt log frames started so far (calls of `_defmt_acquire`)."""
        if self.log_entry is None:
            return 0
        return self.m.pc_counts[self.log_entry & ~1]

    # -- time and the bus ------------------------------------------------------------------

    def settle(self, label: str) -> list[machine.Invocation]:
        """Runs everything pending, letting queued frames go out, until nothing moves."""
        done = self.m.run_pending(label)
        while self.periph.complete_transmissions():
            done += self.m.run_pending(label)
        return done

    def tick(self, ms: int, label: str = "time") -> None:
        for _ in range(ms):
            self.periph.tick()
            self.settle(label)

    def receive(self, cob_id: int, data: bytes, label: str) -> list[machine.Invocation]:
        self.periph.receive(stm32.CanFrame(cob_id, bytes(data)))
        done = self.m.run_pending(label)
        return done + self.settle(label)

    def sent(self, since: int, cob_id: int) -> list[stm32.CanFrame]:
        return [f for f in self.periph.transmitted[since:] if f.cob_id == cob_id]

    def sdo(self, label: str, request: bytes) -> PathSample:
        """One SDO request; measures RX0 entry to the reply's transmit request."""
        done = self.receive(SDO_REQUEST, request.ljust(8, b"\0"), label)
        if not done or done[0].exception != self.rx0:
            raise ScenarioError(f"{label}: the RX0 interrupt did not run first")
        instructions = cycle_sum = refetches = flash_reads = 0
        names = []
        for index, invocation in enumerate(done):
            names.append(invocation.name)
            reply = next((m for m in invocation.transmits if m.frame.cob_id == SDO_REPLY), None)
            if reply is None:
                instructions += invocation.instructions
                cycle_sum += invocation.cycles
                refetches += invocation.refetches
                flash_reads += invocation.flash_reads
                continue
            instructions += reply.instructions
            cycle_sum += reply.cycles
            refetches += reply.refetches
            flash_reads += reply.flash_reads
            # Entry of the RX0 interrupt; each later handler tail-chains onto the previous.
            total = cycles.EXCEPTION_ENTRY + cycle_sum + cycles.TAIL_CHAIN * index
            extra = wait_state_cycles(refetches, flash_reads, index + 1, 0)
            return PathSample(label, reply.frame, instructions, total, extra, names)
        raise ScenarioError(f"{label}: no SDO reply")

    def expect_sdo(self, label: str, request: bytes, reply: bytes) -> PathSample:
        sample = self.sdo(label, request)
        if sample.reply.data != reply:
            raise ScenarioError(
                f"{label}: reply {sample.reply.data.hex(' ')}, expected {reply.hex(' ')}"
            )
        return sample

    # -- switches and wheel ----------------------------------------------------------------

    def select(self, axis_line: int | None, multiplier_line: int | None) -> None:
        port = 0xFFFF
        for line in (axis_line, multiplier_line):
            if line is not None:
                port &= ~(1 << line)
        self.periph.pins.ports[stm32.GPIOA] = port
        # Four stable samples 5 ms apart, plus the sample phase.
        self.tick(30, "selector")

    def edge(self, new: tuple[int, int], feed: str) -> EdgeSample:
        previous = self.levels
        port = self.periph.pins.ports[stm32.GPIOB]
        port &= ~((1 << WHEEL_A_BIT) | (1 << WHEEL_B_BIT))
        port |= (new[0] << WHEEL_A_BIT) | (new[1] << WHEEL_B_BIT)
        self.periph.pins.ports[stm32.GPIOB] = port
        lines = 0
        if new[0] != previous[0]:
            lines |= 1 << WHEEL_A_BIT
        if new[1] != previous[1]:
            lines |= 1 << WHEEL_B_BIT
        if not lines:
            # A line went and came back before the handler read the port: the interrupt
            # still runs and sees no change.
            lines = 1 << WHEEL_A_BIT
        self.periph.set_exti_pending(lines)
        self.m._pend(self.exti)
        done = self.settle(f"edge {feed}")
        self.levels = new
        invocation = next((i for i in done if i.exception == self.exti), None)
        if invocation is None:
            raise ScenarioError("EXTI9_5 did not run: is the edge interrupt enabled?")
        if self.periph.word(stm32.EXTI + 0x14) & ((1 << WHEEL_A_BIT) | (1 << WHEEL_B_BIT)):
            raise ScenarioError("EXTI9_5 left its pending bits set")
        return EdgeSample(feed, previous, new, invocation)

    def step(self, direction: int, feed: str) -> EdgeSample:
        index = GRAY.index(self.levels)
        return self.edge(GRAY[(index + direction) % 4], feed)

    def edge_suite(self, feed: str) -> list[EdgeSample]:
        """Detents both ways, then every (previous, new) pair from every phase of a detent."""
        samples = []
        for direction in (1, -1, 1):
            for _ in range(12):
                samples.append(self.step(direction, feed))
        self.tick(3)
        for _phase in range(4):
            samples.append(self.step(1, feed))
            for previous in GRAY:
                for new in GRAY:
                    while self.levels != previous:
                        samples.append(self.step(1, feed))
                    samples.append(self.edge(new, feed))
            self.tick(3)
        for _ in range(8):
            samples.append(self.step(-1, feed))
        self.tick(3)
        return samples


def sdo_upload(index: int, sub: int) -> bytes:
    return bytes([0x40, index & 0xFF, index >> 8, sub])


def sdo_download(index: int, sub: int, value: int, size: int) -> bytes:
    command = 0x23 | ((4 - size) << 2)
    return bytes([command, index & 0xFF, index >> 8, sub]) + value.to_bytes(size, "little")


def sdo_ok(index: int, sub: int) -> bytes:
    return bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])


def sdo_value(index: int, sub: int, value: int, size: int) -> bytes:
    command = 0x43 | ((4 - size) << 2)
    return bytes([command, index & 0xFF, index >> 8, sub]) + value.to_bytes(size, "little").ljust(
        4, b"\0"
    )


def sdo_abort(index: int, sub: int, code: int) -> bytes:
    return bytes([0x80, index & 0xFF, index >> 8, sub]) + code.to_bytes(4, "little")


@dataclass
class Results:
    edges: list[EdgeSample]
    sdo: list[PathSample]
    rig: Rig
    busy: "Busy"


def run(elf: str) -> Results:
    rig = Rig(elf)
    start = len(rig.periph.transmitted)
    if rig.sent(0, HEARTBEAT) != [stm32.CanFrame(HEARTBEAT, b"\0")]:
        raise ScenarioError("no boot-up frame")

    # Feed disabled: pre-operational, no axis.
    edges = rig.edge_suite("disabled")
    if rig.sent(start, TPDO1):
        raise ScenarioError("TPDO1 sent while pre-operational")

    paths = []
    rig.receive(0x000, bytes([0x01, NODE_ID]), "NMT start")
    rig.select(AXIS_X_LINE, MULTIPLIER_X10_LINE)
    paths.append(
        rig.expect_sdo("upload 0x2010:01 (axis)", sdo_upload(0x2010, 1), sdo_value(0x2010, 1, 1, 1))
    )
    paths.append(
        rig.expect_sdo(
            "download 0x2000 = 1 (feed on)", sdo_download(0x2000, 0, 1, 1), sdo_ok(0x2000, 0)
        )
    )

    start = len(rig.periph.transmitted)
    edges += rig.edge_suite("enabled")
    feed = rig.sent(start, TPDO1)
    positions = {int.from_bytes(f.data[:4], "little", signed=True) for f in feed}
    if len(positions) < 2 or any(f.data[4] != 1 or f.data[5] != 10 for f in feed):
        raise ScenarioError(f"feed records do not follow the wheel: {[str(f) for f in feed[:4]]}")

    requests = [
        ("upload 0x1000 (device type)", sdo_upload(0x1000, 0), sdo_value(0x1000, 0, 0, 4)),
        ("upload 0x1018:01 (vendor ID)", sdo_upload(0x1018, 1), sdo_value(0x1018, 1, 0, 4)),
        ("upload 0x2031 (feed sequence)", sdo_upload(0x2031, 0), None),
        ("upload 0x6004 (position)", sdo_upload(0x6004, 0), None),
        ("download 0x1017 = 1000 (heartbeat)", sdo_download(0x1017, 0, 1000, 2), sdo_ok(0x1017, 0)),
        (
            "download 0x1800:05 = 100 (event timer)",
            sdo_download(0x1800, 5, 100, 2),
            sdo_ok(0x1800, 5),
        ),
        (
            "abort: upload 0x1234 (no object)",
            sdo_upload(0x1234, 0),
            sdo_abort(0x1234, 0, 0x0602_0000),
        ),
        ("abort: download 0x2000 = 5 (range)", sdo_download(0x2000, 0, 5, 1), None),
        (
            "abort: download 0x1000 (read-only)",
            sdo_download(0x1000, 0, 1, 4),
            sdo_abort(0x1000, 0, 0x0601_0002),
        ),
        (
            "segmented upload initiate 0x1008",
            sdo_upload(0x1008, 0),
            bytes([0x41, 0x08, 0x10, 0x00, 13, 0, 0, 0]),
        ),
        ("upload segment 1 of 0x1008", bytes([0x60]), b"\x00CNC han"),
        (
            "upload segment 2 of 0x1008",
            bytes([0x70]),
            bytes([0x10 | 0x01 | (1 << 1)]) + b"dwheel\0",
        ),
    ]
    for label, request, reply in requests:
        if reply is None:
            sample = rig.sdo(label, request)
            if label.startswith("abort") and sample.reply.data[0] != 0x80:
                raise ScenarioError(f"{label}: expected an abort, got {sample.reply}")
            if not label.startswith("abort") and sample.reply.data[0] & 0xF3 != 0x43:
                raise ScenarioError(f"{label}: expected an expedited upload, got {sample.reply}")
        else:
            sample = rig.expect_sdo(label, request, reply)
        paths.append(sample)

    # Bus trouble: error passive (an EMCY), then error-active again (found by polling).
    start = len(rig.periph.transmitted)
    rig.periph.set_error_state((128 << 16) | 0b011)
    rig.settle("bus error")
    rig.tick(12, "bus error")
    emcy = rig.sent(start, EMCY)
    if not emcy or emcy[0].data[:2] != (0x8120).to_bytes(2, "little"):
        raise ScenarioError(f"no EMCY 0x8120 on error passive: {[str(f) for f in emcy]}")
    rig.periph.set_error_state(0)
    rig.tick(25, "bus error")

    # A full receive FIFO drained in one interrupt.
    for _ in range(3):
        rig.periph.receive(stm32.CanFrame(0x080, b""))
    rig.settle("three frames")

    # Time: heartbeats, event-timer TPDOs, the selector and LED tasks.
    start = len(rig.periph.transmitted)
    rig.tick(1100)
    heartbeats = rig.sent(start, HEARTBEAT)
    if not heartbeats or heartbeats[0].data != b"\x05":
        raise ScenarioError(f"no operational heartbeat in 1.1 s: {[str(f) for f in heartbeats]}")
    busy = busy_can_side(rig)
    return Results(edges, paths, rig, busy)


@dataclass
class Busy:
    """The busiest CAN side: what it did and what it cost."""

    ms: int
    sdo_replies: int
    tpdos: int
    log_lines: int
    # CPU cycles of everything but the wheel's own handlers, worst millisecond.
    worst_ms_cycles: int
    edges: list[EdgeSample]


def busy_can_side(rig: Rig) -> Busy:
    """Every millisecond an SDO request, a detent (a TPDO) and an illegal jump and back (a
    log line, "encoder: ... illegal transition(s)"), for `BUSY_MS` ms."""
    # TPDO1 without inhibit time, so that every detent gets its frame: disable, set, enable.
    cob = 0x180 + NODE_ID
    rig.expect_sdo(
        "busy: TPDO1 off", sdo_download(0x1800, 1, (1 << 31) | cob, 4), sdo_ok(0x1800, 1)
    )
    rig.expect_sdo("busy: inhibit 0", sdo_download(0x1800, 3, 0, 2), sdo_ok(0x1800, 3))
    rig.expect_sdo("busy: TPDO1 on", sdo_download(0x1800, 1, cob, 4), sdo_ok(0x1800, 1))
    start = len(rig.periph.transmitted)
    logs_before = rig.log_lines()
    samples = []
    worst_ms = 0
    replies = 0
    for i in range(BUSY_MS):
        label = f"busy {i}"
        mark = len(rig.m.invocations)
        sample = rig.sdo(label, sdo_upload(0x6004, 0))
        replies += sample.reply.data[0] == 0x43
        for _ in range(4):
            samples.append(rig.step(1, "busy"))
        rest = rig.levels
        samples.append(rig.edge((1 - rest[0], 1 - rest[1]), "busy"))
        samples.append(rig.edge(rest, "busy"))
        rig.tick(1, label)
        spent = sum(
            exception_cycles(inv)
            for inv in rig.m.invocations[mark:]
            if inv.priority != rig.wheel_priority
        )
        worst_ms = max(worst_ms, spent)
    # The last millisecond's illegal jumps are logged by the next round (at the latest the
    # next 5 ms selector sample).
    rig.tick(5, "busy: last round")
    tpdos = len(rig.sent(start, TPDO1))
    logs = rig.log_lines() - logs_before
    if replies != BUSY_MS or tpdos < BUSY_MS or logs < BUSY_MS:
        raise ScenarioError(
            f"the busy CAN side did not happen: {replies} SDO replies, {tpdos} TPDOs, {logs} log "
            f"lines in {BUSY_MS} ms"
        )
    return Busy(BUSY_MS, replies, tpdos, logs, worst_ms, samples)


# -- report -------------------------------------------------------------------------------


def by_function(
    image: machine.FirmwareImage, invocation: machine.Invocation
) -> dict[str, tuple[int, int]]:
    """Instructions and cycles of a traced invocation per function, in order of first use."""
    spent: dict[str, tuple[int, int]] = {}
    for address, charged in invocation.trace or []:
        name = image.function_at(address)
        count, total = spent.get(name, (0, 0))
        spent[name] = (count + 1, total + charged)
    return spent


def levels_str(levels: tuple[int, int]) -> str:
    return f"{levels[0]}{levels[1]}"


def cpu_report(results: Results) -> tuple[str, dict]:
    lines = ["## 2. CPU cost (release machine code, instruction-level emulation)", ""]
    edges = results.edges
    worst = max(edges, key=lambda s: (exception_cycles(s.invocation), s.invocation.instructions))
    inv = worst.invocation
    edge_cycles = exception_cycles(inv)
    edge_ws = wait_state_cycles(inv.refetches, inv.flash_reads, 1, 1)
    lines.append(
        f"EXTI9_5, one wheel edge, entry to return: {len(edges)} edges over all 16 (previous, new) "
        "A/B pairs, feed disabled and enabled"
    )
    lines.append("")
    lines.append(
        "| A B before -> after | feed | edges | raised feed event | worst instructions "
        "| worst cycles |"
    )
    lines.append("|---|---|---:|---|---:|---:|")
    groups: dict[tuple, list[EdgeSample]] = {}
    for s in edges:
        groups.setdefault((s.previous, s.new, s.feed), []).append(s)
    for (previous, new, feed), group in sorted(
        groups.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1])
    ):
        top = max(group, key=lambda s: exception_cycles(s.invocation))
        raised = sum(1 for s in group if s.raised)
        lines.append(
            f"| {levels_str(previous)} -> {levels_str(new)} | {feed} | {len(group)} | "
            f"{raised} of {len(group)} | {top.invocation.instructions} | "
            f"{exception_cycles(top.invocation)} |"
        )
    rate = SYSCLK_HZ / edge_cycles
    rate_ws = SYSCLK_HZ / (edge_cycles + edge_ws)
    share = EDGE_RATE_HZ * edge_cycles / SYSCLK_HZ
    share_ws = EDGE_RATE_HZ * (edge_cycles + edge_ws) / SYSCLK_HZ
    lines += [
        "",
        f"Worst edge: {levels_str(worst.previous)} -> {levels_str(worst.new)}, feed {worst.feed}"
        f"{', raising the feed event' if worst.raised else ''}: {inv.instructions} instructions, "
        f"{inv.cycles} cycles + entry {cycles.EXCEPTION_ENTRY} + exit {cycles.EXCEPTION_EXIT} = "
        f"{edge_cycles} cycles at zero wait states; +{edge_ws} with {WAIT_STATES} flash wait "
        f"states ({inv.refetches} refetches, {inv.flash_reads} flash data reads) = "
        f"{edge_cycles + edge_ws}.",
        "Instruction mix of the worst edge: "
        + ", ".join(f"{k} {v}" for k, v in sorted(inv.mix.items()))
        + ".",
        f"Edge rate the handler alone sustains at 72 MHz (each edge handled before the next, "
        f"nothing else running): {rate / 1000:.0f} kHz ({rate_ws / 1000:.0f} kHz with wait "
        "states).",
        f"CPU share at {EDGE_RATE_HZ // 1000} kHz edges: {100 * share:.1f} % "
        f"({100 * share_ws:.1f} % with wait states).",
        f"Limit {GOAL_CYCLES} cycles per edge incl. entry and exit: "
        + ("met" if edge_cycles <= GOAL_CYCLES else f"NOT MET ({edge_cycles} cycles)")
        + f" at zero wait states; with wait states {edge_cycles + edge_ws} cycles.",
    ]
    lines += ["", "Where the worst edge's cycles go (by function):", ""]
    lines += ["| function | instructions | cycles |", "|---|---:|---:|"]
    for name, (count, spent) in by_function(results.rig.m.image, inv).items():
        lines.append(f"| {name} | {count} | {spent} |")
    lines.append(
        f"| exception entry + exit | - | {cycles.EXCEPTION_ENTRY + cycles.EXCEPTION_EXIT} |"
    )
    lines.append("")
    held, latency, wait, rate = latency_report(results, edge_cycles)
    lines += held
    lines += ["", "SDO request in FIFO 0 (RX0 entry) to its reply's transmit request:", ""]
    lines.append("| request | reply | handlers | instructions | cycles | + wait states |")
    lines.append("|---|---|---|---:|---:|---:|")
    for p in results.sdo:
        lines.append(
            f"| {p.label} | {p.reply.data.hex(' ')} | {' -> '.join(p.handlers)} | "
            f"{p.instructions} | {p.cycles} | {p.wait_state_cycles} |"
        )
    worst_sdo = max(results.sdo, key=lambda p: p.cycles)
    lines += [
        "",
        f"Worst SDO path: {worst_sdo.label}: {worst_sdo.instructions} instructions, "
        f"{worst_sdo.cycles} cycles ({worst_sdo.cycles / SYSCLK_HZ * 1e6:.1f} us at 72 MHz), "
        f"{worst_sdo.cycles + worst_sdo.wait_state_cycles} with wait states "
        f"({(worst_sdo.cycles + worst_sdo.wait_state_cycles) / SYSCLK_HZ * 1e6:.1f} us).",
        "",
    ]
    figures = {
        "edge_instructions": inv.instructions,
        "edge_cycles": edge_cycles,
        "edge_latency": latency,
        "edge_held": wait,
        "merge_free_hz": int(rate),
        "edge_cycles_ws": edge_cycles + edge_ws,
        "sdo_instructions": worst_sdo.instructions,
        "sdo_cycles": worst_sdo.cycles,
    }
    return "\n".join(lines), figures


def logical(priority: int) -> str:
    """RTIC's logical priority of an NVIC priority byte (4 priority bits): byte 0, the reset
    priority, is logical 16."""
    return f"priority {16 - (priority >> 4)}"


def latency_report(results: Results, edge_cycles: int) -> tuple[list[str], int, int, float]:
    """Per priority level, the longest it was held off and by what; the worst latency from a
    wheel edge to its port read, the longest wait in it; the highest edge rate with no merged
    edge with the CAN side at its busiest."""
    rig = results.rig
    m = rig.m
    wheel = rig.wheel_priority
    lines = [
        "",
        "Longest stretch each priority level was held off, over every scenario (by PRIMASK or "
        "BASEPRI in a handler of lower priority, or by a handler of the same or a higher "
        "priority running, entry and exit included):",
        "",
        "| level | handlers | masked by PRIMASK/BASEPRI | in | raised by | a handler running "
        "| which |",
        "|---|---|---:|---|---|---:|---|",
    ]
    names: dict[int, list[str]] = {}
    for exception, name in m.image.handlers.items():
        if exception not in machine.FAULTS:
            names.setdefault(m.periph.priority(exception), []).append(name)
    for level in m.mask_levels:
        masked, _, where, at = m.longest_masks.get(level, (0, 0, "-", 0))
        raised_by = m.image.function_at(at) if masked else "-"
        running = [i for i in m.invocations if i.priority <= level]
        top = max(running, key=exception_cycles, default=None)
        lines.append(
            f"| {logical(level)} | {', '.join(sorted(names.get(level, [])))} | {masked} | "
            f"{where if masked else '-'} | {raised_by} | {exception_cycles(top) if top else 0} | "
            f"{top.name if top else '-'} |"
        )
    wheel_runs = [i for i in m.invocations if i.exception == rig.exti]
    # The edge path may neither panic nor log: no function of either kind ran in any edge.
    for run in wheel_runs:
        called = {m.image.function_at(address) for address, _ in run.trace or []}
        bad = sorted(name for name in called if "panic" in name or "defmt" in name)
        if bad:
            raise ScenarioError(f"the wheel's edge handler ran {', '.join(bad)} ({run.label})")
    missing = [i for i in wheel_runs if GPIOB_IDR not in i.reads]
    if missing:
        raise ScenarioError("an EXTI9_5 invocation did not read GPIOB's input register")
    to_read = max(i.reads[GPIOB_IDR] for i in wheel_runs)
    after_read = max(i.cycles - i.reads[GPIOB_IDR] for i in wheel_runs)
    others = [i for i in m.invocations if i.priority <= wheel and i.exception != rig.exti]
    other = max(others, key=exception_cycles, default=None)
    masked, _, masked_in, masked_at = m.longest_masks.get(wheel, (0, 0, "-", 0))
    masked_by = m.image.function_at(masked_at) if masked else "-"
    waits = {
        "the previous edge's handler after its read, then tail-chaining": after_read
        + cycles.TAIL_CHAIN,
        f"another handler at the wheel's priority or above ({other.name if other else '-'})": (
            exception_cycles(other) if other else 0
        ),
        f"PRIMASK or BASEPRI at the wheel's priority (raised by {masked_by} in {masked_in})": (
            masked
        ),
    }
    cause, wait = max(waits.items(), key=lambda kv: kv[1])
    latency = wait + cycles.EXCEPTION_ENTRY + to_read
    lines += [
        "",
        f"Worst latency from a wheel edge to its port read: {latency} cycles "
        f"({latency / SYSCLK_HZ * 1e6:.2f} us at 72 MHz) = the longest wait, {wait} cycles "
        f"({cause}), + entry {cycles.EXCEPTION_ENTRY} + {to_read} cycles of the handler up to "
        f"and including its read of GPIOB_IDR. The waits: "
        + "; ".join(f"{k}: {v}" for k, v in waits.items())
        + ".",
    ]
    busy = results.busy
    share = busy.worst_ms_cycles * 1000 / SYSCLK_HZ
    by_cpu = (1 - share) * SYSCLK_HZ / edge_cycles
    by_latency = SYSCLK_HZ / latency
    rate = min(by_cpu, by_latency)
    lines += [
        "",
        f"Busiest CAN side ({busy.ms} ms, each with an SDO request, a TPDO and a log line: "
        f"{busy.sdo_replies} replies, {busy.tpdos} TPDOs, {busy.log_lines} log lines): its worst "
        f"millisecond took {busy.worst_ms_cycles} cycles ({100 * share:.1f} % of the CPU). "
        f"Highest edge rate with no merged edge then: {rate / 1000:.1f} kHz "
        f"(edges at most one latency apart: {by_latency / 1000:.1f} kHz; the CPU the CAN side "
        f"leaves, at {edge_cycles} cycles per edge: {by_cpu / 1000:.0f} kHz). "
        f"Limit {RATE_GOAL_HZ / 1000:.0f} kHz: " + ("met." if rate >= RATE_GOAL_HZ else "NOT MET."),
    ]
    return lines, latency, wait, rate


@dataclass
class Level:
    priority: int
    handlers: list[str]
    deepest: str
    depth: int


def stack_levels(results: Results) -> list[Level]:
    m = results.rig.m
    by_priority: dict[int, list[str]] = {}
    for exception, name in m.image.handlers.items():
        if exception in machine.FAULTS:
            continue
        by_priority.setdefault(m.periph.priority(exception), []).append(name)
    levels = []
    for priority, names in sorted(by_priority.items()):
        depths = {}
        for name in names:
            runs = [i.depth for i in m.invocations if i.name == name]
            if not runs:
                raise ScenarioError(f"{name} never ran: its stack depth is not measured")
            depths[name] = max(runs)
        deepest = max(depths, key=depths.get)
        levels.append(Level(priority, sorted(names), deepest, depths[deepest]))
    return levels


def stack_report(results: Results) -> tuple[str, list[str]]:
    """The stack table for the console and the lines of the report file for xtask."""
    m = results.rig.m
    levels = stack_levels(results)
    frame = machine.FRAME_BYTES + 4
    total = m.thread_depth + sum(level.depth + frame for level in levels)
    region = m.stack_top - m.stack_bottom
    painted = m.painted_depth()
    lowest = m.stack_top - m.lowest_sp
    lines = [
        "Worst-case stack (each preemption level's deepest handler on top of thread mode):",
        f"  thread mode (init, idle)             {m.thread_depth:>5} B",
    ]
    report = [f"thread\t{m.thread_depth}"]
    for level in levels:
        lines.append(
            f"  {logical(level.priority):<15} {level.deepest:<20} {level.depth:>5} B + {frame} B "
            "frame"
            f"  ({', '.join(level.handlers)})"
        )
        report.append(
            f"level\t{level.priority}\t{level.deepest}\t{level.depth}\t{','.join(level.handlers)}"
        )
    lines += [
        f"  total                                {total:>5} B",
        f"  measured in this run: lowest SP {lowest} B below the top, deepest painted word "
        f"{painted} B ("
        + (
            f"consistent: {lowest - painted} B reserved below the deepest write were never written"
            if painted <= lowest
            else "INCONSISTENT: a write below the lowest SP seen"
        )
        + ")",
        f"  stack region (its top to its end, _stack_start to _stack_end) {region} B",
    ]
    report += [
        f"frame\t{frame}",
        f"total\t{total}",
        f"lowest\t{lowest}",
        f"painted\t{painted}",
        f"region\t{region}",
    ]
    return "\n".join(lines), report


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("elf", help="the release firmware ELF")
    parser.add_argument("--stack-report", help="write the stack figures here for cargo xtask")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")
    args = parser.parse_args(argv)
    try:
        results = run(args.elf)
        cpu, figures = cpu_report(results)
        stack, report = stack_report(results)
        report += [
            f"edge\t{figures['edge_cycles']}",
            f"latency\t{figures['edge_latency']}",
            f"held\t{figures['edge_held']}",
            f"rate\t{figures['merge_free_hz']}",
        ]
    except ScenarioError as error:
        print(f"machine-bench: {error}", file=sys.stderr)
        return 1
    if args.quiet:
        print(
            f"machine-bench: EXTI9_5 worst edge {figures['edge_instructions']} instructions, "
            f"{figures['edge_cycles']} cycles ({figures['edge_cycles_ws']} with wait states), "
            f"held off at most {figures['edge_held']} cycles, latency to its port read "
            f"{figures['edge_latency']} cycles, merge-free with the CAN side busiest up to "
            f"{figures['merge_free_hz'] / 1000:.1f} kHz; "
            f"SDO worst {figures['sdo_instructions']} instructions, {figures['sdo_cycles']} cycles"
        )
    else:
        print(cpu)
    if args.stack_report:
        # cargo xtask prints the stack table from this file, with the budget's headroom.
        Path(args.stack_report).write_text("\n".join(report) + "\n")
    else:
        print(stack)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
