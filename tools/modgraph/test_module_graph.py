"""The import graphs of the firmware crate, the no_std crates and xtask, and of the Python
modules of host/ and tools/, have no circle (`modgraph.py` says how they are read), and the
check finds one in each kind of graph."""

from modgraph import (
    CRATES,
    PYTHON_FOLDERS,
    ROOT,
    circles,
    crate_roots,
    graph_of,
    named,
    python_graph,
    python_modules,
    strongly_connected,
)


def test_the_rust_crates_have_no_module_circle():
    for crate in CRATES:
        for root in crate_roots(ROOT / crate / "src"):
            found = circles(graph_of(root))
            assert not found, f"{root.relative_to(ROOT)}: " + "; ".join(map(named, found))


def test_the_check_reads_every_crate():
    """A check that read nothing would pass: each crate's first root (its library, else its
    binary) has modules, and their uses are found (the firmware's CAN glue uses the board's
    bxCAN instance; xtask's linker finds flip-link with the machine's helpers, and its footprint
    and update file read the one ELF reader)."""
    for crate in CRATES:
        edges = graph_of(crate_roots(ROOT / crate / "src")[0])
        assert len(edges) > 3, crate
        assert any(edges.values()), crate
    firmware = graph_of(ROOT / "src" / "lib.rs")
    assert ("board",) in firmware[("can", "bxcan_port")]
    assert ("can", "bus") in firmware[("round_log",)]
    xtask = graph_of(ROOT / "xtask" / "src" / "main.rs")
    assert ("host",) in xtask[("linker",)]
    assert ("elf",) in xtask[("footprint",)] and ("elf",) in xtask[("update",)]


def test_the_check_finds_a_circle_through_use_trees_and_paths(tmp_path):
    src = tmp_path / "src"
    (src / "device").mkdir(parents=True)
    (src / "lib.rs").write_text(
        "pub mod frame;\npub mod sdo;\nmod nmt;\npub mod device;\npub use frame::{Frame, Sink};\n"
    )
    (src / "frame.rs").write_text("use crate::{nmt::State, sdo::{Abort, Server}};\n")
    # The root's re-export names the module it comes from.
    (src / "sdo.rs").write_text("pub struct Abort;\nfn f(x: crate::Frame) {}\n")
    (src / "nmt.rs").write_text("pub enum State {}\n")
    # A child using its parent is nesting, not a circle; nor is a test module's use.
    (src / "device.rs").write_text("mod objects;\nuse objects::Comm;\n")
    (src / "device" / "objects.rs").write_text(
        "use super::Inner;\n#[cfg(test)]\nmod tests { use crate::frame::X; }\n"
    )
    edges = graph_of(src / "lib.rs")
    assert edges[("frame",)] == {("nmt",), ("sdo",)}
    assert edges[("device", "objects")] == set()
    assert circles(edges) == [[("frame",), ("sdo",)]]


def test_the_check_finds_a_circle_through_a_descendant(tmp_path):
    """`board` uses `can`, and `can`'s child `port` uses `board` back: the circle
    `board <-> can`, which module by module is no circle at all (the firmware had this shape:
    `can::bxcan_port` used `board`, which re-exported `can::start`). Inside `can` its children
    are checked too. A module behind a feature is a module; a test-only module file and a file
    no `mod` declares are not."""
    src = tmp_path / "src"
    (src / "can").mkdir(parents=True)
    (src / "lib.rs").write_text("pub mod board;\npub mod can;\n")
    (src / "main.rs").write_text("mod app { use super::Mono; }\n")
    # Reached only through an alias.
    (src / "board.rs").write_text("use crate::{can as bus};\npub use bus::{start as start_can};\n")
    (src / "can" / "mod.rs").write_text(
        'pub mod port;\n#[cfg(feature = "queue")]\nmod queue;\n'
        "#[cfg(test)]\nmod fake;\npub use port::Port;\n"
    )
    (src / "can" / "port.rs").write_text("use crate::board::Instance;\nuse super::queue::Queue;\n")
    (src / "can" / "queue.rs").write_text("fn f(p: super::port::Port) {}\n")
    (src / "can" / "fake.rs").write_text("use crate::board::Pins;\n")
    (src / "stale.rs").write_text("use crate::board::Pins;\n")

    edges = graph_of(src / "lib.rs")
    assert set(edges) == {(), ("board",), ("can",), ("can", "port"), ("can", "queue")}
    assert edges[("board",)] == {("can",)}
    assert edges[("can", "port")] == {("board",), ("can", "queue")}
    assert strongly_connected(edges) == [[("can", "port"), ("can", "queue")]]
    assert circles(edges) == [
        [("board",), ("can",)],
        [("can", "port"), ("can", "queue")],
    ]
    # Without `port`'s use of `board` the outer circle is gone; the inner one stays.
    (src / "can" / "port.rs").write_text("use super::queue::Queue;\n")
    assert circles(graph_of(src / "lib.rs")) == [[("can", "port"), ("can", "queue")]]
    # The binary is a crate of its own: `super::` from its inline module is its root.
    assert graph_of(src / "main.rs") == {(): set()}


def test_the_check_finds_a_circle_between_two_files_of_a_binary(tmp_path):
    """xtask's shape: a binary whose root declares every module, `linker` using `host` in a
    `use` and `host` using `linker` back by a path in code (xtask had this circle, with
    cargo's `bin` folder in `linker`)."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "main.rs").write_text("mod host;\nmod linker;\nmod fw;\nuse fw::build;\n")
    (src / "linker.rs").write_text("use crate::host;\npub fn flip_link() { host::find(); }\n")
    (src / "host.rs").write_text("pub fn root() { crate::linker::cargo_bin_dir(); }\n")
    (src / "fw.rs").write_text("use crate::{linker, host::find};\n")
    edges = graph_of(src / "main.rs")
    assert edges[("fw",)] == {("host",), ("linker",)}
    assert circles(edges) == [[("host",), ("linker",)]]


def test_the_python_modules_have_no_import_circle():
    found = circles(python_graph([ROOT / folder for folder in PYTHON_FOLDERS]))
    assert not found, "; ".join(named(c, ".") for c in found)


def test_the_check_reads_every_python_folder():
    """Packages and the script folders' modules are found under the names they are imported
    by, and their imports across the folders too; tests and build output are not modules."""
    edges = python_graph([ROOT / folder for folder in PYTHON_FOLDERS])
    assert ("canopen_handwheel", "core") in edges[("canopen_handwheel", "capture")]
    assert ("canopen_handwheel", "core") in edges[("rig", "frames")]
    assert ("stm32emu", "image") in edges[("stm32emu", "machine")]
    assert ("cycles",) in edges[("bench",)]
    assert {("demo",), ("rig",)} <= edges[("console",)]
    assert ("seal", "seal") in edges
    assert not any(m and (m[-1].startswith("test_") or m[-1] == "conftest") for m in edges)
    assert ("fake_hal",) not in edges  # a helper of host/tests


def test_the_check_finds_python_import_circles(tmp_path):
    """Relative and absolute imports, an import inside a function and one of a package's
    name: `a.b` imports `c` at a call while `c` imports `a` is the circle `a <-> c`; inside
    `a`, `b` and `d` import each other. A package importing its own modules, a module
    importing its package, modules from elsewhere and tests make no edge."""
    tools = tmp_path / "tools"
    (tools / "a").mkdir(parents=True)
    (tools / "script").mkdir()
    (tools / "a" / "__init__.py").write_text("from .b import run\nfrom . import d\n")
    (tools / "a" / "b.py").write_text(
        "import os\nfrom a import d\n\ndef run():\n    import c\n    return c\n"
    )
    (tools / "a" / "d.py").write_text("from .b import run as again\nimport a\n")
    (tools / "c.py").write_text("from a.d import again\n")
    (tools / "script" / "tool.py").write_text("import c\nimport helper\n")
    (tools / "script" / "helper.py").write_text("X = 1\n")
    (tools / "script" / "test_tool.py").write_text("import tool\n")

    edges = python_graph([tools])
    assert edges == {
        (): set(),
        ("a",): set(),
        ("a", "b"): {("a", "d"), ("c",)},
        ("a", "d"): {("a", "b")},
        ("c",): {("a", "d")},
        ("tool",): {("c",), ("helper",)},
        ("helper",): set(),
    }
    assert circles(edges) == [[("a",), ("c",)], [("a", "b"), ("a", "d")]]
    # Without the deferred import the outer circle is gone; the inner one stays.
    (tools / "a" / "b.py").write_text("from a import d\n")
    assert circles(python_graph([tools])) == [[("a", "b"), ("a", "d")]]
    assert strongly_connected(python_graph([tools])) == [[("a", "b"), ("a", "d")]]


def test_two_python_modules_of_one_name_are_refused(tmp_path):
    for folder in ("one", "two"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "server.py").write_text("")
    try:
        python_modules([tmp_path])
    except AssertionError as error:
        assert "server" in str(error)
    else:
        raise AssertionError("two modules `server` were taken as one")
