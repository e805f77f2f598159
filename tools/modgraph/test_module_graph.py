"""The import graph of the firmware crate and of the no_std crates has no circle: a module
that uses another never ends up used by it, directly or through others.

A module and its descendants count as one: among the children of each module, a child
stands for its whole subtree, so `a::b` using `c` while `c` uses `a` is the circle
`a <-> c`, and within `a` its own children are checked the same way. A module reaching its
own ancestor or descendant is the nesting, not a circle (a child using its parent with
`super::`). Unit-test modules (`#[cfg(test)]` to the end of a file, or a `#[cfg(test)]`
module file) are left out, as they are no part of the structure.

The modules are the files the crate root reaches through `mod name;` declarations (a module
written inline in its file counts as part of that file's). The firmware package has two
roots: its library (`lib.rs`, the board glue) and its binary (`main.rs`, the RTIC
application), which reaches the library only as the external crate `handwheel_firmware`, so
each root is a graph of its own. The edges are read from the sources: every `crate::`,
`super::` and `self::` path, in `use` trees (braces expanded) and in code, taken to the
deepest module it names."""

import re
from pathlib import Path
from typing import Dict, List, Optional, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]
# The firmware package (the workspace root) and the no_std crates it is built from.
CRATES = [".", "crates/canopen-slave", "crates/handwheel-core", "crates/handwheel-device"]

Module = Tuple[str, ...]

# A `mod name;` declaration (any visibility), with the attributes right before it.
MOD_DECLARATION = re.compile(r"((?:#\[[^\]]*\]\s*)*)(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;")


def crate_roots(src: Path) -> List[Path]:
    """The crate roots in a package's `src`: its library, its binary, or both."""
    roots = [src / name for name in ("lib.rs", "main.rs") if (src / name).exists()]
    assert roots, f"{src}: neither lib.rs nor main.rs"
    return roots


def modules_of(root: Path) -> Dict[Module, Path]:
    """Each module the crate root `root` declares, directly or through its modules, with its
    file; test-only module files are left out."""
    found: Dict[Module, Path] = {(): root}
    todo = [((), root)]
    while todo:
        module, path = todo.pop()
        is_folder_root = path.name == "mod.rs" or path == root
        folder = path.parent if is_folder_root else path.with_suffix("")
        for attributes, name in MOD_DECLARATION.findall(code_of(path)):
            if "cfg(test)" in re.sub(r"\s+", "", attributes):
                continue
            files = [folder / f"{name}.rs", folder / name / "mod.rs"]
            child = next((f for f in files if f.exists()), None)
            assert child, f"{path}: `mod {name};` has no file"
            found[module + (name,)] = child
            todo.append((module + (name,), child))
    return found


def code_of(path: Path) -> str:
    """The file without comments and without its unit tests."""
    text = re.sub(r"//[^\n]*", "", path.read_text())
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    cut = re.search(r"#\[cfg\(test\)\]\s*mod\s+\w+\s*\{", text)
    return text[: cut.start()] if cut else text


def expand_use(tree: str) -> List[str]:
    """The paths a `use` tree names: `a::{b, c::{d, e}}` -> a::b, a::c::d, a::c::e."""
    tree = re.sub(r"\s+", "", re.sub(r"\s+as\s+\w+", "", tree))
    brace = tree.find("{")
    if brace < 0:
        return [tree]
    prefix, inner = tree[:brace], tree[brace + 1 : tree.rindex("}")]
    items, depth, start = [], 0, 0
    for i, ch in enumerate(inner):
        depth += ch == "{"
        depth -= ch == "}"
        if ch == "," and depth == 0:
            items.append(inner[start:i])
            start = i + 1
    items.append(inner[start:])
    return [p for item in items if item for p in expand_use(prefix + item)]


def paths_in(code: str) -> Set[str]:
    """Every crate-relative path the code names."""
    paths = set()
    for tree in re.findall(r"\buse\s+((?:crate|super|self)\b[^;]*);", code, flags=re.S):
        paths.update(expand_use(tree))
    paths.update(re.findall(r"\b(?:crate|super|self)(?:::\w+)+", code))
    return paths


def reexports(root_code: str, known: Set[Module]) -> Dict[str, Module]:
    """The names the crate root re-exports (`pub use a::b::Name;`), with the module each
    comes from, so that `crate::Name` counts as a use of that module."""
    names = {}
    for tree in re.findall(r"\bpub\s+use\s+([^;]*);", root_code, flags=re.S):
        for path in expand_use(tree):
            parts = path.split("::")
            module: Module = ()
            for part in parts[:-1]:
                if module + (part,) not in known:
                    break
                module += (part,)
            if module:
                names[parts[-1]] = module
    return names


def resolve(path: str, current: Module, known: Set[Module], names: Dict[str, Module]) -> Module:
    """The deepest module `path`, written in module `current`, names."""
    parts = [p for p in path.split("::") if p]
    if parts[0] == "crate":
        base: List[str] = []
        parts = parts[1:]
    else:
        base = list(current)
        while parts and parts[0] in ("self", "super"):
            if parts[0] == "super":
                base = base[:-1]
            parts = parts[1:]
    target = tuple(base)
    for part in parts:
        if target + (part,) in known:
            target += (part,)
        else:
            break
    else:
        return target
    if not target and part in names:
        return names[part]
    return target


def nested(a: Module, b: Module) -> bool:
    return a[: len(b)] == b or b[: len(a)] == a


def graph_of(root: Path) -> Dict[Module, Set[Module]]:
    """Each module of the crate whose root file is `root`, with the modules it uses (its
    ancestors and descendants left out)."""
    mods = modules_of(root)
    known = set(mods)
    names = reexports(code_of(root), known)
    edges: Dict[Module, Set[Module]] = {m: set() for m in mods}
    for module, path in mods.items():
        for p in paths_in(code_of(path)):
            target = resolve(p, module, known, names)
            if not nested(module, target):
                edges[module].add(target)
    return edges


def strongly_connected(edges: Dict[Module, Set[Module]]) -> List[List[Module]]:
    """The strongly connected components with more than one node (Tarjan)."""
    index: Dict[Module, int] = {}
    low: Dict[Module, int] = {}
    stack: List[Module] = []
    on_stack: Set[Module] = set()
    found: List[List[Module]] = []

    def visit(v: Module) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def child_towards(parent: Module, module: Module) -> Optional[Module]:
    """The child of `parent` whose subtree holds `module`; None for `parent` itself and for
    a module outside its subtree."""
    inside = len(module) > len(parent) and module[: len(parent)] == parent
    return module[: len(parent) + 1] if inside else None


def circles(edges: Dict[Module, Set[Module]]) -> List[List[Module]]:
    """The circles among the children of each module, each child merged with its
    descendants, outermost first."""
    found: List[List[Module]] = []
    for parent in sorted(edges, key=lambda m: (len(m), m)):
        merged: Dict[Module, Set[Module]] = {}
        for module, targets in edges.items():
            child = child_towards(parent, module)
            if child is None:
                continue
            uses = merged.setdefault(child, set())
            for target in targets:
                other = child_towards(parent, target)
                if other is not None and other != child:
                    uses.add(other)
        found += strongly_connected(merged)
    return found


def named(component: List[Module]) -> str:
    return " <-> ".join("::".join(m) or "crate" for m in component)


def test_the_firmware_and_no_std_crates_have_no_module_circle():
    for crate in CRATES:
        for root in crate_roots(ROOT / crate / "src"):
            found = circles(graph_of(root))
            assert not found, f"{root.relative_to(ROOT)}: " + "; ".join(map(named, found))


def test_the_check_reads_every_crate():
    """A check that read nothing would pass: each library has modules, and their uses are
    found (the firmware's CAN glue uses the board's bxCAN instance)."""
    for crate in CRATES:
        edges = graph_of(ROOT / crate / "src" / "lib.rs")
        assert len(edges) > 3, crate
        assert any(edges.values()), crate
    firmware = graph_of(ROOT / "src" / "lib.rs")
    assert ("board",) in firmware[("can", "bxcan_port")]
    assert ("can", "bus") in firmware[("round_log",)]


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
