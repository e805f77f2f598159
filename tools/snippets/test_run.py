"""The blocks of the README, docs/ and host/README.md that run without hardware, run against
the emulated board (`cargo xtask test`, with the interop suite's venv: python-can, canopen;
`tools/` on the path): per document, its `emulator` block is started on free ports, then its
`python` blocks run in order in one namespace and its `control` lines are typed on the
control port. How the blocks are marked: `snippets.py`."""

from __future__ import annotations

import contextlib
import io
import time
from pathlib import Path

import pytest

import snippets
from rig import Board, Stimulus
from rig.constants import START_TIMEOUT

# Documents (by their path in the repository) whose blocks continue another's session
# (`network` and `node` from it).
CONTINUES = {"docs/LSS.md": "docs/EMULATED-BOARD.md"}
RUNNABLE = {"emulator", "python", "control"}
# Seconds between two `python` blocks of a session.
PAUSE = 1.0


def sessions() -> dict[str, list[snippets.Snippet]]:
    """The runnable blocks of each document that has an emulator, a continued document's
    blocks first."""
    by_doc = {
        path.relative_to(snippets.ROOT).as_posix(): [
            s for s in snippets.snippets(path) if s.kind in RUNNABLE
        ]
        for path in snippets.documents()
    }
    result = {}
    for name, blocks in by_doc.items():
        if not blocks:
            continue
        before = by_doc.get(CONTINUES.get(name, ""), [])
        result[name] = before + blocks
    return result


SESSIONS = sessions()


def test_the_runnable_documents():
    assert {"docs/FIRST-POWER-ON.md", "docs/EMULATED-BOARD.md", "docs/LSS.md"} <= set(SESSIONS)
    for name, blocks in SESSIONS.items():
        assert blocks[0].kind == "emulator", f"{name}: its first runnable block starts nothing"


# The engine's log line once the boot-up has gone out.
BOOTED = r"NMT Initialising -> PreOperational"


def start(snippet: snippets.Snippet, log_dir: Path) -> Board:
    """The board of an `emulator` block, on free ports, its parameter page in a fresh file
    (not the default one) unless the block names one."""
    words = snippets.command_lines(snippet.text)[0].split()
    extra = dict(zip(words[7::2], words[8::2], strict=True))
    extra = {k.removeprefix("--"): v for k, v in extra.items()}
    flash = Path(extra.get("flash", log_dir / "flash.bin"))
    board = Board(log_dir / "board.log", flash, dip=extra.get("dip"), image=extra.get("image"))
    # As the documents say: connect once it listens.
    port = board.can_port
    board.wait_for_log(rf"board-emu: SLCAN on 127\.0\.0\.1:{port}\b", timeout=START_TIMEOUT)
    return board


@pytest.mark.parametrize("document", sorted(SESSIONS))
def test_blocks_run_as_written(document, tmp_path):
    emulator = None
    stimulus = None
    namespace: dict = {"__name__": "__snippet__"}
    try:
        for block in SESSIONS[document]:
            started = time.monotonic()
            if block.kind == "emulator":
                assert emulator is None, f"{block.where}: a second emulator"
                emulator = start(block, tmp_path)
                continue
            assert emulator is not None
            if block.kind == "python":
                # A reader pastes one block after another: give the node a moment, e.g. to
                # finish the reset the block before asked for.
                if namespace.get("__builtins__") is not None:
                    time.sleep(PAUSE)
                code = snippets.python_for_emulator(block, emulator.can_port)
                out = io.StringIO()
                with contextlib.redirect_stdout(out):
                    exec(compile(code, block.where, "exec"), namespace)  # noqa: S102
                lines = out.getvalue().splitlines()
                print(f"{block.where}: ran in {time.monotonic() - started:.1f} s: {lines}")
                expected = snippets.printed(code)
                if expected:
                    assert lines[-len(expected) :] == expected, f"{block.where}: printed {lines}"
            elif block.kind == "control":
                if stimulus is None:
                    # As a reader would: type once the node is up (its boot-up went out).
                    emulator.wait_for_log(BOOTED, timeout=START_TIMEOUT)
                    stimulus = Stimulus(emulator.stim_port, emulator)
                for line in snippets.control_lines(block):
                    reply = stimulus.send(line)
                    assert reply == "ok", f"{block.where}: `{line}` answered `{reply}`"
                print(f"{block.where}: {snippets.control_lines(block)} answered ok")
    finally:
        network = namespace.get("network")
        if network is not None:
            with contextlib.suppress(Exception):
                network.disconnect()
        if stimulus is not None:
            stimulus.close()
        if emulator is not None:
            emulator.stop()
