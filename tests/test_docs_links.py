"""Every relative link in the documentation resolves to a file or folder of the repository
(issue 34): README.md, docs/*.md and benchmarks/README.md.

Links are the Markdown ``[text](target)`` and ``![alt](target)`` forms and reference
definitions ``[label]: target``; fenced code blocks and inline code are not read.  Web
addresses (``scheme:``) and in-page anchors (``#...``) are not checked; an anchor or query after
a path is dropped before the path is checked."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "benchmarks" / "README.md"]

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.M | re.S)
CODE = re.compile(r"(`+)(?:(?!\1).)+?\1", re.S)
INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFDEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)


def relative_links(text: str) -> list[str]:
    """The relative link targets of a Markdown text, in order, without their anchors."""
    text = CODE.sub("", FENCE.sub("", text))
    out = []
    for target in INLINE.findall(text) + REFDEF.findall(text):
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"):
            continue
        path = unquote(re.split(r"[#?]", target, maxsplit=1)[0])
        if path:
            out.append(path)
    return out


def test_the_link_reader_finds_what_it_should():
    text = (
        "see [a](docs/a.md#x) and ![img](img/p.png \"title\") and [web](https://x.org) [top](#top)\n"
        "`[not](code.md)`\n```\n[not](fenced.md)\n```\n[ref]: ../b%20c.md\n"
    )
    assert relative_links(text) == ["docs/a.md", "img/p.png", "../b c.md"]


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_resolve(page):
    broken = [t for t in relative_links(page.read_text()) if not (page.parent / t).exists()]
    assert not broken, f"{page.relative_to(ROOT)}: links to nothing: {broken}"
