"""Every relative link in the documentation resolves (issue 34): README.md, docs/*.md,
docs/history/*.md and benchmarks/README.md.

Links are the Markdown ``[text](target)`` and ``![alt](target)`` forms and reference
definitions ``[label]: target``; fenced code blocks and inline code are not read.  Web
addresses (``scheme:``) are not checked.  A path must name a file or folder of the repository;
an anchor (``page.md#anchor`` or an in-page ``#anchor``) must name a heading of that Markdown
page, spelt as GitHub spells heading anchors.  No documentation page is over 800 lines."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md")) + sorted((ROOT / "docs" / "history").glob("*.md"))
PAGES = [ROOT / "README.md", *DOCS, ROOT / "benchmarks" / "README.md"]
MAX_LINES = 800

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.M | re.S)
CODE = re.compile(r"(`+)(?:(?!\1).)+?\1", re.S)
INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFDEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)
HEADING = re.compile(r"^#{1,6}[ \t]+(.+?)[ \t#]*$", re.M)


def links(text: str) -> list[str]:
    """The relative link targets of a Markdown text, in order, anchors kept."""
    text = CODE.sub("", FENCE.sub("", text))
    return [t for t in INLINE.findall(text) + REFDEF.findall(text) if not re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", t)]


def relative_links(text: str) -> list[str]:
    """The relative link targets of a Markdown text, in order, without their anchors."""
    out = []
    for target in links(text):
        path = unquote(re.split(r"[#?]", target, maxsplit=1)[0])
        if path:
            out.append(path)
    return out


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: the rendered text lower-cased, punctuation dropped
    (letters, digits, ``_`` and ``-`` kept), spaces as hyphens."""
    text = re.sub(r"!?\[((?:[^\[\]]|\[[^\[\]]*\])*)\]\([^)]*\)", r"\1", heading)  # links -> their text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading anchor of a Markdown page (repeats numbered -1, -2, ... as GitHub does)."""
    seen: dict[str, int] = {}
    out = set()
    for h in HEADING.findall(FENCE.sub("", text)):
        s = slug(h)
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def test_the_link_reader_finds_what_it_should():
    text = (
        "see [a](docs/a.md#x) and ![img](img/p.png \"title\") and [web](https://x.org) [top](#top)\n"
        "`[not](code.md)`\n```\n[not](fenced.md)\n```\n[ref]: ../b%20c.md\n"
    )
    assert relative_links(text) == ["docs/a.md", "img/p.png", "../b c.md"]
    assert links(text) == ["docs/a.md#x", "img/p.png", "#top", "../b%20c.md"]


def test_anchors_are_spelt_as_github_spells_them():
    text = (
        "# Stress cases — `mpmjax stress`\n## Results, `--size ci` (raw: [x.json](../x.json))\n"
        "### Levenberg–Marquardt: the target met\n## Notes\n## Notes\n```\n# not a heading\n```\n"
    )
    assert anchors(text) == {
        "stress-cases--mpmjax-stress",
        "results---size-ci-raw-xjson",
        "levenbergmarquardt-the-target-met",
        "notes",
        "notes-1",
    }


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_resolve(page):
    text = page.read_text()
    broken = []
    for target in links(text):
        path, _, anchor = target.partition("#")
        path = unquote(path.split("?")[0])
        dest = (page.parent / path) if path else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and unquote(anchor) not in anchors(dest.read_text()):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: links to nothing: {broken}"


@pytest.mark.parametrize("page", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_no_page_is_too_long(page):
    n = len(page.read_text().splitlines())
    assert n <= MAX_LINES, f"{page.relative_to(ROOT)}: {n} lines; split it by topic (at most {MAX_LINES})"
