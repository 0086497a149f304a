"""The documents a reader meets: a README read in five minutes, links that lead somewhere,
headings that say what a section holds (not who wrote it or when), and user documents that
do not send a reader to the evaluation data beside the repository, which a user does not have.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
DOCS = sorted([README, *(REPO / "docs").glob("*.md"), *(REPO / "firmware").glob("*.md")])
#: The one document for contributors, where the evaluation data's folder is named.
CONTRIBUTORS = REPO / "docs" / "contributing.md"

README_MAX_WORDS = 1000
#: A heading that is a log entry: a work session, a writer, a branch.
LOG_HEADING = re.compile(r"^#+ .*(session|\(lead|\(branch|branch [a-z]+\))")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks (a `#` there is a comment, a `[x](y)` is code)."""
    lines, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"`([^`]*)`", r"\1", heading.strip().lstrip("#").strip())
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in prose_lines(path.read_text()):
        if not line.startswith("#"):
            continue
        base = slug(line)
        count = seen.get(base, 0)
        seen[base] = count + 1
        out.add(base if count == 0 else f"{base}-{count}")
    return out


def broken_links(path: Path, root: Path = REPO) -> list[str]:
    """Links to a file that does not exist, or to a heading the document does not have."""
    broken = []
    for line in prose_lines(path.read_text()):
        for target in LINK.findall(line):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:, file:
                continue
            file_part, _, anchor = target.partition("#")
            dest = (path.parent / file_part).resolve() if file_part else path
            if not dest.exists():
                broken.append(f"{path.relative_to(root)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{path.relative_to(root)}: {target} (no such heading)")
    return broken


def test_the_readme_is_read_in_five_minutes() -> None:
    words = len(README.read_text().split())
    assert words <= README_MAX_WORDS, f"README.md has {words} words"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(path: Path) -> None:
    assert broken_links(path) == []


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_no_heading_is_a_log_entry(path: Path) -> None:
    logs = [line for line in prose_lines(path.read_text()) if LOG_HEADING.match(line)]
    assert logs == []


@pytest.mark.parametrize(
    "path", [p for p in DOCS if p != CONTRIBUTORS], ids=lambda p: str(p.relative_to(REPO))
)
def test_user_documents_do_not_name_the_evaluation_data_folder(path: Path) -> None:
    assert "../shared" not in path.read_text()


def test_the_checks_find_what_they_look_for(tmp_path: Path) -> None:
    """Each check fails on a document made to break it: none of them passes by reading
    nothing."""
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# Title\n\n## A `code` heading, here\n\n"
        "[ok](#a-code-heading-here) [gone](#nowhere) [file](missing.md) "
        "[web](https://example.org)\n\n```sh\n# a comment (branch main)\n[x](nope.md)\n```\n"
        "### Loops (lead, 2026-11-28, ninth session)\n"
    )
    assert anchors(doc) == {"title", "a-code-heading-here", "loops-lead-2026-11-28-ninth-session"}
    assert broken_links(doc, root=tmp_path) == [
        "doc.md: #nowhere (no such heading)",
        "doc.md: missing.md (no such file)",
    ]
    logs = [line for line in prose_lines(doc.read_text()) if LOG_HEADING.match(line)]
    assert logs == ["### Loops (lead, 2026-11-28, ninth session)"]
