"""The component's pins in a replay (`decode.replay`): its own `HalPins` and `write_steps`
writing into a stand-in for LinuxCNC's `hal` module that keeps every change, so that a
replayed capture ends on the pins exactly as the component's code writes them (the tests and
the interop suite compare them with the pins a live run wrote). The one part of the decoder
that needs the HAL shell; the decoder imports it only when it replays the pins."""

from __future__ import annotations

from typing import Dict, List, Tuple

from . import core
from .component import HalPins
from .component import write_steps as write_pin_steps


class HalRecorder:
    """A stand-in for LinuxCNC's `hal` module: `component.HalPins` writes the pins into it,
    and it keeps every change (time, pin, value)."""

    HAL_BIT, HAL_FLOAT, HAL_S32, HAL_U32 = "bit", "float", "s32", "u32"
    HAL_IN, HAL_OUT = "in", "out"

    def __init__(self) -> None:
        self.values: Dict[str, object] = {}
        self.initial: Dict[str, object] = {}
        self.changes: List[Tuple[float, str, object]] = []
        self.now = 0.0
        recorder = self

        class component:  # noqa: N801 - the real module's name
            def __init__(self, name: str) -> None:
                self.name = name

            def newpin(self, name, type_, dir_) -> None:
                value = 0.0 if type_ == "float" else False if type_ == "bit" else 0
                recorder.values[name] = recorder.initial[name] = value

            def ready(self) -> None:
                pass

            def exit(self) -> None:
                pass

            def __getitem__(self, name):
                return recorder.values[name]

            def __setitem__(self, name, value) -> None:
                if recorder.values.get(name) != value:  # as fake_hal logs a change
                    recorder.changes.append((recorder.now, name, value))
                recorder.values[name] = value

        self.component = component


def shell_pins(recorder: HalRecorder, cfg: core.Config) -> HalPins:
    """The component's pins (`cfg`'s), made in `recorder`."""
    return HalPins(recorder, "handwheel", cfg)


def write_steps(pins: HalPins, steps: List[core.Pins]) -> None:
    """`Core.publish`'s steps, written as the component writes them (without its holds
    between them: a replay has no servo cycles to wait for)."""
    write_pin_steps(pins, steps, sleep=lambda s: None)
