"""What the master receives: every frame recorded, waited on instead of slept for."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, List, Optional

import can

from canopen_handwheel.core import FLAGS_MASK, Record

from .constants import FRAME_TIMEOUT, TPDO1


@dataclass(frozen=True)
class Frame:
    """One frame the master received."""

    seq: int  # position in the recording
    t: float  # host receive time (time.monotonic())
    id: int
    data: bytes
    extended: bool = False
    remote: bool = False

    def __repr__(self) -> str:
        return f"<#{self.seq} {self.t:.3f} {self.id:03X} [{self.data.hex(' ')}]>"


class FrameRecorder(can.Listener):
    """Keeps every received frame; tests wait on it instead of sleeping."""

    def __init__(self) -> None:
        self._frames: List[Frame] = []
        self._cond = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        with self._cond:
            self._frames.append(
                Frame(
                    seq=len(self._frames),
                    t=time.monotonic(),
                    id=msg.arbitration_id,
                    data=bytes(msg.data),
                    extended=msg.is_extended_id,
                    remote=msg.is_remote_frame,
                )
            )
            self._cond.notify_all()

    def on_error(self, exc: Exception) -> None:  # keep the notifier alive
        pass

    def mark(self) -> int:
        """A position in the recording; `since=mark` looks only at later frames."""
        with self._cond:
            return len(self._frames)

    def frames(self, cob_id: Optional[int] = None, since: int = 0) -> List[Frame]:
        with self._cond:
            return [f for f in self._frames[since:] if cob_id is None or f.id == cob_id]

    def wait_for(
        self,
        pred: Callable[[Frame], bool],
        timeout: float = FRAME_TIMEOUT,
        since: int = 0,
        what: str = "frame",
    ) -> Frame:
        """The first frame after `since` matching `pred`; fails with the frames seen."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for f in self._frames[since:]:
                    if pred(f):
                        return f
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = self._frames[since:][-30:]
                    raise AssertionError(f"no {what} within {timeout} s; last frames: {seen}")
                self._cond.wait(left)

    def wait_id(self, cob_id: int, data: Optional[bytes] = None, **kw) -> Frame:
        what = f"frame {cob_id:03X}" + (f" [{data.hex(' ')}]" if data is not None else "")
        return self.wait_for(
            lambda f: f.id == cob_id and (data is None or f.data == data), what=what, **kw
        )

    def wait_count(
        self, cob_id: int, count: int, timeout: float = FRAME_TIMEOUT, since: int = 0
    ) -> List[Frame]:
        """Waits until `count` frames on `cob_id` arrived after `since`; returns them all."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                got = [f for f in self._frames[since:] if f.id == cob_id]
                if len(got) >= count:
                    return got
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(
                        f"{len(got)} of {count} frames {cob_id:03X} within {timeout} s: {got}"
                    )
                self._cond.wait(left)

    def assert_none(
        self, pred: Callable[[Frame], bool], duration: float, since: int = 0, what: str = ""
    ) -> None:
        """No frame matching `pred` arrives after `since` for `duration` seconds (a
        negative check must wait; it fails as soon as such a frame shows up)."""
        deadline = time.monotonic() + duration
        with self._cond:
            while True:
                bad = [f for f in self._frames[since:] if pred(f)]
                assert not bad, f"unexpected {what or 'frames'}: {bad}"
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._cond.wait(left)


# Bits 0-4 of the feed status (0x2030, byte 5 of a feed record) are flags; bits 5-7 the
# session.
STATUS_FLAGS = FLAGS_MASK


def feed_record(frame: Frame) -> Record:
    """The feed record a TPDO1 carries, decoded by the host component's `Record` (the one
    place the layout is written down in Python): position, axis, multiplier (1, 10, 100),
    epoch, flags (status bits 0-4), session, sequence."""
    assert frame.id == TPDO1 and len(frame.data) == 8, f"not a feed record: {frame}"
    return Record.decode(frame.data)
