"""Where the repository is, the node's COB-IDs, NMT states and commands, and the timeouts
every master here waits with (each overridable through its environment variable)."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "eds" / "handwheel.eds"

NODE_ID = 16
NMT = 0x000
EMCY = 0x080 + NODE_ID
TPDO1 = 0x180 + NODE_ID
TPDO2 = 0x280 + NODE_ID
SDO_TX = 0x580 + NODE_ID  # server -> client
SDO_RX = 0x600 + NODE_ID  # client -> server
HEARTBEAT = 0x700 + NODE_ID

# Heartbeat / boot-up state bytes.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F

# NMT command specifiers.
NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82

# The selector's axis codes (0x2010:1, byte 4 of the feed record) by stimulus name.
AXES = {"off": 0, "x": 1, "y": 2, "z": 3, "w": 4, "v": 5}


def _env_seconds(name: str, default: float) -> float:
    return float(os.environ.get(name, default))


# How long a notifier's thread waits in one receive: it sees a stop only between two, so
# this is what closing a master costs (python-can's and python-canopen's 1 s, on every test's
# teardown, was a third of the interop suite's time).
NOTIFIER_CYCLE = 0.05

# The first start also builds the firmware (and may install defmt-print): be patient.
START_TIMEOUT = _env_seconds("HANDWHEEL_START_TIMEOUT", 900)
# Waiting for a frame, a reply or a log line. The board's time is emulated: generous.
FRAME_TIMEOUT = _env_seconds("HANDWHEEL_FRAME_TIMEOUT", 5)
SDO_TIMEOUT = _env_seconds("HANDWHEEL_SDO_TIMEOUT", 2)
STIM_TIMEOUT = _env_seconds("HANDWHEEL_STIM_TIMEOUT", 30)
# Debounced selector: 4 samples at 5 ms; polled through SDO until it shows.
SELECT_TIMEOUT = _env_seconds("HANDWHEEL_SELECT_TIMEOUT", 3)
