"""Relative links in the repository's Markdown files, and where they lead.

A link `[text](path#anchor)` (or an image `![alt](path)`) whose destination has no scheme is
relative: `path` is a file or folder beside the linking file, and `#anchor`, when given,
names a heading of the Markdown file it leads to (or of the linking file itself, for a bare
`#anchor`) as GitHub spells heading anchors. Code blocks and code spans are not prose: links
in them are not links.

Standard library only.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Folders holding no documents of the repository (build output, caches, fuzzing data).
SKIP_DIRS = {"target", "build", "__pycache__", "corpus", "artifacts", "coverage"}

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
# `](destination)` or `](destination "title")`: the end of an inline link or image.
LINK = re.compile(r"\]\(\s*<?([^)\s>]*)>?(?:\s+\"[^\"]*\")?\s*\)")
# A reference definition: `[label]: destination`.
REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$")
SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


@dataclass(frozen=True)
class Link:
    source: Path
    line: int
    target: str


def prose_lines(text: str, blank_code: bool = True) -> list[tuple[int, str]]:
    """(line number, line) of the text outside fenced code blocks, code spans blanked unless
    `blank_code` is false."""
    result = []
    fence = None
    for number, line in enumerate(text.splitlines(), start=1):
        opened = FENCE.match(line)
        if fence is not None:
            if opened and opened[1][0] == fence[0] and len(opened[1]) >= len(fence):
                fence = None
            continue
        if opened:
            fence = opened[1]
            continue
        if blank_code:
            line = CODE_SPAN.sub(lambda m: " " * len(m[0]), line)
        result.append((number, line))
    return result


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text: links reduced to their text, lower case,
    punctuation other than `-` and `_` dropped, each space a `-`."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading).lower()
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LNM")
    return kept.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a Markdown text's headings; a repeated one gets `-1`, `-2`, ..."""
    seen: dict[str, int] = {}
    result = set()
    for _, line in prose_lines(text, blank_code=False):
        heading = HEADING.match(line)
        if not heading:
            continue
        base = slug(heading[2].replace("`", ""))
        count = seen.get(base, 0)
        seen[base] = count + 1
        result.add(base if count == 0 else f"{base}-{count}")
    return result


def links(path: Path, text: str) -> list[Link]:
    """The relative links of one Markdown file."""
    result = []
    for number, line in prose_lines(text):
        targets = LINK.findall(line)
        reference = REFERENCE.match(line)
        if reference:
            targets.append(reference[1])
        result.extend(Link(path, number, t) for t in targets if t and not SCHEME.match(t))
    return result


def broken(link: Link) -> str | None:
    """Why a relative link leads nowhere, or None when it resolves."""
    target, _, anchor = link.target.partition("#")
    where = ((link.source.parent / target) if target else link.source).resolve()
    if not where.exists():
        return f"no file {target}"
    if not anchor:
        return None
    if where.is_dir() or where.suffix.lower() != ".md":
        return f"#{anchor} into {target}, which is not a Markdown file"
    if anchor not in anchors(where.read_text(encoding="utf-8")):
        shown = where.relative_to(ROOT) if where.is_relative_to(ROOT) else where
        return f"no heading #{anchor} in {shown}"
    return None


def markdown_files(root: Path = ROOT) -> list[Path]:
    """The repository's Markdown files (no hidden folders, no build output)."""
    found = []
    for path in sorted(root.rglob("*.md")):
        parts = path.relative_to(root).parts[:-1]
        if any(p.startswith(".") or p in SKIP_DIRS or p.endswith(".egg-info") for p in parts):
            continue
        found.append(path)
    return found
