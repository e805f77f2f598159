"""The `canopen-handwheel` HAL component: the thin shell around `core.Core`.

It creates the HAL pins, connects python-can and python-canopen, produces the master's
heartbeat, hands every frame from the device to the core, carries out the core's actions
(SDO writes, NMT start) on a worker thread so that the heartbeat never waits for an SDO
timeout, and copies the core's pins to HAL. It decides nothing itself.

    loadusr -Wn handwheel canopen-handwheel --channel can0 --axes xyz

`hal` is imported lazily (`run(..., hal_module=...)` takes a stand-in), so that this module
loads without LinuxCNC.
"""

from __future__ import annotations

import argparse
import queue
import signal
import sys
import threading
import time
from importlib import resources
from typing import Callable, Optional

from . import core

NMT_START = 0x01


def log(message: str) -> None:
    print(f"canopen-handwheel: {message}", file=sys.stderr, flush=True)


def default_eds() -> str:
    return str(resources.files(__package__).joinpath("handwheel.eds"))


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="canopen-handwheel",
        description="LinuxCNC userspace HAL component for the CANopen CNC handwheel "
        "(python-canopen as the master). Load with: loadusr -Wn handwheel canopen-handwheel "
        "[options]",
    )
    p.add_argument("--interface", default="socketcan", help="python-can interface (socketcan)")
    p.add_argument(
        "--channel",
        default="can0",
        help="python-can channel (can0; for slcan a serial port or socket://host:port)",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=None,
        help="bit rate for interfaces that set it (default: leave it as it is)",
    )
    p.add_argument("--node", type=int, default=16, help="the handwheel's node-ID (16)")
    p.add_argument("--name", default="handwheel", help="HAL prefix (handwheel)")
    p.add_argument(
        "--axes",
        default=core.DEVICE_AXES,
        help="LinuxCNC axis letters for switch positions 1..5 (xyzwv)",
    )
    p.add_argument(
        "--scale", type=float, default=0.001, help="machine units per multiplied unit (0.001)"
    )
    p.add_argument(
        "--master-node",
        type=int,
        default=None,
        help="node-ID whose heartbeat the component produces (1, or 2 if --node is 1)",
    )
    p.add_argument("--eds", default=None, help="EDS of the device (the shipped handwheel.eds)")
    p.add_argument(
        "--heartbeat-ms",
        type=int,
        default=100,
        help="period of the component's heartbeat (100); the device is told to "
        "stop the feed after 5 periods without it",
    )
    p.add_argument(
        "--event-timer-ms",
        type=int,
        default=100,
        help="the device's TPDO1 event timer 0x1800:5 (100): no record for 3 "
        "periods means disconnected",
    )
    p.add_argument(
        "--max-detents-per-s",
        type=int,
        default=core.DEFAULT_MAX_DETENTS_PER_S,
        help=f"fastest plausible turning ({core.DEFAULT_MAX_DETENTS_PER_S}, twice a hard flick "
        "of a 100-detent wheel); motion beyond it is counted in frames-bad and not applied",
    )
    args = p.parse_args(argv)
    try:
        args.config = core.make_config(
            args.node,
            args.master_node,
            args.axes,
            args.scale,
            args.event_timer_ms,
            args.heartbeat_ms,
            args.max_detents_per_s,
        )
    except ValueError as e:
        p.error(str(e))
    return args


def config_from(args: argparse.Namespace) -> core.Config:
    return args.config


class HalPins:
    """The HAL component and its pins, as `core.pin_table` names them."""

    def __init__(self, hal, name: str, cfg: core.Config) -> None:
        types = {"bit": hal.HAL_BIT, "s32": hal.HAL_S32, "u32": hal.HAL_U32, "float": hal.HAL_FLOAT}
        dirs = {"in": hal.HAL_IN, "out": hal.HAL_OUT}
        self.comp = hal.component(name)
        self.axes = cfg.axes
        for pin, t, d in core.pin_table(cfg.axes):
            self.comp.newpin(pin, types[t], dirs[d])
        for L in cfg.axes:
            self.comp[f"axis.{L}.jog-scale"] = cfg.scale
            self.comp[f"axis.{L}.jog-vel-mode"] = False
        self.comp["state"] = -1
        self.comp.ready()

    def enable(self) -> bool:
        return bool(self.comp["enable"])

    def write(self, pins: core.Pins) -> None:
        c = self.comp
        for L in self.axes:
            c[f"axis.{L}.jog-counts"] = pins.jog_counts[L]
            c[f"axis.{L}.jog-enable"] = pins.jog_enable[L]
            c[f"halui.axis.{L}.select"] = pins.select[L]
        c["connected"] = pins.connected
        c["feed-enabled"] = pins.feed_enabled
        c["encoder-error"] = pins.encoder_error
        c["axis"] = pins.axis
        c["multiplier"] = pins.multiplier
        c["position"] = pins.position
        c["emcy-code"] = pins.emcy_code
        c["records-lost"] = pins.records_lost
        c["frames-bad"] = pins.frames_bad
        c["state"] = pins.state

    def exit(self) -> None:
        try:
            self.comp.exit()
        except Exception:
            pass


class Link:
    """python-can bus + python-canopen network with the device's node; frames from the
    device go to `events` as ("frame", cob_id, data, time)."""

    def __init__(self, args: argparse.Namespace, events: "queue.Queue") -> None:
        import can
        import canopen

        self.failed = threading.Event()
        kwargs = {}
        if args.bitrate is not None:
            kwargs["bitrate"] = args.bitrate
        if args.interface == "slcan" and str(args.channel).startswith("socket://"):
            kwargs["sleep_after_open"] = 0
        self.bus = can.Bus(interface=args.interface, channel=args.channel, **kwargs)
        self.network = canopen.Network(self.bus)
        ids = {0x180 + args.node, 0x080 + args.node, 0x700 + args.node}
        link = self

        class Feed(can.Listener):
            def on_message_received(self, msg: "can.Message") -> None:
                if msg.is_error_frame or msg.is_extended_id or msg.is_remote_frame:
                    return
                if msg.arbitration_id in ids:
                    events.put(("frame", msg.arbitration_id, bytes(msg.data), time.monotonic()))

            def on_error(self, exc: Exception) -> None:
                link.failed.set()

        self.network.listeners.append(Feed())
        self.node = self.network.add_node(args.node, args.eds or default_eds())
        self.network.connect()

    def send(self, cob_id: int, data: bytes) -> None:
        self.network.send_message(cob_id, data)

    def close(self) -> None:
        try:
            self.network.disconnect()
        except Exception as e:
            log(f"closing the bus: {e!r}")


class Worker:
    """Carries out the core's actions one at a time; reports ("done", action, ok, abort)."""

    def __init__(self, link: Link, events: "queue.Queue", node_id: int) -> None:
        self.link = link
        self.events = events
        self.node_id = node_id
        self.jobs: "queue.Queue" = queue.Queue()
        self.thread = threading.Thread(target=self._run, name="sdo-worker", daemon=True)
        self.thread.start()

    def submit(self, action, done: Optional[threading.Event] = None) -> None:
        self.jobs.put((action, done))

    def stop(self) -> None:
        self.jobs.put(None)
        self.thread.join(3)

    def _run(self) -> None:
        import canopen

        while True:
            job = self.jobs.get()
            if job is None:
                return
            action, done = job
            ok, abort = False, None
            try:
                self._carry_out(action)
                ok = True
            except canopen.SdoAbortedError as e:
                abort = e.code
                log(f"{describe(action)}: SDO abort 0x{e.code:08X}")
            except Exception as e:  # no answer, bus gone: the core retries
                log(f"{describe(action)}: {e!r}")
            self.events.put(("done", action, ok, abort))
            if done is not None:
                done.set()

    def _carry_out(self, action) -> None:
        sdo = self.link.node.sdo
        if isinstance(action, core.Configure):
            count = sdo.upload(0x1016, 0)[0]
            entries = {}
            for sub in range(1, count + 1):
                entries[sub] = int.from_bytes(sdo.upload(0x1016, sub), "little")
            sub, value = core.consumer_plan(entries, action.master, action.timeout_ms)
            sdo.download(0x1016, sub, value.to_bytes(4, "little"))
            if sdo.upload(0x2001, 0)[0] != 0:
                sdo.download(0x2001, 0, b"\x00")
            # Feed off: a fresh start enables it again, stepping the selection epoch.
            sdo.download(0x2000, 0, b"\x00")
            self.link.send(0x000, bytes([NMT_START, self.node_id]))
            log(f"device configured (0x1016:{sub} = 0x{value:08X}, feed off), NMT start sent")
        elif isinstance(action, core.WriteFeed):
            sdo.download(0x2000, 0, bytes([action.value]))
            log(f"feed enable 0x2000 = {action.value}")


def describe(action) -> str:
    if isinstance(action, core.Configure):
        return "configuring the device"
    if isinstance(action, core.WriteFeed):
        return f"0x2000 = {action.value}"
    return repr(action)


def run(
    args: argparse.Namespace,
    hal_module=None,
    stop: Optional[threading.Event] = None,
    clock: Callable[[], float] = time.monotonic,
) -> int:
    """The component's main loop until `stop` is set (or SIGTERM / SIGINT arrives)."""
    if hal_module is None:
        import hal as hal_module  # LinuxCNC's; only present on a LinuxCNC machine
    cfg = config_from(args)
    stop = stop or threading.Event()
    pins = HalPins(hal_module, args.name, cfg)
    c = core.Core(cfg)
    events: "queue.Queue" = queue.Queue()
    link: Optional[Link] = None
    worker: Optional[Worker] = None
    next_heartbeat = 0.0
    next_connect = 0.0
    log(
        f"{args.name}: node {args.node} on {args.interface} {args.channel}, axes "
        f"{cfg.axes}, master heartbeat {cfg.master} every {args.heartbeat_ms} ms"
    )
    try:
        while not stop.is_set():
            now = clock()
            if link is None and now >= next_connect:
                try:
                    link = Link(args, events)
                    worker = Worker(link, events, args.node)
                    log("bus open")
                except Exception as e:
                    log(f"cannot open the bus ({e!r}); retrying")
                    link = None
                    next_connect = now + 1.0
            if link is not None and link.failed.is_set():
                log("bus failed; reconnecting")
                drop(link, worker)
                link, worker = None, None
                c.done(c.pending, False, None, now)
                next_connect = now + 1.0
            try:
                event = events.get(timeout=0.01)
            except queue.Empty:
                event = None
            while event is not None:
                if event[0] == "frame":
                    _, cob_id, data, t = event
                    c.frame(cob_id, data, t)
                elif event[0] == "done":
                    _, action, ok, abort = event
                    c.done(action, ok, abort, clock())
                try:
                    event = events.get_nowait()
                except queue.Empty:
                    event = None
            now = clock()
            c.set_enable(pins.enable())
            c.tick(now)
            if link is not None:
                try:
                    if now >= next_heartbeat:
                        link.send(0x700 + cfg.master, bytes([core.OPERATIONAL]))
                        next_heartbeat = now + cfg.heartbeat_period
                except Exception as e:
                    log(f"sending: {e!r}")
                    link.failed.set()
                action = c.next_action(now)
                if action is not None and worker is not None:
                    worker.submit(action)
            pins.write(c.pins())
    finally:
        if link is not None and worker is not None:
            action = c.shutdown_action()
            if action is not None:
                done = threading.Event()
                worker.submit(action, done)
                done.wait(1.5)
        if link is not None:
            drop(link, worker)
        pins.exit()
        log("stopped")
    return 0


def drop(link: Link, worker: Optional[Worker]) -> None:
    if worker is not None:
        worker.stop()
    link.close()


def main(argv=None) -> int:
    args = parse_args(argv)
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return run(args, stop=stop)


if __name__ == "__main__":
    sys.exit(main())
