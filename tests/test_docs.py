"""The documentation stands on its own: its relative links resolve inside the repository,
and nothing points at files outside it (the spec the project was started from)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# [text](target) or [text](target "title"); images (![alt](target)) are matched too
LINK = re.compile(r"\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
# spelt in pieces so that this file does not name what it forbids
FORBIDDEN = ("shared" + "/spec", "../" + "shared")


def _prose(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line outside fenced code blocks."""
    out, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append((number, line))
    return out


def _links(path: Path) -> list[tuple[int, str]]:
    """(line number, target) of the relative links of a Markdown file."""
    out = []
    for number, line in _prose(path.read_text(encoding="utf-8")):
        for target in LINK.findall(line):
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"):
                continue  # http(s), mailto, ...; an anchor in the same file
            out.append((number, target))
    return out


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of the headings of a Markdown file (duplicates get -1, -2, ...)."""
    seen: dict[str, int] = {}
    out = set()
    for _, line in _prose(path.read_text(encoding="utf-8")):
        m = HEADING.match(line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(2).lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc: Path) -> None:
    broken = []
    for number, target in _links(doc):
        file_part, _, anchor = target.partition("#")
        resolved = (doc.parent / file_part).resolve()
        if not resolved.exists():
            broken.append(f"{doc.name}:{number}: {target} (no such file)")
        elif not resolved.is_relative_to(ROOT):
            broken.append(f"{doc.name}:{number}: {target} (outside the repository)")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{doc.name}:{number}: {target} (no heading with that anchor)")
    assert not broken, "broken links:\n" + "\n".join(broken)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_same_file_anchors_resolve(doc: Path) -> None:
    anchors = _anchors(doc)
    broken = [f"{doc.name}:{number}: {target}"
              for number, line in _prose(doc.read_text(encoding="utf-8"))
              for target in LINK.findall(line) if target.startswith("#") and target[1:] not in anchors]
    assert not broken, "links to missing headings:\n" + "\n".join(broken)


def _repository_files() -> list[Path]:
    """Every .py and .md file git knows of or would add (tracked or new, not ignored)."""
    if shutil.which("git") and (ROOT / ".git").exists():
        names = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout.splitlines()
        files = [ROOT / n for n in names]
    else:  # a source tree without git: walk it
        files = [p for p in ROOT.rglob("*") if p.is_file()]
    skip = {".venv", "target", ".git"}
    return [p for p in files if p.suffix in (".py", ".md") and p.is_file()
            and not skip.intersection(p.relative_to(ROOT).parts)]


def test_nothing_points_outside_the_repository() -> None:
    files = _repository_files()
    assert any(p.name == "README.md" for p in files)
    hits = [f"{p.relative_to(ROOT)}:{number}: {line.strip()}"
            for p in files
            for number, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
            if any(s in line for s in FORBIDDEN)]
    assert not hits, "references to files outside the repository:\n" + "\n".join(hits)
