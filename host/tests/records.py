"""Feed records and configured cores for the tests: every record is made by `core.Record`
(no bytes by hand), so the tests follow the layout wherever it is written down."""

from typing import Optional

from canopen_handwheel import core
from canopen_handwheel.core import Config, Configure, Core, Record

NODE = 16
TPDO1, EMCY, HB = 0x180 + NODE, 0x080 + NODE, 0x700 + NODE
EN = core.STATUS_ENABLED
ML = core.STATUS_MASTER_LOST
# The token a core's first configuration writes on a device in no session.
SESSION = core.TOKENS[0]


def record(
    position: int,
    axis: int = 1,
    mult: int = 1,
    flags: int = EN,
    seq: int = 0,
    epoch: int = 0,
    session: int = SESSION,
) -> Record:
    return Record(position, axis, mult, epoch, flags, session, seq % core.SEQUENCE_MODULO)


def rec(*args, **kwargs) -> bytes:
    """A feed record's 8 bytes (`record`'s arguments)."""
    return record(*args, **kwargs).encode()


def configure(
    c: Core, now: float, found: int = 0, due: bool = True, uptime_ms: Optional[int] = None
) -> Optional[int]:
    """Carries out the configuration `c` asks for at `now` on a device whose 0x2002 reads
    `found` and whose uptime 0x2035 reads `uptime_ms` (None: not read), every step
    succeeding (`core.configure_outcome`); the session `c` then has. `due`: `c` must ask for
    one (else: nothing if it does not, as when it waits for a token)."""
    action = c.next_action(now)
    if not due and not isinstance(action, Configure):
        return c.session
    assert isinstance(action, Configure), action
    uptime = None if uptime_ms is None else (uptime_ms, now)
    ok, result = core.configure_outcome(action, found, c.event_timer, uptime)
    c.done(action, ok, None, now, result)
    return c.session


def configured(cfg: Optional[Config] = None, now: float = 0.0) -> Core:
    """A core whose first configuration succeeded at `now` (session `SESSION`)."""
    c = Core(cfg or Config())
    assert configure(c, now) == SESSION
    return c
