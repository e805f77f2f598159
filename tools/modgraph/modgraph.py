"""The import graphs of the project's code have no circle: a module that uses another never
ends up used by it, directly or through others. Two readers make the graphs, one search
finds the circles.

A module and its descendants count as one: among the children of each module, a child
stands for its whole subtree, so `a::b` using `c` while `c` uses `a` is the circle
`a <-> c`, and within `a` its own children are checked the same way. A module reaching its
own ancestor or descendant is the nesting, not a circle (a child using its parent with
`super::`, a package's `__init__.py` importing its modules).

Rust, the firmware crate, the no_std crates and xtask (`CRATES`): the modules are the files
the crate root reaches through `mod name;` declarations (a module written inline in its file
counts as part of that file's). The firmware package has two roots: its library (`lib.rs`,
the board glue) and its binary (`main.rs`, the RTIC application), which reaches the library
only as the external crate `handwheel_firmware`, so each root is a graph of its own; xtask is
a binary alone. The edges are read from the sources: every `crate::`, `super::` and `self::`
path, in `use` trees (braces expanded) and in code, taken to the deepest module it names.
Unit-test modules (`#[cfg(test)]` to the end of a file, or a `#[cfg(test)]` module file) are
left out, as they are no part of the structure.

Python, every module under host/ and tools/ (`PYTHON_FOLDERS`) but the tests (`test_*.py`,
`conftest.py`, `tests/` folders) and build output: one graph, as its modules import one
another across the folders (the rig imports the host component's core, the LinuxCNC console
the rig). A module is named as it is imported: from the nearest folder above it that is no
package (no `__init__.py`), the folder its users put on the path (tools/pytest.ini, the
host's install, a script's own folder); a package's `__init__.py` is the package. The edges
are every `import` and `from ... import` in the module, those inside functions too (an
import deferred to a call still makes the two modules use each other), relative ones
resolved against the module's package, each taken to the deepest module it names; modules
from elsewhere (the standard library, installed packages) are left out."""

import ast
import re
from pathlib import Path
from typing import Dict, List, Optional, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]
# The firmware package (the workspace root), the no_std crates it is built from, and the
# project's tasks.
CRATES = [
    ".",
    "crates/canopen-slave",
    "crates/handwheel-core",
    "crates/handwheel-device",
    "xtask",
]
# The folders whose Python modules make one graph.
PYTHON_FOLDERS = ["host", "tools"]
# Folders of no module of the structure: tests, build output, caches.
PYTHON_SKIP = {"tests", "build", "target", "__pycache__"}

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


def python_name(path: Path) -> Module:
    """The dotted name `path` is imported by: its packages (the folders above it with an
    `__init__.py`) and its own name, none for a package's `__init__.py`."""
    names = [] if path.stem == "__init__" else [path.stem]
    folder = path.parent
    while (folder / "__init__.py").exists():
        names.insert(0, folder.name)
        folder = folder.parent
    return tuple(names)


def python_modules(folders: List[Path]) -> Dict[Module, Path]:
    """Each Python module under `folders` with its file, tests and build output left out."""
    found: Dict[Module, Path] = {}
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).parts[:-1]
            if any(p.startswith(".") or p in PYTHON_SKIP or p.endswith(".egg-info") for p in parts):
                continue
            if path.name.startswith("test_") or path.name == "conftest.py":
                continue
            module = python_name(path)
            # Two modules of one name would be one node of the graph.
            assert module not in found, f"{path} and {found[module]} are both {module}"
            found[module] = path
    return found


def deepest(parts: Module, known: Set[Module]) -> Module:
    """The deepest known module `parts` names; () when it names none of them."""
    target: Module = ()
    for part in parts:
        if target + (part,) not in known:
            break
        target += (part,)
    return target


def python_imports(path: Path, module: Module, known: Set[Module]) -> Set[Module]:
    """The known modules the module `module` in `path` imports."""
    package = module if path.name == "__init__.py" else module[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            named = [tuple(alias.name.split(".")) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else ()
            base += tuple(node.module.split(".")) if node.module else ()
            named = [base + (alias.name,) for alias in node.names]
        else:
            continue
        found.update(deepest(parts, known) for parts in named)
    found.discard(())
    return found


def python_graph(folders: List[Path]) -> Dict[Module, Set[Module]]:
    """Each Python module under `folders` with the modules it imports (its ancestors and
    descendants left out), under one root () that stands for the path."""
    mods = python_modules(folders)
    known = set(mods)
    edges: Dict[Module, Set[Module]] = {(): set()}
    for module, path in mods.items():
        targets = python_imports(path, module, known)
        edges[module] = {t for t in targets if not nested(module, t)}
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


def named(component: List[Module], separator: str = "::") -> str:
    return " <-> ".join(separator.join(m) or "crate" for m in component)
