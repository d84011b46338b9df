"""Every in-repository link of the documentation resolves: the file it names, and the heading it points at.

The pages are read as GitHub renders them: a link ``[text](target)`` or image ``![alt](target)``
outside code, or a reference definition ``[ref]: target``, whose target is a path relative to the
page (``scale.md``, ``../benchmarks/results/x.png``) with an optional ``#anchor``; an anchor into
a Markdown page must be one of that page's headings as GitHub slugs them (lower case, punctuation
dropped, spaces to hyphens, ``-1``, ``-2`` for repeats). A page named in prose
(``docs/scale.md#which-python``, or ``scale.md#which-python`` beside another page) is held to the
same rule, and so is every ``docs/<page>.md`` the code names. Web links are not followed (no
network). Pages move and headings get reworded; this says which reference was left behind.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]

FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"(`+)(?:(?!\1).)+?\1")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$")
PROSE_PAGE = re.compile(r"(?<![\w/.#-])((?:docs/)?[A-Za-z0-9_-]+\.md)(?:#([A-Za-z0-9_-]+))?")
CODE_PAGE = re.compile(r"docs/[A-Za-z0-9_-]+\.md")
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
HTML_ANCHOR = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"")


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text: the rendered text (no code marks, link targets or
    emphasis), lower case, every character but letters, digits, ``-``, ``_`` and spaces dropped,
    each space a hyphen."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text, not its target
    parts = re.split(r"(`+[^`]*`+)", re.sub(r"<[^>]+>", "", text))  # code spans keep their underscores
    text = "".join(part.strip("`") if part.startswith("`") else re.sub(r"\*+|(?<!\w)_+|_+(?!\w)", "", part)
                   for part in parts)
    return "".join(ch for ch in text.strip().lower() if ch.isalnum() or ch in "-_ ").replace(" ", "-")


def prose_lines(page: Path) -> list[tuple[int, str]]:
    """The page's lines outside fenced code, inline code blanked out, with their numbers."""
    out: list[tuple[int, str]] = []
    fenced = False
    for number, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append((number, INLINE_CODE.sub(lambda m: " " * len(m.group(0)), line)))
    return out


def anchors(page: Path) -> set[str]:
    """Every anchor a page offers: its headings' slugs (repeats numbered) and HTML anchors."""
    seen: dict[str, int] = {}
    found: set[str] = set()
    fenced = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        found.update(HTML_ANCHOR.findall(line))
        m = HEADING.match(line)
        if m:
            base = slug(m.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f"{base}-{count}")
    return found


def targets(page: Path) -> list[tuple[int, str]]:
    """(line, target) of every link, image and reference definition of the page, and every page
    with an anchor named in its prose."""
    out: list[tuple[int, str]] = []
    for number, line in prose_lines(page):
        links = [m.group(1) for m in LINK.finditer(line)]
        out.extend((number, t) for t in links)
        m = REFERENCE.match(line)
        if m:
            out.append((number, m.group(1)))
        bare = LINK.sub(" ", line)  # the prose around the links
        for m in PROSE_PAGE.finditer(bare):  # "docs/x.md", "x.md#anchor", "docs/x.md#anchor"
            if m.group(2):
                out.append((number, f"{m.group(1)}#{m.group(2)}"))
            elif m.group(1).startswith("docs/"):
                out.append((number, m.group(1)))
    return out


def problem(page: Path, target: str) -> str | None:
    """Why ``target`` (as written in ``page``) does not resolve, or None when it does."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto: ...
        return None
    path, _, anchor = target.partition("#")
    if not path:
        dest = page
    elif path.startswith("docs/") and not (page.parent / path).exists():
        dest = ROOT / path  # "docs/<page>.md" in prose: the repository's docs folder
    else:
        dest = (page.parent / path).resolve()
    if not dest.exists():
        return f"{target}: no such file"
    if anchor and dest.suffix == ".md" and anchor not in anchors(dest):
        return f"{target}: no heading with that anchor"
    return None


def broken(page: Path) -> list[str]:
    return [f"{page.relative_to(ROOT)}:{number}: {why}"
            for number, target in targets(page) if (why := problem(page, target)) is not None]


def test_slugs_follow_githubs_rule() -> None:
    assert slug("Scale: CPU, memory, RTF and pose age per virtual UAV (`benchmarks/scale.py`)") == (
        "scale-cpu-memory-rtf-and-pose-age-per-virtual-uav-benchmarksscalepy")
    assert slug("Huge pages at N = 50: today's code, 2 cores") == "huge-pages-at-n--50-todays-code-2-cores"
    assert slug("What a UAV's tick costs (`MRSWARM_TICK_METER`)") == "what-a-uavs-tick-costs-mrswarm_tick_meter"
    assert slug("The [netem](netem.md) shim, **fast**") == "the-netem-shim-fast"
    assert slug("Poses into the table (`swarmnet/_intake.c`), _fast_") == "poses-into-the-table-swarmnet_intakec-fast"


def test_a_broken_link_and_a_stale_anchor_are_reported(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    (tmp_path / "other.md").write_text("# Other\n\n## A section\n", encoding="utf-8")
    page.write_text("# Page\n\n[ok](other.md#a-section) [gone](missing.md) [stale](other.md#old-name)\n"
                    "[self](#page) and other.md#a-section in prose, `code.md#ignored`, docs/none.md\n\n"
                    "```\n[in code](nowhere.md)\n```\n", encoding="utf-8")
    found = [why for _, t in targets(page) if (why := problem(page, t)) is not None]
    assert found == ["missing.md: no such file", "other.md#old-name: no heading with that anchor",
                     "docs/none.md: no such file"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_of_the_page_resolves(page: Path) -> None:
    assert broken(page) == []


def test_every_docs_page_the_code_names_exists() -> None:
    missing = []
    for source in sorted(ROOT.glob("*/**/*.py")) + sorted(ROOT.glob("*/**/*.c")):
        if ".venv" in source.parts or "build" in source.parts or source == Path(__file__).resolve():
            continue
        for number, line in enumerate(source.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            missing += [f"{source.relative_to(ROOT)}:{number}: {m}" for m in CODE_PAGE.findall(line)
                        if not (ROOT / m).exists()]
    assert missing == []
