"""Every relative link in the repository's Markdown files leads to an existing file, and its
`#anchor` to a heading there (run by `cargo xtask test` and `cargo xtask docs --check`)."""

from __future__ import annotations

from pathlib import Path

import pytest

import doclinks

FILES = doclinks.markdown_files()


def test_the_documents_are_found():
    names = {p.relative_to(doclinks.ROOT).as_posix() for p in FILES}
    assert {"README.md", "docs/TESTING.md", "host/README.md"} <= names
    assert not any(n.startswith("target/") for n in names)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(doclinks.ROOT).as_posix())
def test_every_relative_link_resolves(path):
    found = doclinks.links(path, path.read_text(encoding="utf-8"))
    wrong = [
        f"line {link.line}: ({link.target}) {why}"
        for link in found
        if (why := doclinks.broken(link))
    ]
    assert not wrong, "\n".join(wrong)


def test_slugs_are_githubs():
    assert doclinks.slug("Feed record (TPDO1, 8 bytes, little-endian)") == (
        "feed-record-tpdo1-8-bytes-little-endian"
    )
    assert doclinks.slug("Velocity mode and position mode: what run-on to expect") == (
        "velocity-mode-and-position-mode-what-run-on-to-expect"
    )
    assert (
        doclinks.slug("1. Feed protocol: the paper's scheme") == "1-feed-protocol-the-papers-scheme"
    )
    assert doclinks.slug("Log (RTT, cargo embed --release)") == "log-rtt-cargo-embed---release"
    assert doclinks.slug("See [the page](x.md) now") == "see-the-page-now"


def test_repeated_headings_and_code_are_told_apart():
    text = "# A\n## Pins\n```sh\n# not a heading\n```\n### Pins\n`## no`\n"
    assert doclinks.anchors(text) == {"a", "pins", "pins-1"}
    # A code span in a heading is part of its anchor, without the backticks.
    assert doclinks.anchors("### Log (RTT, `cargo embed --release`)\n") == {
        "log-rtt-cargo-embed---release"
    }


def test_links_in_prose_only(tmp_path: Path):
    page = tmp_path / "page.md"
    text = (
        "# Top\n"
        "[ok](other.md#there) and [![pic](pic.svg)](pic.svg), [web](https://x.org/a.md)\n"
        "`[code](nowhere.md)`\n"
        "```\n[block](nowhere.md)\n```\n"
        "[self](#top) [gone](#nothing) [missing](missing.md) [dir](sub)\n"
        "[label]: other.md#elsewhere\n"
    )
    page.write_text(text)
    (tmp_path / "other.md").write_text("## There\n")
    (tmp_path / "pic.svg").write_text("<svg/>")
    (tmp_path / "sub").mkdir()
    found = doclinks.links(page, text)
    assert [(link.line, link.target) for link in found] == [
        (2, "other.md#there"),
        (2, "pic.svg"),
        (2, "pic.svg"),
        (7, "#top"),
        (7, "#nothing"),
        (7, "missing.md"),
        (7, "sub"),
        (8, "other.md#elsewhere"),
    ]
    assert [doclinks.broken(link) for link in found] == [
        None,
        None,
        None,
        None,
        f"no heading #nothing in {page}",
        "no file missing.md",
        None,
        f"no heading #elsewhere in {tmp_path / 'other.md'}",
    ]
