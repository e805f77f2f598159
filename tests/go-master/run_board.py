"""Starts a fresh emulated board (the repository's rig, `rig.Board`) and runs the gocanopen
suite's test binary against it: the board's CAN port and control port go to the binary in
HANDWHEEL_CAN_PORT and HANDWHEEL_CONTROL_PORT. Run by `cargo xtask go-master` with the
interop venv's python, after the binary is built, so that the board does not wait for a build.

    python run_board.py LOG_DIR TEST_BINARY [test flags...]

Exits with the binary's status; on a failure it prints the last lines of the board's log.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
# The rig and what it imports (the host component's record layout), as the suites'
# pytest.ini files put them on the path.
sys.path[:0] = [str(ROOT / "tools"), str(ROOT / "host" / "src")]

from rig import Board  # noqa: E402


def main() -> int:
    log_dir, binary, *flags = sys.argv[1:]
    log_dir = Path(log_dir).resolve()
    log_dir.mkdir(parents=True, exist_ok=True)
    flash = log_dir / "flash.bin"
    flash.unlink(missing_ok=True)  # the factory state: nothing stored
    board = Board(log_dir / "board.log", flash)
    status = 1
    try:
        print(f"board: CAN port {board.can_port}, control port {board.stim_port}", flush=True)
        env = dict(
            os.environ,
            HANDWHEEL_CAN_PORT=str(board.can_port),
            HANDWHEEL_CONTROL_PORT=str(board.stim_port),
        )
        # The tests find the EDS relative to their own folder, as under `go test`.
        status = subprocess.run([binary, *flags], cwd=HERE, env=env).returncode
    finally:
        board.stop()
        if status != 0:
            tail = "\n".join(board.log().splitlines()[-40:])
            print(f"--- last lines of {board.log_path} ---\n{tail}", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
