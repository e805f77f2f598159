"""The test rig: the release image on the emulated board and a python-canopen master, as a
library.

The interop suite (`tests/interop`, whose conftest.py holds only the pytest fixtures), the
LinuxCNC suite, `cargo xtask demo` (tools/demo.py) and the LinuxCNC console import it from
here. It is not installed: put `tools/` on `sys.path` (the suites' pytest.ini files do) or
run a script that lives in `tools/`; `host/src` too, since `feed_record` decodes with the
host component's `canopen_handwheel.core.Record` and the relay speaks SLCAN with its
`canopen_handwheel.slcan` (both standard library only).

- `constants`: the repository root, the EDS, COB-IDs, NMT states and commands, timeouts;
- `frames`: `Frame`, `FrameRecorder` (every received frame, with waits), `feed_record` (a
  TPDO1 as a `Record`);
- `emulator`: `free_ports`, `Board` (`cargo xtask board` in its own process group, with its
  control line), `Stimulus` (the rig's client of that line: wheel and switches),
  `connect_bus` (python-can's slcan bus on the CAN port);
- `master`: `Rig` (the master's view of one node), `open_rig`, `MasterHeartbeat`;
- `relay` (imported as `rig.relay`, not re-exported): `Relay`, an SLCAN relay between one
  client (the host component) and the emulator that drops, copies and adds frames;
- `component` (imported as `rig.component`): `HalLog`, the host component's pins as its fake
  `hal` logs them, and `end_component`.
"""

from .constants import (
    AXES,
    BOOTUP,
    EDS,
    EMCY,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NMT,
    NMT_PRE_OPERATIONAL,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    NODE_ID,
    NOTIFIER_CYCLE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    ROOT,
    SDO_RX,
    SDO_TIMEOUT,
    SDO_TX,
    SELECT_TIMEOUT,
    START_TIMEOUT,
    STIM_TIMEOUT,
    STOPPED,
    TPDO1,
    TPDO2,
)
from .emulator import Board, Stimulus, connect_bus, free_ports, slcan_line
from .frames import STATUS_FLAGS, Frame, FrameRecorder, feed_record
from .master import MasterHeartbeat, Rig, open_rig

__all__ = [
    "AXES",
    "BOOTUP",
    "Board",
    "EDS",
    "EMCY",
    "FRAME_TIMEOUT",
    "HEARTBEAT",
    "NMT",
    "NMT_PRE_OPERATIONAL",
    "NMT_RESET_COMMUNICATION",
    "NMT_RESET_NODE",
    "NMT_START",
    "NMT_STOP",
    "NODE_ID",
    "NOTIFIER_CYCLE",
    "OPERATIONAL",
    "PRE_OPERATIONAL",
    "ROOT",
    "SDO_RX",
    "SDO_TIMEOUT",
    "SDO_TX",
    "SELECT_TIMEOUT",
    "START_TIMEOUT",
    "STIM_TIMEOUT",
    "STOPPED",
    "TPDO1",
    "TPDO2",
    "Frame",
    "STATUS_FLAGS",
    "FrameRecorder",
    "MasterHeartbeat",
    "Rig",
    "Stimulus",
    "connect_bus",
    "feed_record",
    "free_ports",
    "open_rig",
    "slcan_line",
]
