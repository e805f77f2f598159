"""A stand-in for LinuxCNC's `hal` module: the calls the component makes, with the pins in
a dict (types and directions checked on every write). Like LinuxCNC 2.9's, creating a
component sets SIGTERM to raise KeyboardInterrupt (when done in the main thread).

For a component in a process of its own (the interop suite's host tests), two variables of
its environment: `FAKE_HAL_LOG`, a file that gets a line `<time.monotonic()> <pin> <value>`
for every change of a pin's value, written at once (so that a test sees the order and time
of every write), and `FAKE_HAL_SET`, `pin=value,...` for input pins, set at `ready()`
(`1`/`0` for bits)."""

import os
import signal
import threading
import time

HAL_BIT, HAL_FLOAT, HAL_S32, HAL_U32 = "bit", "float", "s32", "u32"
HAL_IN, HAL_OUT, HAL_IO = "in", "out", "io"


class component:  # noqa: N801 - the real module's name
    def __init__(self, name: str) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, signal.default_int_handler)
        self.name = name
        self.pins = {}
        self.types = {}
        self.dirs = {}
        self.is_ready = False
        self.exited = False
        self.running = threading.Event()
        self.running.set()
        path = os.environ.get("FAKE_HAL_LOG")
        self.log_fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND) if path else None

    def newpin(self, name, type_, dir_):
        assert not self.is_ready, "pins are made before ready()"
        assert name not in self.pins, f"pin {name} twice"
        self.types[name] = type_
        self.dirs[name] = dir_
        self.pins[name] = 0.0 if type_ == HAL_FLOAT else False if type_ == HAL_BIT else 0

    def ready(self):
        self.is_ready = True
        for item in filter(None, os.environ.get("FAKE_HAL_SET", "").split(",")):
            name, value = item.split("=")
            t = self.types[name]
            self.pins[name] = (
                value == "1" if t == HAL_BIT else float(value) if t == HAL_FLOAT else int(value)
            )

    def exit(self):
        self.exited = True

    def __getitem__(self, name):
        self.running.wait()  # cleared by a test: the component's loop hangs here
        return self.pins[name]

    def __setitem__(self, name, value):
        t = self.types[name]
        if t == HAL_BIT:
            assert isinstance(value, bool), (name, value)
        elif t == HAL_S32:
            assert isinstance(value, int) and -(2**31) <= value < 2**31, (name, value)
        elif t == HAL_U32:
            assert isinstance(value, int) and 0 <= value < 2**32, (name, value)
        else:
            assert isinstance(value, float), (name, value)
        if self.log_fd is not None and self.pins[name] != value:
            os.write(self.log_fd, f"{time.monotonic():.6f} {name} {value}\n".encode())
        self.pins[name] = value
