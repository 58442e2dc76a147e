"""Every relative link in the Markdown docs points at a file that exists and, after a
``#``, at a heading that file has (GitHub's anchors): a moved section breaks no link."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")
SKIP = ("http://", "https://", "mailto:")


def markdown_files() -> list[Path]:
    return sorted(p for p in ROOT.rglob("*.md") if not any(part.startswith(".") or part in ("runs", "node_modules") for part in p.relative_to(ROOT).parts))


def anchors(text: str) -> set[str]:
    """The anchors GitHub gives the headings of a Markdown text (repeats get -1, -2, ...)."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    in_code = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            in_code = not in_code
            continue
        m = None if in_code else HEADING.match(line)
        if m is None:
            continue
        title = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", m.group(1))  # a link's text stays, its target goes
        slug = re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def broken_links(path: Path, root: Path = ROOT) -> list[str]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # code blocks hold no links
    bad = []
    for target in LINK.findall(text):
        if target.startswith(SKIP):
            continue
        file_part, _, anchor = target.partition("#")
        dest = path if not file_part else (path.parent / file_part).resolve()
        if not dest.exists():
            bad.append(f"{path.relative_to(root)}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text(encoding="utf-8")):
            bad.append(f"{path.relative_to(root)}: {target} (no such heading)")
    return bad


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path: Path) -> None:
    assert broken_links(path) == []


def test_the_check_finds_a_missing_file_and_a_missing_heading(tmp_path: Path) -> None:
    (tmp_path / "b.md").write_text("# Some `code` title (2026-12-03)\n## Again\n## Again\n")
    page = tmp_path / "a.md"
    page.write_text("[ok](b.md#some-code-title-2026-12-03) [ok](b.md#again-1) [x](c.md) [y](b.md#nope) [z](https://x.org/#q)\n")
    assert broken_links(page, tmp_path) == ["a.md: c.md (no such file)", "a.md: b.md#nope (no such heading)"]
