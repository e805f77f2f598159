"""Captures: every frame the component read and sent, time-stamped, in python-can's own log
formats, and beside it the component's host notes; and reading both back for a replay.

Writing (`Capture`, the component's `--capture FILE`): the frames go through python-can's
`SizedRotatingLogger`, in the format the file's extension names (`.log` candump, as
`candump -L` writes it, with the direction of each frame; `.asc` Vector ASCII; `.blf`
Vector binary). When the file reaches `max_bytes` it is renamed `NAME.1.EXT` (the one before
to `NAME.2.EXT`, ...) and a new one begun; of the older files only `files - 1` are kept, so a
capture left on never takes more than about `files * max_bytes`. A frame the component
handed to the core carries the very time the core was given (the component's monotonic
clock, moved by a constant to the wall clock), so that a replay judges it at the same
moment.

The host notes (`FILE.host`, one JSON object per line, rotated with the file) hold what
decided the pins besides the frames, which no bus capture can show: the input pins when they
change, the actions the core asked for and their outcomes (what a configuration found and
wrote), the end of the main loop, and when the component had last found its receive path
empty before a feed record, where that was long enough ago to matter (`DRAIN_SLACK`: the
backlog rule, `core.BACKLOG_LIMIT`). Each note says after how many frames of its file it
came (`at`) and its time relative to the frame before it (`dt`; to the file's first frame
before any), so that it lines up with the frames whatever time base a format keeps. Its
first line holds the component's settings (`core.Config`).

Reading (`read`): the frames of a capture (any format python-can reads) and, if there is
one, its notes; `decode.replay` runs them through the core.
"""

from __future__ import annotations

import dataclasses
import json
import os
import threading
import time
from pathlib import Path
from typing import Callable, Dict, Iterable, List, Optional, Tuple

from . import core

# The formats `--capture` writes, by extension (python-can's writers for them).
FORMATS = {".log": "candump", ".asc": "Vector ASC", ".blf": "Vector BLF"}
DEFAULT_MAX_MB = 16
DEFAULT_FILES = 4
MAX_MB_RANGE = (1, 4096)
FILES_RANGE = (2, 100)
NOTES_SUFFIX = ".host"
NOTES_VERSION = 1
# A feed record handled more than this after the component last found its receive path empty
# gets a note with that moment; one handled sooner is replayed as if the path had been found
# empty this long before it. Below `core.BACKLOG_LIMIT`, so that the backlog rule judges every
# record of a replay as it did live (a record without a note was not late, and is not).
DRAIN_SLACK = core.BACKLOG_LIMIT / 2
# Notes kept while a file has no frame yet (they are written relative to its first one).
EARLY_NOTES = 1000
# The interface name candump lines carry when the channel is no interface name.
CANDUMP_CHANNEL = "can0"


def check_path(path: str) -> str:
    """`path` if its extension names a format `Capture` writes, else `ValueError`."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        names = ", ".join(f"{s} ({n})" for s, n in FORMATS.items())
        raise ValueError(f"--capture {path}: the extension names the format: {names}")
    return path


def notes_path(path) -> Path:
    """Where the host notes of capture file `path` are."""
    return Path(str(path) + NOTES_SUFFIX)


def rotated(path, n: int) -> Path:
    """The n-th older file of capture `path` (`NAME.n.EXT`); n = 0: `path` itself."""
    p = Path(path)
    return p if n == 0 else p.with_name(f"{p.stem}.{n}{p.suffix}")


def candump_channel(channel: str) -> str:
    """The interface name of the candump lines: the channel if it is one (`can0`), else
    `can0` (a serial port, a `socket://` URL)."""
    channel = str(channel)
    return channel if channel.isidentifier() and len(channel) <= 15 else CANDUMP_CHANNEL


def _config_fields(cfg: core.Config) -> dict:
    return dataclasses.asdict(cfg)


def config_from_fields(fields: dict) -> core.Config:
    """A `core.Config` from the notes' settings (fields it does not know are left out: a
    capture of another version of the component)."""
    known = {f.name for f in dataclasses.fields(core.Config)}
    values = {k: v for k, v in fields.items() if k in known}
    if isinstance(values.get("own_sdo"), list):  # JSON has no tuples
        values["own_sdo"] = tuple(values["own_sdo"])
    return core.Config(**values)


class Capture:
    """The component's capture: `received` and `sent` write frames, `note` the host notes.
    Safe to call from the component's threads (the main loop, the heartbeat, the SDO worker);
    `clock` is the component's (`time.monotonic`)."""

    def __init__(
        self,
        path: str,
        cfg: core.Config,
        channel: str = CANDUMP_CHANNEL,
        max_bytes: int = DEFAULT_MAX_MB * 1024 * 1024,
        files: int = DEFAULT_FILES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        import can

        check_path(path)
        self.path = Path(path).resolve()
        self.cfg = cfg
        self.clock = clock
        self.files = files
        self.max_bytes = max_bytes
        self.channel = candump_channel(channel) if self.path.suffix.lower() == ".log" else None
        # The component's clock to the wall clock (the capture's time stamps).
        self.offset = time.time() - clock()
        self._lock = threading.Lock()
        self._can = can
        # A component started again keeps what the last one captured: its files move on.
        self.run = f"{time.time():.6f}-{os.getpid()}"
        if self.path.exists() and self.path.stat().st_size:
            self._shift()
        self._logger = can.SizedRotatingLogger(str(self.path), max_bytes=max_bytes)
        self._logger.rotator = self._rotate_files
        self._notes = None
        self._open_notes()
        self._frames = 0  # frames in the current file
        self._last_time: Optional[float] = None  # wall time of its last frame
        self._early: List[Tuple[dict, float]] = []  # notes before its first frame
        self._dirty = False
        self._inputs: Dict[str, object] = {}
        self.closed = False

    # Files -----------------------------------------------------------------------------------

    def _open_notes(self) -> None:
        path = notes_path(self.path)
        self._notes = open(path, "w", encoding="utf-8")
        header = {
            "canopen-handwheel": "host notes",
            "version": NOTES_VERSION,
            "capture": self.path.name,
            "run": self.run,
            "config": _config_fields(self.cfg),
        }
        self._notes.write(json.dumps(header) + "\n")

    def _rotate_files(self, source, dest) -> None:
        """python-can's rotation, called with the file to retire: NAME.k.EXT moves to
        NAME.k+1.EXT (the oldest kept one is removed), the file to NAME.1.EXT, each with its
        notes."""
        del dest  # python-can's name (a time stamp): ours are numbered
        self._close_notes()
        self._shift()
        self._open_notes()
        self._frames = 0
        self._last_time = None
        self._early = []

    def _shift(self) -> None:
        """NAME.k.EXT to NAME.k+1.EXT with their notes, the oldest kept one removed, NAME.EXT
        to NAME.1.EXT."""
        last = self.files - 1
        for path in (rotated(self.path, last), notes_path(rotated(self.path, last))):
            if path.exists():
                path.unlink()
        for n in range(last - 1, -1, -1):
            for old, new in (
                (rotated(self.path, n), rotated(self.path, n + 1)),
                (notes_path(rotated(self.path, n)), notes_path(rotated(self.path, n + 1))),
            ):
                if old.exists():
                    os.replace(old, new)

    def _close_notes(self) -> None:
        if self._notes is not None:
            # A file without a frame: its notes relative to the first of them.
            for fields, note_wall in self._early:
                self._write_note(fields, note_wall, self._early[0][1])
            self._early = []
            self._notes.close()
            self._notes = None

    # Frames ----------------------------------------------------------------------------------

    def _write(self, msg, t: float, is_rx: bool, notes=()) -> None:
        """Writes `notes` ((fields, core time) pairs) and then `msg` at core time `t`, into a
        new file first if the current one is full (under the lock)."""
        can = self._can
        wall = t + self.offset
        if self._last_time is not None and wall < self._last_time:
            wall = self._last_time  # another thread's frame came first: never backwards
        copy = can.Message(
            timestamp=wall,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            dlc=msg.dlc,
            data=bytes(msg.data) if not msg.is_remote_frame else None,
            is_rx=is_rx,
            channel=self.channel,
        )
        logger = self._logger
        if logger.should_rollover(copy) or self._notes.tell() >= self.max_bytes:
            logger.do_rollover()
            logger.rollover_count += 1
        for fields, nt in notes:
            self._note_locked(fields, nt)
        logger.writer.on_message_received(copy)
        first = self._last_time is None
        self._frames += 1
        self._last_time = wall
        self._dirty = True
        if first and self._early:
            early, self._early = self._early, []
            for fields, note_wall in early:
                self._write_note(fields, note_wall, wall, at=0)

    def received(self, msg, clock: Callable[[], float], drained_at=None, judged=False) -> float:
        """Writes a frame the component read, at the time `clock()` gives now, which it
        returns: the time to hand the frame to the core with. `judged`: the core takes it
        (the device's frames); `drained_at` is then the core's `drained_at`, and a note
        before the frame tells it if it is None or more than `DRAIN_SLACK` before now."""
        with self._lock:
            now = clock()
            if self.closed:
                return now
            notes = []
            if judged and drained_at is None:
                notes.append(({"drained": None}, now))
            elif judged and now - drained_at > DRAIN_SLACK:
                notes.append(({"drained": True}, drained_at))
            self._write(msg, now, True, notes)
            return now

    def sent(self, msg) -> None:
        """Writes a frame the component sent (any thread), at the time it went out."""
        with self._lock:
            if not self.closed:
                self._write(msg, self.clock(), False)

    # Notes -----------------------------------------------------------------------------------

    def note(self, t: float, **fields) -> None:
        """A host note at core time `t` (`input`, `action`, `done`, `stop`)."""
        with self._lock:
            if not self.closed:
                self._note_locked(fields, t)

    def inputs(self, t: float, **values) -> None:
        """The input pins as the core was given them at `t` (`enable`, `position_mode`,
        `velocity_mode`, `run_on_budget`, `motion_known`): a note when one changed."""
        changed = {k: v for k, v in values.items() if self._inputs.get(k) != v}
        if changed:
            self._inputs.update(changed)
            self.note(t, input=changed)

    def action(self, t: float, action) -> None:
        """The core asked for `action` at `t` (the component carries it out)."""
        self.note(t, action=action_name(action))

    def done(self, t: float, action, ok: bool, abort=None, result=None) -> None:
        """The outcome of `action` handed to the core at `t` (`result`: a configuration's
        `core.Configured`)."""
        fields = {"action": action_name(action), "ok": bool(ok), "abort": abort}
        if result is not None:
            outcome = dataclasses.asdict(result)
            # Times (`first_reply_at`, `sent_at`): kept relative to the note's own, as every
            # time in the notes (`..._dt`).
            for name in [k for k in outcome if k.endswith("_at")]:
                at = outcome.pop(name)
                outcome[name[:-3] + "_dt"] = None if at is None else round(at - t, 6)
            fields["result"] = outcome
        self.note(t, done=fields)

    def stopped(self, t: float) -> None:
        """The main loop ended at `t`: the pins stay as they are; the shutdown follows."""
        self.note(t, stop=True)

    def _note_locked(self, fields: dict, t: float) -> None:
        wall = t + self.offset
        if self._last_time is None:
            if len(self._early) < EARLY_NOTES:
                self._early.append((fields, wall))
            return
        self._write_note(fields, wall, self._last_time)

    def _write_note(self, fields: dict, wall: float, base: float, at: Optional[int] = None):
        note = {"at": self._frames if at is None else at, "dt": round(wall - base, 6)}
        note.update(fields)
        self._notes.write(json.dumps(note) + "\n")
        self._dirty = True

    def flush(self) -> None:
        """Writes what is buffered (the main loop calls it once a round); a binary BLF file
        keeps its buffer until it is full or closed."""
        with self._lock:
            if self.closed or not self._dirty:
                return
            self._dirty = False
            writer = self._logger.writer
            f = getattr(writer, "file", None)
            if f is not None and self.path.suffix.lower() != ".blf":
                f.flush()
            self._notes.flush()

    def close(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._logger.stop()
            self._close_notes()


def action_name(action) -> str:
    """How the notes name an action: `configure`, `check` (a configuration that keeps the
    session if intact), `feed 0` / `feed 1` (0x2000), or its repr."""
    if isinstance(action, core.Configure):
        return "configure" if action.keep is None else "check"
    if isinstance(action, core.WriteFeed):
        return f"feed {action.value}"
    if isinstance(action, core.Probe):
        return f"probe {action.nonce}"
    return repr(action)


def wrap_send(bus, capture: Capture) -> None:
    """Makes every frame sent on `bus` (python-canopen sends through `bus.send`) go into
    `capture` once it is out."""
    send = bus.send

    def captured_send(msg, timeout=None):
        send(msg, timeout)
        capture.sent(msg)

    bus.send = captured_send


# Reading ----------------------------------------------------------------------------------------


@dataclasses.dataclass
class Frame:
    """One frame of a capture: time (s, as the file keeps it), identifier, data, direction
    (`rx`: read by whoever captured; a capture without directions says rx)."""

    t: float
    id: int
    data: bytes
    rx: bool = True
    extended: bool = False
    remote: bool = False
    error: bool = False
    dlc: int = 0


@dataclasses.dataclass
class Note:
    """A host note at time `t` (the frames' time base), before frame `at` of its file."""

    at: int
    t: float
    fields: dict


@dataclasses.dataclass
class CaptureFile:
    """One file of a capture: its frames, its notes (None: it has none) and the settings its
    notes hold."""

    path: Path
    frames: List[Frame]
    notes: Optional[List[Note]]
    config: Optional[dict] = None
    run: Optional[str] = None  # which start of the component wrote it


def read_frames(path) -> List[Frame]:
    """The frames of `path`, any format python-can reads (by extension)."""
    import can

    frames = []
    with can.LogReader(str(path)) as reader:
        for msg in reader:
            frames.append(
                Frame(
                    t=float(msg.timestamp),
                    id=msg.arbitration_id,
                    data=bytes(msg.data or b""),
                    rx=bool(getattr(msg, "is_rx", True)),
                    extended=msg.is_extended_id,
                    remote=msg.is_remote_frame,
                    error=msg.is_error_frame,
                    dlc=msg.dlc,
                )
            )
    return frames


def read_notes(path, frames: List[Frame]) -> Tuple[dict, List[Note], Optional[str]]:
    """(settings, notes, run) of a notes file, the notes' times in the frames' time base."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    if not lines:
        raise ValueError(f"{path}: empty")
    header = json.loads(lines[0])
    if header.get("canopen-handwheel") != "host notes":
        raise ValueError(f"{path}: not the host notes of a canopen-handwheel capture")
    notes = []
    for line in lines[1:]:
        try:
            fields = json.loads(line)
        except json.JSONDecodeError:
            break  # a file cut off mid-line (the component killed): what came before counts
        at = int(fields.pop("at"))
        dt = float(fields.pop("dt"))
        if frames:
            base = frames[min(max(at - 1, 0), len(frames) - 1)].t
        else:
            base = 0.0
        notes.append(Note(at=at, t=base + dt, fields=fields))
    return header.get("config") or {}, notes, header.get("run")


def read(path, notes: Optional[str] = "auto") -> CaptureFile:
    """A capture file and its notes: `notes` "auto" reads `FILE.host` if it exists, None
    reads none, a path reads that file."""
    frames = read_frames(path)
    if notes == "auto":
        candidate = notes_path(path)
        notes = str(candidate) if candidate.exists() else None
    if notes is None:
        return CaptureFile(Path(path), frames, None)
    config, note_list, run = read_notes(notes, frames)
    return CaptureFile(Path(path), frames, note_list, config, run)


def files_of(path) -> List[Path]:
    """A capture's files, oldest first: `NAME.k.EXT` down to `NAME.1.EXT`, then `path`."""
    older = []
    n = 1
    while rotated(path, n).exists():
        older.append(rotated(path, n))
        n += 1
    return list(reversed(older)) + [Path(path)]


def merged(f: CaptureFile) -> Iterable[Tuple[str, object]]:
    """The file's notes and frames in the order the component wrote them: ("note", Note) and
    ("frame", Frame)."""
    by_at: Dict[int, List[Note]] = {}
    for n in f.notes or []:
        by_at.setdefault(n.at, []).append(n)
    for i, frame in enumerate(f.frames):
        for n in by_at.pop(i, []):
            yield "note", n
        yield "frame", frame
    for at in sorted(by_at):
        for n in by_at[at]:
            yield "note", n
