"""Work-arounds for the firmware's QEMU variant as it is today, in one place.

QEMU drops the bytes that reach the emulated USART1 before the firmware has enabled it, and
the firmware holds its frames until the host has opened the SLCAN channel (`O`), so the `O`
python-can sends on connecting can be lost. Until the firmware sends its boot-up without
waiting for `O`, SLCAN clients re-send `O` (idempotent) until they hear the device. Remove
this module (and its two callers, `component.py` and the test hub) once that has landed.
"""

from __future__ import annotations

from typing import Callable

REOPEN_PERIOD = 0.2  # s


class ReopenUntilHeard:
    """Calls `send_open` every `REOPEN_PERIOD` until `heard()` is true."""

    def __init__(self, send_open: Callable[[], None]) -> None:
        self._send_open = send_open
        self._due = 0.0
        self.done = False

    def poll(self, now: float, heard: bool) -> None:
        if self.done:
            return
        if heard:
            self.done = True
            return
        if now >= self._due:
            self._due = now + REOPEN_PERIOD
            self._send_open()
