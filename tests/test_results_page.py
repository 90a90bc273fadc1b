"""docs/results.md, the current answers: its size, a command before every table, the version of every experiment's
table, and links that lead somewhere.

A table is a markdown pipe table (a row of ``|`` cells over a ``|---|`` separator) or a fenced code block of printed
output (a fenced block whose first line is not itself a command). Its command is a backtick span or a fenced block
that starts with ``python `` or ``make `` (``/usr/bin/time -v python ...`` too), anywhere in the table's section (from
the nearest heading above it) before the table. Links are resolved as GitHub does: relative to docs/, ``#anchor``
against the headings of the target (GitHub's slug: lowercase, punctuation but hyphens dropped, spaces to hyphens,
``-1``, ``-2`` ... on repeated headings).
"""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGE = DOCS / "results.md"
MAX_LINES = 850
COMMAND = re.compile(r"\s*(?:/usr/bin/time -v\s+)?(?:python|make)\s")
FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
SEPARATOR = re.compile(r"^\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")
SPAN = re.compile(r"`([^`]+)`")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def blocks(lines: list[str]) -> list[tuple[str, int, int]]:
    """The page cut into ("heading" | "prose" | "code", first line, end line) pieces, fences included in "code"."""
    pieces: list[tuple[str, int, int]] = []
    i, start = 0, 0
    while i < len(lines):
        if FENCE.match(lines[i]):
            if start < i:
                pieces.append(("prose", start, i))
            end = i + 1
            while end < len(lines) and not FENCE.match(lines[end]):
                end += 1
            pieces.append(("code", i, min(end + 1, len(lines))))
            i = start = end + 1
            continue
        if HEADING.match(lines[i]):
            if start < i:
                pieces.append(("prose", start, i))
            pieces.append(("heading", i, i + 1))
            start = i + 1
        i += 1
    if start < len(lines):
        pieces.append(("prose", start, len(lines)))
    return pieces


def _code_is_command(lines: list[str]) -> bool:
    body = [line for line in lines[1:-1] if line.strip()]
    return bool(body) and COMMAND.match(body[0]) is not None


def _prose_has_command(text: str) -> bool:
    return any(COMMAND.match(span) for span in SPAN.findall(text))


def tables_without_command(text: str) -> list[int]:
    """The first line (1-based) of every table with no command before it in its section."""
    lines = text.split("\n")
    missing: list[int] = []
    seen_command = False
    for kind, first, end in blocks(lines):
        chunk = lines[first:end]
        if kind == "heading":
            seen_command = False
        elif kind == "code":
            if _code_is_command(chunk):
                seen_command = True
            elif not seen_command:
                missing.append(first + 1)
        else:
            # a pipe table inside prose: the prose before its header row counts, the table's own cells do not
            for k in range(1, len(chunk)):
                if SEPARATOR.match(chunk[k]) and chunk[k - 1].lstrip().startswith("|"):
                    if not (seen_command or _prose_has_command("\n".join(chunk[:k - 1]))):
                        missing.append(first + k)
            seen_command = seen_command or _prose_has_command("\n".join(chunk))
    return missing


def github_slug(heading: str) -> str:
    """GitHub's anchor of a heading's text (before the -1, -2 ... of repeated headings)."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a markdown file, as GitHub numbers repeated ones (headings in code blocks left out)."""
    lines = path.read_text().split("\n")
    found: set[str] = set()
    counts: dict[str, int] = {}
    for kind, first, _ in blocks(lines):
        if kind != "heading":
            continue
        slug = github_slug(HEADING.match(lines[first]).group(2))
        n = counts.get(slug, 0)
        counts[slug] = n + 1
        found.add(slug if n == 0 else f"{slug}-{n}")
    return found


def links(text: str) -> list[str]:
    """The targets of the page's links and images, outside code blocks and inline code."""
    lines = text.split("\n")
    prose = "\n".join("\n".join(lines[first:end]) for kind, first, end in blocks(lines) if kind != "code")
    return LINK.findall(SPAN.sub("", prose))


def test_size():
    n = len(PAGE.read_text().rstrip("\n").split("\n"))
    assert n <= MAX_LINES, f"docs/results.md has {n} lines (at most {MAX_LINES}): move the history to docs/lab/"


def test_every_table_has_its_command():
    missing = tables_without_command(PAGE.read_text())
    assert not missing, f"tables with no command before them in their section, at lines {missing} of docs/results.md"


def test_every_experiment_section_names_the_version_that_made_it():
    sections = re.findall(r"<!-- experiment:(\w+):begin -->(.*?)<!-- experiment:\1:end -->", PAGE.read_text(), re.S)
    made_with = re.compile(r"^Made with sb3-emmarl \S+, git commit [0-9a-f]{12}(\+dirty)?\.$", re.M)
    unnamed = [name for name, body in sections if not made_with.search(body)]
    assert len(sections) == 10 and not unnamed, f"experiment sections without their version: {unnamed}"


def test_the_check_finds_a_table_without_a_command():
    page = "\n".join([
        "# Results", "", "## With", "", "`python zoo/compare.py -n 1`:", "", "```", "variant  team_reward", "ppo  1.0",
        "```", "", "| a | b |", "|---|---|", "| 1 | 2 |", "",
        "## Without", "", "Measured once:", "", "```", "variant  team_reward", "ppo  2.0", "```", "",
        "## A pipe table without", "", "| a | b |", "|---|---|", "| 3 | 4 |", "",
        "## A command block", "", "```", "python benchmarks/env_speed.py", "```", "", "```", "agents  rate", "```", ""])
    assert tables_without_command(page) == [20, 27]


def test_links_lead_somewhere():
    broken = []
    own = anchors(PAGE)
    for target in links(PAGE.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # http(s), mailto: not checked here
        path, _, anchor = target.partition("#")
        file = (PAGE.parent / path).resolve() if path else PAGE
        if not file.exists():
            broken.append(f"{target}: no file {file}")
        elif anchor and file.suffix == ".md" and DOCS in file.parents and anchor not in (own if not path else anchors(file)):
            broken.append(f"{target}: no heading with that anchor in {file.name}")
    assert not broken, "broken links in docs/results.md:\n" + "\n".join(broken)


def test_slug_rule():
    assert github_slug("Where knowing the mode pays a learned team: ZonePatrol") == \
        "where-knowing-the-mode-pays-a-learned-team-zonepatrol"
    assert github_slug("The zoo's PPO settings (since 0.13.0)") == "the-zoos-ppo-settings-since-0130"
    assert github_slug("VDN+EM's E-step (0.17.0)") == "vdnems-e-step-0170"
