"""Every code block of the README, docs/ and host/README.md is marked with how it is checked,
and the blocks that are checked against files agree with them (run by `cargo xtask docs --check` and
`cargo xtask test`; standard library and pytest only). What runs against the emulated board:
`test_run.py`."""

from __future__ import annotations

import re

import pytest

import snippets

ALL = snippets.all_snippets()
# The pins of LinuxCNC's components that `hal` blocks load (LinuxCNC's and2 manual page).
COMPONENT_PINS = {"and2": {"in0", "in1", "out"}}
# What a `file` block must contain, by the document and the block's argument.
FILE_CONTENTS = {
    "can0.network": ["[Match]", "Name=can0", "[CAN]", "BitRate=1000000", "RestartSec="],
    "udev": ['SUBSYSTEM=="usb"', "ATTR{idVendor}", "ATTR{idProduct}", "TAG+="],
}


def by_kind(kind: str) -> list[snippets.Snippet]:
    return [s for s in ALL if s.kind == kind]


def test_the_documents_have_blocks_of_every_checked_kind():
    kinds = {s.kind for s in ALL}
    assert {"hardware", "commands", "emulator", "python", "control", "mirrors"} <= kinds
    assert len(ALL) >= 25


@pytest.mark.parametrize("snippet", ALL, ids=lambda s: s.where)
def test_every_block_is_marked_with_a_known_kind(snippet):
    assert snippet.kind is not None, (
        f"{snippet.where}: mark the block with `<!-- snippet: KIND -->` on the line before it "
        f"(tools/snippets/snippets.py lists the kinds)"
    )
    assert snippet.kind in snippets.KINDS, f"{snippet.where}: unknown kind {snippet.kind}"


@pytest.mark.parametrize("snippet", by_kind("commands"), ids=lambda s: s.where)
def test_commands_match_the_files_they_name(snippet):
    problems = [
        p for line in snippets.command_lines(snippet.text) for p in snippets.command_problems(line)
    ]
    assert not problems, f"{snippet.where}: " + "; ".join(problems)


def test_the_command_check_finds_wrong_tasks_flags_and_paths():
    assert snippets.command_problems("cargo xtask demo --script") == []
    assert snippets.command_problems("cargo xtask dmeo") == [
        "`cargo xtask dmeo`: no such task in xtask's usage"
    ]
    assert snippets.command_problems("cargo xtask demo --bored") == [
        "`cargo xtask demo`: --bored is not in its usage"
    ]
    assert snippets.command_problems("ls tools/no-such-tool") == [
        "tools/no-such-tool: no such path"
    ]
    assert snippets.cargo_aliases()["fw"] == (
        "build --release --package handwheel-firmware --target thumbv7m-none-eabi"
    )


@pytest.mark.parametrize("snippet", by_kind("emulator"), ids=lambda s: s.where)
def test_emulator_blocks_are_one_xtask_line_on_the_documents_ports(snippet):
    (line,) = snippets.command_lines(snippet.text)
    assert re.fullmatch(
        rf"cargo xtask board --can-port {snippets.DOC_CAN_PORT} "
        rf"--stim-port {snippets.DOC_STIM_PORT}( .*)?",
        line,
    ), f"{snippet.where}: {line}"
    assert snippets.command_problems(line) == []


@pytest.mark.parametrize("snippet", by_kind("pip"), ids=lambda s: s.where)
def test_pip_pins_are_the_projects(snippet):
    pinned = snippets.pins((snippets.ROOT / snippet.argument).read_text(encoding="utf-8"))
    wanted = snippets.pins(snippet.text)
    assert wanted, f"{snippet.where}: no pinned package"
    wrong = {name: v for name, v in wanted.items() if pinned.get(name) != v}
    assert not wrong, f"{snippet.where}: not as {snippet.argument} pins them: {wrong}"


def test_the_venv_snippet_installs_what_slcan_needs():
    (first_power_on,) = [s for s in by_kind("pip") if s.path.name == "FIRST-POWER-ON.md"]
    assert {"canopen", "python-can", "pyserial"} <= set(snippets.pins(first_power_on.text))


@pytest.mark.parametrize("snippet", by_kind("mirrors"), ids=lambda s: s.where)
def test_hal_lines_are_those_linuxcnc_runs(snippet):
    hal_file = (snippets.ROOT / snippet.argument).read_text(encoding="utf-8")
    problems = snippets.hal_problems(snippet.text, hal_file)
    assert not problems, f"{snippet.where} against {snippet.argument}: " + "; ".join(problems)


def test_the_hal_check_finds_a_changed_line():
    hal = "loadusr -Wn h comp --channel X --node 1\nnet a h.x => b.x  # c\n"
    assert snippets.hal_problems("loadusr -Wn h /p/comp --node 2\nnet  a h.x =>  b.x\n", hal) == []
    assert snippets.hal_problems("net a h.y => b.x\nloadusr c --nodes 1\n", hal) == [
        "net a h.y => b.x: not in the file",
        "loadusr c --nodes 1: options ['--nodes'] not in the file",
    ]


@pytest.mark.parametrize("snippet", by_kind("hal"), ids=lambda s: s.where)
def test_hal_blocks_name_pins_that_exist(snippet):
    problems = snippets.hal_pin_problems(snippet.text, COMPONENT_PINS)
    assert not problems, f"{snippet.where}: " + "; ".join(problems)
    assert "handwheel.enable" in snippet.text


def test_the_hal_pin_check_finds_wrong_pins():
    assert {"enable", "axis.z.jog-counts", "halui.axis.v.select"} <= snippets.table_pins()
    text = "loadrt and2 names=a\nnet s a.out => handwheel.enabled\nnet t a.in2 => x.y\n"
    assert snippets.hal_pin_problems(text, COMPONENT_PINS) == [
        "a: no addf",
        "handwheel.enabled: not a pin of the component's table",
        "a.in2: and2 has no such pin",
    ]


@pytest.mark.parametrize("snippet", by_kind("file"), ids=lambda s: s.where)
def test_configuration_files_name_what_they_must(snippet):
    missing = [n for n in FILE_CONTENTS[snippet.argument] if n not in snippet.text]
    assert not missing, f"{snippet.where}: missing {missing}"


def test_marks_and_blocks_are_read_as_written(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "text\n<!-- snippet: python can0 -->\n```python\n"
        'n.connect(interface="socketcan", channel="can0")\nprint(1)  # 1\n```\n'
        "- item:\n\n  <!-- snippet: hardware -->\n  ```sh\n  ip link\n  ```\n"
        "```\nunmarked\n```\n"
    )
    found = snippets.snippets(page)
    code = 'n.connect(interface="socketcan", channel="can0")\nprint(1)  # 1\n'
    assert [(s.line, s.info, s.kind, s.argument, s.text) for s in found] == [
        (3, "python", "python", "can0", code),
        (10, "sh", "hardware", "", "ip link\n"),
        (13, "", None, "", "unmarked\n"),
    ]
    assert snippets.printed(found[0].text) == ["1"]
    assert snippets.python_for_emulator(found[0], 6000) == code.replace(
        'interface="socketcan", channel="can0"',
        'interface="slcan", channel="socket://127.0.0.1:6000", sleep_after_open=0',
    )
