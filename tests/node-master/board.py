"""One emulated board for the node-canopen suite, started by the repository's rig.

    python board.py FOLDER

Starts the release image on the emulated board (`rig.Board`: the server command that `cargo
xtask` exports, or `cargo xtask board`) with its log and a fresh parameter page in FOLDER,
prints one JSON line with its CAN (SLCAN) and control ports, and keeps the board running
until its standard input closes: the node test process holds that pipe, so a board never
outlives the tests that use it, even when they crash.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# The rig is not installed (docs/TESTING.md): tools/ on the path, and host/src for the feed
# record's layout that the rig imports.
sys.path[:0] = [str(ROOT / "tools"), str(ROOT / "host" / "src")]

from rig import Board  # noqa: E402


def main() -> None:
    folder = Path(sys.argv[1])
    folder.mkdir(parents=True, exist_ok=True)
    flash = folder / "flash.bin"
    # Every group starts in the factory state: no stored parameters from an earlier run.
    flash.unlink(missing_ok=True)
    board = Board(folder / "board.log", flash)
    try:
        ports = {"can_port": board.can_port, "stim_port": board.stim_port}
        print(json.dumps(ports), flush=True)
        sys.stdin.read()
    finally:
        board.stop()


if __name__ == "__main__":
    main()
