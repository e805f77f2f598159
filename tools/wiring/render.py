"""Renders docs/wiring/handwheel.svg from docs/wiring/handwheel.yml with WireViz.

Run by `cargo xtask docs` with target/wiring-venv's Python (WireViz pinned in
tools/wiring/requirements.txt) once Graphviz's `dot` is on PATH. The SVG gets a stamp line with
the YAML's SHA-256, which `test_wiring.py` compares with the YAML in `cargo xtask test`.
"""

from __future__ import annotations

import sys

from wireviz import __version__ as wireviz_version
from wireviz.wireviz import parse

import wiring


def main() -> int:
    source = wiring.SOURCE.read_text(encoding="utf-8")
    # return_types only: WireViz writes no files of its own (no .gv, .html, BOM).
    svg = parse(wiring.SOURCE, return_types="svg")
    wiring.SVG.write_text(wiring.stamp(svg, wiring.digest(source)), encoding="utf-8")
    print(
        f"render: {wiring.SVG.relative_to(wiring.ROOT)} from "
        f"{wiring.SOURCE.relative_to(wiring.ROOT)} (WireViz {wireviz_version})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
