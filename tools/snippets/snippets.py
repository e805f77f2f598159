"""The code blocks of the README, docs/ and host/README.md, and how each is checked.

Every fenced code block of `README.md`, `docs/*.md` and `host/README.md` carries a mark, an
HTML comment on the line right before its opening fence (GitHub does not show it):

    <!-- snippet: KIND [ARGUMENT] -->

KIND says how `cargo xtask test` checks the block:

- `hardware`: needs a board, a debug probe or a CAN adapter; not run.
- `output`: what a program printed (log lines, frames); not a command.
- `commands`: shell lines of this project's tools, checked against the files they name: every
  `cargo xtask TASK --flag` against xtask's usage text (`xtask/src/main.rs`), `cargo fw`
  against the alias in `.cargo/config.toml` (xtask runs it after its own build and fails if
  it compiles anything), and every path of the repository a line names must exist (not those below
  `target/`, which the tools make).
- `emulator`: one `cargo xtask board --can-port 5000 --stim-port 5001 ...` line. The run
  check starts it (on free ports in place of 5000 and 5001) for the `python` and `control`
  blocks after it in the same file (`test_run.py` names the documents that continue another's
  session, such as LSS.md after EMULATED-BOARD.md).
- `python`: run, in order with the file's other `python` blocks in one namespace (as typed
  into one interpreter), against the last `emulator` block's emulator, with the interop
  suite's pinned python-can and canopen, a second apart (as a reader pastes them).
  `socket://127.0.0.1:5000` becomes the emulator's SLCAN port. ARGUMENT `can0`: the block
  opens SocketCAN `can0` (a real adapter) and runs with the emulator's SLCAN channel in its
  place. A `print(...)` line ending in a comment `# TEXT` must print TEXT.
- `control`: `nc 127.0.0.1 5001`, then lines typed on the board's control port: each is
  sent, and each must be answered `ok`.
- `pip`: `pip install` lines whose pinned packages must be pinned so in ARGUMENT, a
  requirements file (`name==version` lines).
- `mirrors`: HAL lines that must agree with ARGUMENT, a HAL file that LinuxCNC runs in the
  LinuxCNC suite: every other line of the block is a line of that file (spaces aside), and
  a `loadusr` line's options are options of the file's `loadusr` line.
- `hal`: HAL lines of LinuxCNC's own components around the handwheel's pins: every
  `handwheel.` pin is a pin of the component's pin table (host/README.md, "Pins"), and every
  `loadrt ... names=X` instance gets its `addf` and only pins its component has
  (`test_marks.py` lists those).
- `file`: the contents of a configuration file for another program (systemd-networkd, udev);
  checked for the names it must contain, listed in `test_marks.py`.

Standard library only: `test_marks.py` runs in the documents' check, `test_run.py` with the
interop suite's venv.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
KINDS = {
    "hardware",
    "output",
    "commands",
    "emulator",
    "python",
    "control",
    "pip",
    "mirrors",
    "hal",
    "file",
}
FENCE = re.compile(r"^( *)(`{3,}|~{3,})(.*)$")
MARK = re.compile(r"^\s*<!--\s*snippet:\s*(\S+)(?:\s+(.*?))?\s*-->\s*$")
# The ports the documents use, replaced by free ones when run.
DOC_CAN_PORT = 5000
DOC_STIM_PORT = 5001


@dataclass(frozen=True)
class Snippet:
    path: Path
    line: int  # of the opening fence, from 1
    info: str  # the fence's info string (`sh`, `python`, ...)
    kind: str | None  # None: no mark
    argument: str
    text: str  # the block's lines, without their common indentation

    @property
    def where(self) -> str:
        shown = self.path.relative_to(ROOT) if self.path.is_relative_to(ROOT) else self.path
        return f"{shown.as_posix()}:{self.line}"


def documents(root: Path = ROOT) -> list[Path]:
    """The README, docs/*.md and the LinuxCNC component's README."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md")), root / "host" / "README.md"]


def snippets(path: Path) -> list[Snippet]:
    """The fenced code blocks of one Markdown file, with their marks."""
    lines = path.read_text(encoding="utf-8").splitlines()
    found = []
    i = 0
    while i < len(lines):
        opened = FENCE.match(lines[i])
        if not opened:
            i += 1
            continue
        indent, fence, info = len(opened[1]), opened[2], opened[3].strip()
        body = []
        j = i + 1
        while j < len(lines):
            closing = FENCE.match(lines[j])
            if closing and closing[2][0] == fence[0] and len(closing[2]) >= len(fence):
                if not closing[3].strip():
                    break
            body.append(lines[j][indent:] if lines[j][:indent].strip() == "" else lines[j])
            j += 1
        mark = MARK.match(lines[i - 1]) if i > 0 else None
        found.append(
            Snippet(
                path=path,
                line=i + 1,
                info=info,
                kind=mark[1] if mark else None,
                argument=(mark[2] or "") if mark else "",
                text="\n".join(body) + "\n",
            )
        )
        i = j + 1
    return found


def all_snippets(root: Path = ROOT) -> list[Snippet]:
    return [s for path in documents(root) for s in snippets(path)]


def command_lines(text: str) -> list[str]:
    """The commands of a shell block: comments and blank lines dropped."""
    result = []
    for line in text.splitlines():
        command = re.sub(r"(^|\s)#.*$", "", line).strip()
        if command:
            result.append(command)
    return result


def xtask_usage(root: Path = ROOT) -> dict[str, str]:
    """xtask's usage text (`USAGE` in xtask/src/main.rs) by task: the task's lines."""
    source = (root / "xtask" / "src" / "main.rs").read_text(encoding="utf-8")
    usage = re.search(r'const USAGE: &str = "(.*?)";', source, re.S)
    assert usage, "no USAGE in xtask/src/main.rs"
    tasks: dict[str, str] = {}
    current = None
    for line in usage[1].split("tasks:", 1)[1].splitlines():
        task = re.match(r"^  ([a-z][a-z-]*)(\s|$)", line)
        if task:
            current = task[1]
            tasks[current] = line
        elif current and line.strip():
            tasks[current] += "\n" + line
    return tasks


def cargo_aliases(root: Path = ROOT) -> dict[str, str]:
    """The `[alias]` table of .cargo/config.toml."""
    text = (root / ".cargo" / "config.toml").read_text(encoding="utf-8")
    table = re.search(r"^\[alias\]\n(.*?)(?:^\[|\Z)", text, re.S | re.M)
    assert table, "no [alias] in .cargo/config.toml"
    return dict(re.findall(r'^(\w[\w-]*)\s*=\s*"([^"]*)"', table[1], re.M))


def command_problems(line: str, root: Path = ROOT) -> list[str]:
    """Why a `commands` line does not match the files it names (empty: it does)."""
    words = line.split()
    problems = []
    if words[:2] == ["cargo", "xtask"]:
        usage = xtask_usage(root)
        task = words[2] if len(words) > 2 else ""
        if task not in usage:
            return [f"`cargo xtask {task}`: no such task in xtask's usage"]
        for word in words[3:]:
            flag = word.split("=")[0].strip("[]")
            if flag.startswith("--") and flag not in usage[task]:
                problems.append(f"`cargo xtask {task}`: {flag} is not in its usage")
    for word in words:
        candidate = word.strip("`'\",;()")
        first = candidate.split("/")[0]
        # Paths below the repository's folders (not build output, made by the tools).
        if "/" in candidate and "://" not in candidate and first not in ("", "target"):
            if not (root / first).is_dir():
                continue
            if not (root / candidate.rstrip("/")).exists():
                problems.append(f"{candidate}: no such path")
    return problems


def pins(text: str) -> dict[str, str]:
    """`name==version` pins of a requirements file or of `pip install` lines, by the
    normalised name."""
    return {
        re.sub(r"[-_.]+", "-", m[1]).lower(): m[2]
        for m in re.finditer(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([0-9][^\s;#]*)", text)
    }


def hal_lines(text: str) -> list[str]:
    """A HAL text's statements, spaces normalised, comments dropped."""
    return [" ".join(s.split()) for s in command_lines(text)]


def hal_problems(snippet_text: str, hal_file: str) -> list[str]:
    """Lines of a HAL snippet that the HAL file does not have."""
    file_lines = hal_lines(hal_file)
    loadusr = [line for line in file_lines if line.startswith("loadusr")]
    problems = []
    for line in hal_lines(snippet_text):
        if line.startswith("loadusr"):
            options = {w for w in line.split() if w.startswith("-")}
            known = {w for f in loadusr for w in f.split() if w.startswith("-")}
            if not loadusr or not options <= known:
                problems.append(f"{line}: options {sorted(options - known)} not in the file")
        elif line not in file_lines:
            problems.append(f"{line}: not in the file")
    return problems


def table_pins(root: Path = ROOT) -> set[str]:
    """The component's pins in its pin table (host/README.md), without the `N.` prefix."""
    text = (root / "host" / "README.md").read_text(encoding="utf-8")
    names = set()
    for m in re.finditer(r"^\| `N\.([a-z0-9.L-]+)` \|", text, re.M):
        name = m[1]
        names |= {name.replace(".L.", f".{a}.") for a in "xyzwv"} if ".L." in name else {name}
    return names


def hal_pin_problems(
    text: str, component_pins: dict[str, set[str]], root: Path = ROOT
) -> list[str]:
    """Pins of a `hal` block that do not exist: the handwheel's against the component's pin
    table, a `loadrt` instance's against its component's pins (`component_pins`)."""
    problems = []
    lines = hal_lines(text)
    instances = {}
    for line in lines:
        loadrt = re.fullmatch(r"loadrt (\S+) names=(\S+)", line)
        if loadrt:
            for name in loadrt[2].split(","):
                instances[name] = loadrt[1]
    for name in instances:
        if f"addf {name} servo-thread" not in lines and not any(
            line.startswith(f"addf {name} ") for line in lines
        ):
            problems.append(f"{name}: no addf")
    known = table_pins(root)
    for line in lines:
        if not line.startswith("net "):
            continue
        for pin in line.split()[2:]:
            if pin in ("=>", "<=", "<=>"):
                continue
            owner, _, rest = pin.partition(".")
            if owner == "handwheel" and rest not in known:
                problems.append(f"{pin}: not a pin of the component's table")
            if owner in instances and rest not in component_pins.get(instances[owner], set()):
                problems.append(f"{pin}: {instances[owner]} has no such pin")
    return problems


def printed(text: str) -> list[str]:
    """What the `print(...)  # TEXT` lines of a Python block say they print."""
    return [m[1].strip() for m in re.finditer(r"^\s*print\(.*\)\s*#\s*(.+)$", text, re.M)]


def python_for_emulator(snippet: Snippet, can_port: int) -> str:
    """A `python` block's code with the emulator's SLCAN port in the document's place."""
    code = snippet.text.replace(
        f"socket://127.0.0.1:{DOC_CAN_PORT}", f"socket://127.0.0.1:{can_port}"
    )
    if snippet.argument == "can0":
        socketcan = 'interface="socketcan", channel="can0"'
        assert socketcan in code, f"{snippet.where}: no `{socketcan}` to replace"
        code = code.replace(
            socketcan,
            f'interface="slcan", channel="socket://127.0.0.1:{can_port}", sleep_after_open=0',
        )
    return code


def control_lines(snippet: Snippet) -> list[str]:
    """The lines a `control` block types on the control port (after its `nc` line)."""
    lines = command_lines(snippet.text)
    assert lines and lines[0] == f"nc 127.0.0.1 {DOC_STIM_PORT}", (
        f"{snippet.where}: a control block starts with `nc 127.0.0.1 {DOC_STIM_PORT}`"
    )
    return lines[1:]
