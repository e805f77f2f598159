"""A stand-in for LinuxCNC's `hal` module: the calls the component makes, with the pins in
a dict (types and directions checked on every write). Like LinuxCNC 2.9's, creating a
component sets SIGTERM to raise KeyboardInterrupt (when done in the main thread)."""

import signal
import threading

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

    def newpin(self, name, type_, dir_):
        assert not self.is_ready, "pins are made before ready()"
        assert name not in self.pins, f"pin {name} twice"
        self.types[name] = type_
        self.dirs[name] = dir_
        self.pins[name] = 0.0 if type_ == HAL_FLOAT else False if type_ == HAL_BIT else 0

    def ready(self):
        self.is_ready = True

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
        self.pins[name] = value
