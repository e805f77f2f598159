"""The emulated board in real time: `machine.Machine` paced against the wall clock, its CAN
bus on an SLCAN TCP port and its pins on a control TCP port, the defmt log (RTT up-channel
0) written to stdout as raw bytes for `defmt-print` (or to a file), or with `--defmt-print`
decoded by a `defmt-print` the server runs itself (its output on stderr) and restarts at
every reset, so that a log frame the reset broke never reaches the next boot's decoder, and
whenever the CPU goes from one image to the other (loader, application: each its own
ELF's log).

    python server.py [--loader ELF] [--elf ELF] --can-port P --stim-port Q [--flash FILE]
        [--dip N] [--defmt-print PATH] [--cut-seed N]

`--loader` and `--elf` (the application) are flashed as a probe flashes them (their pages
erased and written, every other page as the `--flash` file holds it: the whole flash, or an
older file of the parameter pages alone); the CPU boots the loader. Without `--loader` the
application starts alone, as before the loader; without `--elf` the application slot is
what the flash file holds (an application an earlier update wrote, or nothing).

The CPU starts only once a client is on the CAN port, so the boot-up frame is the first
thing the master reads. The control port listens at once.

Pacing: emulated time never runs ahead of the wall clock (the loop waits on the sockets
instead); when the emulation falls behind by more than `MAX_LAG` (a busy stretch: boot,
a flash erase in Python's slow path) the wall clock reference slips, so emulated time never
rushes to catch up. `status` reports the slips. An idle CPU (YIELD, nothing to take) waits
on the sockets until its next event, and input arriving meanwhile reaches it at once.

SLCAN (Lawicel, as python-can's `slcan` interface speaks it): `O`, `L`, `C` answer `\\r`;
`S0`..`S8` set the bit rate of the host's side of the bus (10 .. 1000 kbit/s; unset, the bus
runs at whatever the node's BTR gives), `V`/`N`/`F` report; `t`/`r` frames are put on the bus
(`z\\r`), `T`/`R` too (`Z\\r`); the node's frames come as `tIIIL<data>\\r`.

Control line, one command a line, each answered `ok` once applied (some with lines before
it) or `err <reason>`: `turn <n>` (n signed detents, edge by edge as valid quadrature from
the current A/B levels; the reply comes 25 ms after the last edge), `ab <0..3>` (A = bit 0,
B = bit 1 directly: chatter, illegal jumps), `axis <off|x|y|z|w|v>`, `mult <1|10|100>` (the
switch lines; the firmware's debouncing decides when the selection changes),
`dip <0..255>` (switch n on = bit n-1, read by the firmware at its next reset), `power`
(power cut and power-on: SRAM lost, the flash kept, a flash operation running at that
instant left half done as `Fpec.cut` says), `cut <n> <before|inside>` (cut the power at the
n-th flash operation from now, 1 the next, anywhere in the flash (a page erase or a
half-word program of the loader's, the application's or a parameter store): before it
starts or inside it; `cut off` disarms), `flash-ops` (`flash-ops ops=N erases=N programs=N
cuts=N armed=N|-` then `ok`: the operations started so far, the cuts that left one half
done, the operations until the armed cut), `mode` (`mode loader|application|none`: which
image the CPU is in, then `ok`), `peek <address> <length>` (`data <hex>` then `ok`: flash or
SRAM content, at most 4096 bytes, e.g. the image header or the HANDOFF words), `snapshot`
(remember the whole flash), `rollback` (the flash as remembered, then a power-on), `reload`
(the flash as the `--flash` file holds it, e.g. after a test rewrote it, then a power-on; a
file of the parameter pages alone replaces only them), `reset` (NRST), `buserr <tx> <rx>`
(transmit / receive errors seen by the node: TEC += 8 each, REC += 1 each), `busoff <ms>`
(TEC past 255, and the bus stays faulty for ms before the automatic recovery can run),
`hold <ms|off|on>` (the bus is taken by other traffic: the node's mailboxes wait),
`trickle <ms|off>` (other traffic leaves the node one frame per ms, the first after ms),
`dominant <ms|off|on>` (the bus is stuck dominant: no frame passes either way, frames from
the host are lost, and a controller leaving initialization or sleep mode cannot synchronise),
`storm <ms>` (an interrupt storm on TIM2's vector starves the CAN task), `stall <ms>` (the
same for 1..400 ms, shorter than the watchdog: the CAN task falls behind while the CAN
interrupts keep receiving, and catches up), `corrupt` (flips
a bit of the parameter page), `leds` (the LED history: `led <ms> <run|err> <0|1>` lines,
then `ok`), `status` (one `status key=value ...` line, then `ok`; `outputs=0x..` the digital
outputs driven high, bit n = board output n + 1, and `jog=0|1` output 1, "jog live"),
`rate <kbit|auto>`.
"""

from __future__ import annotations

import argparse
import selectors
import socket
import subprocess
import sys
import time
from pathlib import Path

# The chip model (tools/stm32emu) is a package beside this folder; the SLCAN codec is the host
# component's (host/src; standard library only, so this venv needs no python-can for it).
sys.path[:0] = [
    str(Path(__file__).resolve().parents[1]),
    str(Path(__file__).resolve().parents[2] / "host" / "src"),
]

from canopen_handwheel import slcan  # noqa: E402
from stm32emu import cortex, periph  # noqa: E402
from stm32emu import machine as machine_mod  # noqa: E402
from stm32emu.image import APPLICATION, LOADER  # noqa: E402

MAX_LAG = 0.05
# An SLCAN line is 30 bytes at most; a client's unfinished line beyond this is refused.
LONGEST_SLCAN_LINE = 64


class Client:
    def __init__(self, sock: socket.socket, kind: str) -> None:
        self.sock = sock
        self.kind = kind
        self.buffer = b""  # the control line's unfinished line
        self.lines = slcan.LineSplitter(LONGEST_SLCAN_LINE)  # the CAN port's

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError:
            pass


class Decoder:
    """`defmt-print -e ELF` fed through a pipe, its output on this process's stderr, started
    anew at every reset and with the other image's ELF when the CPU goes from one image to
    the other (`restart`; `elfs`: image kind -> ELF, only images that log with defmt). While
    an image without a defmt log runs (a loader of before), nothing is decoded: it writes no RTT
    log. A decoder that exits is restarted too: the board never dies of a broken log pipe."""

    def __init__(self, defmt_print: str, elfs: dict[str, str], kind: str) -> None:
        self.defmt_print = defmt_print
        self.elfs = elfs
        self.kind = kind
        self.proc: subprocess.Popen | None = None
        self.restarts = 0
        self._start()

    def _start(self) -> None:
        if self.kind not in self.elfs:
            self.proc = None
            return
        command = [self.defmt_print, "-e", self.elfs[self.kind]]
        self.proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=sys.stderr)

    def write(self, data: bytes) -> None:
        if self.proc is None:
            return
        try:
            self.proc.stdin.write(data)
        except (BrokenPipeError, ValueError):
            self.restart()

    def flush(self) -> None:
        if self.proc is None:
            return
        try:
            self.proc.stdin.flush()
        except (BrokenPipeError, ValueError):
            self.restart()

    def restart(self, kind: str | None = None) -> None:
        """Ends the running decoder (it sees the end of its stream) and starts another, for
        the image `kind` (else the same)."""
        self.close()
        self.restarts += 1
        if kind is not None:
            self.kind = kind
        self._start()

    def close(self) -> None:
        if self.proc is None:
            return
        try:
            self.proc.stdin.close()
        except (BrokenPipeError, ValueError):
            pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def logs_with_defmt(elf: str) -> bool:
    """Whether the ELF carries defmt's symbol table (an image without it logs nothing)."""
    from elftools.elf.elffile import ELFFile

    with open(elf, "rb") as f:
        return ELFFile(f).get_section_by_name(".defmt") is not None


class Server:
    def __init__(self, m: machine_mod.Machine, can_port: int, stim_port: int, log_out) -> None:
        self.m = m
        self.log_out = log_out
        self.log_broken = False
        self.snapshot: bytes | None = None
        m.on_reset = self._on_reset
        m.on_power_off = self.flush_log
        m.on_reset_start = self.flush_log
        m.on_handover = self.flush_log
        self.sel = selectors.DefaultSelector()
        self.can_listener = self._listen(can_port, "can-listen")
        self.stim_listener = self._listen(stim_port, "stim-listen")
        self.can_client: Client | None = None
        self.stim_clients: list[Client] = []
        self.slcan_open = True
        self.started = False
        self.wall0 = 0.0
        self.slips = 0
        self.frames_in = 0
        self.frames_out = 0
        m.on_frame = self._node_frame

    def _listen(self, port: int, kind: str) -> socket.socket:
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen(4)
        s.setblocking(False)
        self.sel.register(s, selectors.EVENT_READ, kind)
        return s

    # -- sockets ------------------------------------------------------------------------------

    def poll(self, timeout: float) -> None:
        for key, _ in self.sel.select(timeout):
            kind = key.data
            if kind in ("can-listen", "stim-listen"):
                sock, _ = key.fileobj.accept()
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setblocking(False)
                client = Client(sock, "can" if kind == "can-listen" else "stim")
                if client.kind == "can":
                    if self.can_client is not None:
                        self._drop(self.can_client)
                    self.can_client = client
                    self.slcan_open = True
                    if not self.started:
                        self.started = True
                        self.wall0 = time.monotonic()
                else:
                    self.stim_clients.append(client)
                self.sel.register(sock, selectors.EVENT_READ, client)
                continue
            client = kind
            try:
                data = client.sock.recv(4096)
            except OSError:
                data = b""
            if not data:
                self._drop(client)
                continue
            if client.kind == "can":
                self._slcan_input(client, data)
            else:
                client.buffer += data
                self._stim_input(client)

    def _drop(self, client: Client) -> None:
        try:
            self.sel.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()
        if client is self.can_client:
            self.can_client = None
        elif client in self.stim_clients:
            self.stim_clients.remove(client)

    # -- SLCAN --------------------------------------------------------------------------------

    def _slcan_input(self, client: Client, data: bytes) -> None:
        overflows = client.lines.overflows
        # A line typed by hand (`nc`) ends in `\n`: that ends a command here as `\r` does.
        for line in client.lines.feed(data.replace(b"\n", b"\r")):
            client.send(self._slcan_command(line))
        if client.lines.overflows > overflows:
            client.send(b"\a")  # after the lines before it: it is the last thing read

    def _slcan_command(self, line: bytes) -> bytes:
        frame = slcan.decode(line)
        if frame is not None:
            self.frames_in += 1
            self.m.deliver(
                periph.Frame(frame.id, frame.data, frame.extended, frame.remote, frame.length)
            )
            self.m.update_irqs()
            return slcan.ack(frame)
        if not line:
            return b"\r"
        text = line.decode("ascii", "replace")
        letter, args = text[0], text[1:]
        if letter in "OL":
            self.slcan_open = True
            return b"\r"
        if letter == "C":
            self.slcan_open = False
            return b"\r"
        if letter == "S" and len(args) == 1 and args.isdigit() and int(args) < 9:
            self.m.can.bus_bitrate = slcan.BITRATES[int(args)]
            return b"\r"
        if letter == "V":
            return b"V0101\r"
        if letter == "N":
            return b"NBOARD\r"
        if letter == "F":
            return b"F00\r"
        if letter in "sZ":
            return b"\r"
        return b"\a"  # an unknown command, or a frame line no frame can be read from

    def _node_frame(self, frame: periph.Frame) -> None:
        self.frames_out += 1
        if self.can_client is None or not self.slcan_open:
            return
        self.can_client.send(
            slcan.encode(
                slcan.Frame(frame.can_id, frame.data, frame.extended, frame.remote, frame.dlc)
            )
        )

    # -- control line -------------------------------------------------------------------------

    def _stim_input(self, client: Client) -> None:
        while b"\n" in client.buffer:
            line, client.buffer = client.buffer.split(b"\n", 1)
            words = line.decode("ascii", "replace").strip().lower().split()
            try:
                self._stim_command(client, words)
            except StimError as e:
                client.send(f"err {e}\n".encode())

    def _stim_command(self, client: Client, words: list[str]) -> None:
        m = self.m
        ok = lambda: client.send(b"ok\n")  # noqa: E731
        if not words:
            raise StimError("empty line")
        name, args = words[0], words[1:]

        def one(limit_low: int, limit_high: int) -> int:
            if not args:
                raise StimError("missing argument")
            if len(args) > 1:
                raise StimError("extra argument")
            try:
                value = int(args[0])
            except ValueError:
                raise StimError("bad number") from None
            if not limit_low <= value <= limit_high:
                raise StimError("out of range")
            return value

        if name == "turn":
            n = one(-10_000, 10_000)
            if n == 0:
                ok()
            else:
                m.turn(n, done=ok)
        elif name == "ab":
            m.set_ab(one(0, 3))
            m.schedule(machine_mod.EDGE_CYCLES, ok)  # once the edge has been handled
        elif name == "axis":
            axes = {"off": 0, "x": 1, "y": 2, "z": 3, "w": 4, "v": 5}
            if len(args) != 1:
                raise StimError("missing argument" if not args else "extra argument")
            if args[0] not in axes:
                raise StimError("bad axis")
            m.set_selectors(axis=axes[args[0]])
            ok()
        elif name == "mult":
            if len(args) != 1:
                raise StimError("missing argument" if not args else "extra argument")
            if args[0] not in ("1", "10", "100"):
                raise StimError("bad multiplier")
            m.set_selectors(mult=int(args[0]))
            ok()
        elif name == "dip":
            # The switch is binary: `dip 0b01100101` (switches 8..1) as well as decimal.
            if len(args) == 1 and args[0][:2].lower() in ("0b", "0x"):
                try:
                    args = [str(int(args[0], 0))]
                except ValueError:
                    raise StimError("bad number") from None
            m.set_dip(one(0, 255))
            ok()
        elif name == "power":
            self.flush_log()
            m.power_cut()
            ok()
        elif name == "cut":
            if args == ["off"]:
                m.fpec.armed = None
                ok()
                return
            if len(args) != 2 or not args[0].isdigit() or args[1] not in ("before", "inside"):
                raise StimError("usage: cut <n> <before|inside> | cut off")
            n = int(args[0])
            if not 1 <= n <= 100_000:
                raise StimError("out of range")
            m.fpec.arm(n, args[1] == "inside")
            ok()
        elif name == "flash-ops":
            if args:
                raise StimError("extra argument")
            fpec = m.fpec
            armed = "-" if fpec.armed is None else fpec.armed[0] - fpec.operations
            client.send(
                f"flash-ops ops={fpec.operations} erases={fpec.erases} "
                f"programs={fpec.programs} cuts={fpec.cuts} armed={armed}\n".encode()
            )
            ok()
        elif name == "mode":
            if args:
                raise StimError("extra argument")
            client.send(f"mode {m.running()}\n".encode())
            ok()
        elif name == "peek":
            if len(args) != 2:
                raise StimError("usage: peek <address> <length>")
            try:
                address, length = int(args[0], 0), int(args[1], 0)
            except ValueError:
                raise StimError("bad number") from None
            if not 1 <= length <= 4096 or not any(
                address in r and address + length <= r.end for r in (m.flash, m.ram)
            ):
                raise StimError("out of range")
            data = bytes(m.uc.mem_read(address, length))
            client.send(f"data {data.hex()}\n".encode())
            ok()
        elif name == "snapshot":
            self.snapshot = bytes(m.fpec.memory)
            ok()
        elif name in ("rollback", "reload"):
            if name == "rollback":
                if self.snapshot is None:
                    raise StimError("no snapshot")
                flash = self.snapshot
            else:
                if not m.flash_file:
                    raise StimError("no flash file")
                flash = m.stored_flash(bytes(m.fpec.memory))
            self.flush_log()
            m.write_flash(0, flash)
            m.power_cut()
            ok()
        elif name == "reset":
            m.pin_reset()
            ok()
        elif name == "buserr":
            if len(args) != 2 or not all(a.isdigit() for a in args):
                raise StimError("bad number")
            m.can.inject(int(args[0]), int(args[1]), m.now)
            m.update_irqs()
            ok()
        elif name == "busoff":
            ms = one(0, 60_000)
            m.can.bus_faulty_until = m.now + ms * cortex.CORE_HZ // 1000
            m.can.inject(32, 0, m.now)
            m.update_irqs()
            ok()
        elif name in ("hold", "dominant"):
            # Until a cycle, for ever (None) or no longer (0): a timed one ends by itself.
            if args == ["on"]:
                until = None
            elif args == ["off"]:
                until = 0
            else:
                until = m.now + one(0, 60_000) * cortex.CORE_HZ // 1000
            if name == "hold":
                m.can.bus_hold_until = until
            else:
                m.can.bus_dominant_until = until
            ok()
        elif name == "trickle":
            if args == ["off"]:
                m.can.bus_trickle = 0
                m.can.bus_hold_until = 0
            else:
                m.can.bus_trickle = one(1, 60_000) * cortex.CORE_HZ // 1000
                m.can.bus_hold_until = m.now + m.can.bus_trickle
            ok()
        elif name in ("storm", "stall"):
            # TIM2's vector (`feed_due`, priority 3) kept pending: `canopen` (priority 2)
            # does not run, while the CAN interrupts, at the same priority but on lower
            # vector numbers, keep receiving. A stall is a CAN side that falls behind and
            # catches up: shorter than the watchdog's 500 ms.
            longest = 60_000 if name == "storm" else 400
            m.storm_until = m.now + one(1, longest) * cortex.CORE_HZ // 1000
            m.storm_started_ms = m.ms()
            ok()
        elif name == "corrupt":
            at = m.memory.storage.origin - m.flash.origin + 8
            m.write_flash(at, bytes([m.fpec.memory[at] ^ 0x01]))
            ok()
        elif name == "rate":
            if args == ["auto"]:
                m.can.bus_bitrate = None
            else:
                m.can.bus_bitrate = one(1, 1000) * 1000
            ok()
        elif name == "leds":
            for change in m.leds:
                client.send(f"led {change.ms:.1f} {change.led} {int(change.on)}\n".encode())
            ok()
        elif name == "status":
            client.send(
                ("status " + " ".join(f"{k}={v}" for k, v in self.status().items()) + "\n").encode()
            )
            ok()
        else:
            raise StimError("unknown command")

    def status(self) -> dict:
        m = self.m
        can = m.can
        return {
            "ms": f"{m.ms():.1f}",
            "boot": m.boot_cause,
            "run": m.running(),
            "vtor": f"{m.nvic.vtor:#010x}",
            "handoff": bytes(m.uc.mem_read(m.ram.end - 8, 8)).hex(),
            "resets": len(m.stats.resets),
            "reset_ms": f"{m.last_reset_ms:.1f}",
            "storm_ms": f"{m.storm_started_ms:.1f}",
            "btr": f"{can.btr:#010x}",
            "bitrate": round(can.bitrate()),
            "bus": can.bus_bitrate or "auto",
            "online": int(can.online()),
            "mode": can.mode,
            "tec": can.tec,
            "rec": can.rec,
            "boff": int(can.bus_off),
            "delivered": can.delivered,
            "filtered": can.filtered,
            "overruns": can.overruns,
            "aborted": can.aborted,
            "pending": ",".join(
                f"{can.frame_in(b).can_id:03x}" for b in range(3) if can.mailboxes[b][0] & 1
            )
            or "-",
            "offline": can.dropped_offline,
            "in": self.frames_in,
            "out": self.frames_out,
            "feeds": m.iwdg.feeds,
            "erases": m.fpec.erases,
            "programs": m.fpec.programs,
            "flashops": m.fpec.operations,
            "cuts": m.fpec.cuts,
            "armed": "-" if m.fpec.armed is None else m.fpec.armed[0] - m.fpec.operations,
            "locked": int(m.core.locked_up),
            "faults": m.core.faults,
            "fault_addr": "-" if m.core.fault_address is None else f"{m.core.fault_address:#010x}",
            "slips": self.slips,
            "exceptions": m.core.exceptions_taken,
            "tailchains": m.core.tail_chains,
            "nesting": m.core.max_nesting,
            # The digital outputs driven high (bit n = board output n + 1: 1 is "jog live",
            # 2..8 are 0x6A00:1 bits 0..6), and "jog live" alone.
            "outputs": f"{m.outputs():#04x}",
            "jog": m.outputs() & 1,
        }

    # -- the loop -----------------------------------------------------------------------------

    def _pass_log(self) -> None:
        data = self.m.rtt_read()
        if not data or self.log_broken or self.log_out is None:
            return
        try:
            self.log_out.write(data)
            self.log_out.flush()
        except (BrokenPipeError, ValueError):
            # The reader of stdout is gone (a decoder that gave up): the board runs on.
            self.log_broken = True

    def flush_log(self) -> None:
        """Passes on what the image that runs wrote to its RTT log; a decoder of ours first
        starts anew with the other image's ELF if the CPU went from one image to the other
        (the image sets RTT up anew: a new stream)."""
        kind = self.m.running()
        out = self.log_out
        if isinstance(out, Decoder) and self.started and kind != out.kind and kind in out.elfs:
            out.restart(kind)
        self._pass_log()

    def _on_reset(self, cause: str) -> None:
        """A reset starts a new log stream (the firmware sets RTT up again), which a frame
        cut off by it would garble: a decoder of ours starts anew with it (the log up to
        the reset was passed on at its start, `on_reset_start`)."""
        if isinstance(self.log_out, Decoder) and self.started:
            self.log_out.restart(self.m.running())

    def serve(self) -> None:
        while not self.started:
            self.poll(None)
        steps = 0
        while True:
            emu = self.m.now / cortex.CORE_HZ
            wall = time.monotonic() - self.wall0
            if emu > wall:
                self.flush_log()
                self.poll(emu - wall)
                continue
            if wall - emu > MAX_LAG:
                self.wall0 += wall - emu - MAX_LAG
                self.slips += 1
            steps += 1
            if steps % 16 == 0:
                self.poll(0)
                self.flush_log()
            if self.m.step(idle_jump=False):
                self.idle()

    def idle(self) -> None:
        """The CPU waits for an event: emulated time follows the wall clock up to the next
        event, or up to the moment a host's input arrives, which then reaches the node at the
        emulated instant it arrived. (Jumping to the next event at once would put emulated
        time ahead of the wall clock, and input arriving meanwhile would wait until the wall
        clock caught up: up to the 10 ms of `Machine.next_event` per round trip.)"""
        self.flush_log()
        if self.m.interrupt_due():
            return
        until = self.m.next_event()
        wait = until / cortex.CORE_HZ - (time.monotonic() - self.wall0)
        if wait > 0:
            self.sel.select(wait)
        reached = int((time.monotonic() - self.wall0) * cortex.CORE_HZ)
        self.m.idle_until(min(until, reached))
        self.poll(0)


class StimError(Exception):
    pass


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elf", help="the application's ELF (its slot)")
    parser.add_argument("--loader", help="the resident loader's ELF (the first pages)")
    parser.add_argument("--can-port", type=int, required=True)
    parser.add_argument("--stim-port", type=int, required=True)
    parser.add_argument("--flash", help="file holding the whole flash across runs")
    parser.add_argument(
        "--dip", type=lambda v: int(v, 0), default=0, help="switch n on = bit n-1 (0b..., 0x...)"
    )
    parser.add_argument("--log", help="write the raw defmt stream here instead of stdout")
    parser.add_argument("--defmt-print", help="decode the log with this defmt-print (stderr)")
    parser.add_argument("--cut-seed", type=int, default=1, help="seed of half-done flash ops")
    args = parser.parse_args()
    if not args.elf and not args.loader:
        parser.error("give the application (--elf), the loader (--loader) or both")
    m = machine_mod.Machine(args.elf, args.flash, cut_seed=args.cut_seed, loader=args.loader)
    m.set_dip(args.dip)
    if args.log:
        out = open(args.log, "wb")
    elif args.defmt_print:
        elfs = {
            kind: elf
            for kind, elf in ((LOADER, args.loader), (APPLICATION, args.elf))
            if elf and logs_with_defmt(elf)
        }
        out = Decoder(args.defmt_print, elfs, m.running())
    else:
        out = sys.stdout.buffer
    server = Server(m, args.can_port, args.stim_port, out)
    print(
        f"board-emu: SLCAN on 127.0.0.1:{args.can_port}, control on 127.0.0.1:{args.stim_port}",
        file=sys.stderr,
        flush=True,
    )
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
