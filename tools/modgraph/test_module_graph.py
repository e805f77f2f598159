"""The import graph of the no_std crates has no circle: a module that uses another never
ends up used by it, directly or through others. A module and its own descendants count as
one (a child reaching its parent with `super::` is the nesting, not a circle); unit-test
modules (`#[cfg(test)]` to the end of a file) are left out, as they are no part of the
structure.

The graph is read from the sources: every `crate::`, `super::` and `self::` path, in `use`
trees (braces expanded) and in code, taken to the deepest module it names."""

import re
from pathlib import Path
from typing import Dict, List, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]
CRATES = ["crates/canopen-slave", "crates/handwheel-core", "crates/handwheel-device"]

Module = Tuple[str, ...]


def modules_of(src: Path) -> Dict[Module, Path]:
    """Each module of the crate whose `src` this is, with its file."""
    found = {}
    for path in src.rglob("*.rs"):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts in (["lib"], ["main"]):
            parts = []
        elif parts[-1] == "mod":
            parts = parts[:-1]
        found[tuple(parts)] = path
    return found


def code_of(path: Path) -> str:
    """The file without comments and without its unit tests."""
    text = re.sub(r"//[^\n]*", "", path.read_text())
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    cut = re.search(r"#\[cfg\(test\)\]\s*mod\s", text)
    return text[: cut.start()] if cut else text


def expand_use(tree: str) -> List[str]:
    """The paths a `use` tree names: `a::{b, c::{d, e}}` -> a::b, a::c::d, a::c::e."""
    tree = re.sub(r"\s+", "", tree)
    brace = tree.find("{")
    if brace < 0:
        return [tree.split(" as ")[0]]
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


def graph_of(src: Path) -> Dict[Module, Set[Module]]:
    mods = modules_of(src)
    known = set(mods)
    names = reexports(code_of(mods[()]), known)
    edges: Dict[Module, Set[Module]] = {m: set() for m in mods}
    for module, path in mods.items():
        for p in paths_in(code_of(path)):
            target = resolve(p, module, known, names)
            if not nested(module, target):
                edges[module].add(target)
    return edges


def circles(edges: Dict[Module, Set[Module]]) -> List[List[Module]]:
    """The strongly connected components with more than one module (Tarjan)."""
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


def named(component: List[Module]) -> str:
    return " <-> ".join("::".join(m) or "crate" for m in component)


def test_the_no_std_crates_have_no_module_circle():
    for crate in CRATES:
        found = circles(graph_of(ROOT / crate / "src"))
        assert not found, f"{crate}: " + "; ".join(named(c) for c in found)


def test_the_check_finds_a_circle_through_use_trees_and_paths(tmp_path):
    src = tmp_path / "src"
    (src / "device").mkdir(parents=True)
    (src / "lib.rs").write_text(
        "pub mod frame;\npub mod sdo;\npub mod device;\npub use frame::{Frame, Sink};\n"
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
    edges = graph_of(src)
    assert edges[("frame",)] == {("nmt",), ("sdo",)}
    assert edges[("device", "objects")] == set()
    assert circles(edges) == [[("frame",), ("sdo",)]]
