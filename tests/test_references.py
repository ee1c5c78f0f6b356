"""Every source the repository cites is one its readers can open.

Comments, docstrings, tests, benchmarks and pages cite public sources (an ETG document and
section, an ESC register, a file of a public project) or a page under ``docs/`` written for
this repository.  They never point at working notes outside the repository or at issue
numbers of the tracker the code was written from: a reader of the repository has neither.
Tests may read the corpus (``../shared/corpus``): that is data to test against, not a
citation.

The first test greps every file of the checkout for such pointers; the second checks that
every page and section cited inside the repository exists (``docs/protocol-notes.md §6``,
``eni-exports §3``, a Markdown link).  The last two show that both checks can fail.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from conftest import ROOT

# Pointers to documents outside the repository, and to issues.  Each pattern is written so
# that it does not match its own source text (``[s]`` and the like).
FORBIDDEN = [
    (re.compile(r"ethercat[-_]fact[s]", re.I), "the outside protocol notes"),
    (re.compile(r"\bfacts (?:shee[t]|§)", re.I), "the outside protocol notes"),
    (re.compile(r"eni[-_ ]observation[s]", re.I), "the outside ENI observation notes"),
    (re.compile(r"test[-_]benc[h]", re.I), "the outside test-machine notes"),
    (re.compile(r"ARCHITECTUR[E]\.md"), "the outside architecture notes"),
    (re.compile(r"design car[d]", re.I), "the outside design notes"),
    (re.compile(r"shared\W{0,6}doc[s]\b", re.I), "documents outside the repository"),
    (re.compile(r"\bissues?\s*(?:#|no\.?\s*)?\d+", re.I), "an issue number"),
]

# Our own pages, as files cite them: ``docs/<page>.md`` (then ``§N``), or the short form
# ``NAME §N`` that a module uses after naming the page in its docstring.
PAGES_WITH_SECTIONS = ("protocol-notes", "eni-exports")
DOCS_PAGE = re.compile(r"\bdocs/([\w-]+\.md)")
SECTION_CITE = re.compile(r"\b(" + "|".join(PAGES_WITH_SECTIONS) + r")(?:\.md)?\b([^;\n]*)")
SECTION = re.compile(r"§(\d+)(?![.\d])")
MD_LINK = re.compile(r"\]\(([\w./-]+\.md)(?:#[\w-]*)?\)")
HEADING = re.compile(r"^## (\d+)\. ", re.M)

SKIP_DIRS = {".git", "__pycache__", "build", "dist", "ecatcfg-demo"}


def repository_files(root: Path = ROOT) -> list[Path]:
    """The files of the checkout: what git tracks plus new files it does not ignore; without
    git, every file outside caches and build output."""
    try:
        out = subprocess.run(["git", "-C", str(root), "ls-files", "-z", "--cached", "--others",
                              "--exclude-standard"], capture_output=True, check=True,
                             timeout=60).stdout
        names = [n for n in out.decode().split("\0") if n]
        return sorted(root / n for n in names if (root / n).is_file())
    except (OSError, subprocess.CalledProcessError):
        return sorted(p for p in root.rglob("*") if p.is_file()
                      and not any(part in SKIP_DIRS or part.startswith(".") and part != ".ci"
                                  or part.endswith((".egg-info", "_cache"))
                                  for part in p.relative_to(root).parts))


def read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError):
        return None                         # binary files cite nothing


def forbidden_references(text: str) -> list[tuple[int, str, str]]:
    """``(line, what it points at, the line)`` for every pointer outside the repository."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for pattern, what in FORBIDDEN:
            if pattern.search(line):
                found.append((number, what, line.strip()))
    return found


def _sections(page: Path) -> set[int]:
    text = read_text(page)
    return {int(n) for n in HEADING.findall(text)} if text is not None else set()


def broken_citations(path: Path, text: str, docs: Path) -> list[tuple[int, str]]:
    """``(line, problem)`` for every cited page or section that does not exist."""
    problems = []
    for number, line in enumerate(text.splitlines(), 1):
        for name in DOCS_PAGE.findall(line):
            if not (docs / name).is_file():
                problems.append((number, f"docs/{name} does not exist"))
        for link in MD_LINK.findall(line):
            if path.suffix == ".md" and "://" not in link \
                    and not (path.parent / link).is_file():
                problems.append((number, f"link to {link}, which does not exist"))
        for page, rest in SECTION_CITE.findall(line):
            have = _sections(docs / f"{page}.md")
            for section in SECTION.findall(rest):
                if int(section) not in have:
                    problems.append((number, f"{page} §{section} does not exist"))
    return problems


def test_nothing_points_outside_the_repository():
    found = []
    for path in repository_files():
        text = read_text(path)
        if text is not None:
            found += [f"{path.relative_to(ROOT)}:{n}: {what}: {line}"
                      for n, what, line in forbidden_references(text)]
    assert not found, "cite a public source or a page under docs/ instead:\n" + \
        "\n".join(found)


def test_every_cited_page_and_section_exists():
    problems = []
    for path in repository_files():
        text = read_text(path)
        if text is not None:
            problems += [f"{path.relative_to(ROOT)}:{n}: {problem}"
                         for n, problem in broken_citations(path, text, ROOT / "docs")]
    assert not problems, "\n".join(problems)


def test_the_grep_finds_each_kind_of_outside_pointer():
    samples = ["see " + "ethercat-" + "facts.md §6", "(" + "facts " + "§5)",
               "eni-" + "observations §3", "test-" + "bench.md §4",
               "the contract in " + "ARCHITECTURE" + ".md", "layout from the design " + "card",
               "../sha" + "red/do" + "cs/x.md", 'ROOT.parent / "sha' + 'red" / "do' + 'cs"',
               "Acceptance tests (iss" + "ue 6)", "see iss" + "ue #12"]
    for sample in samples:
        assert forbidden_references("x = 1\n" + sample + "\n"), sample
    # What stays allowed: the corpus, our own pages, ETG sections, the word on its own.
    assert not forbidden_references(
        'CORPUS = ROOT.parent / "shared" / "corpus"\n'
        "docs/protocol-notes.md §6 and docs/architecture.md; ETG.1000.6 §5.6.2\n"
        "patent issues; an issue with the slave\n")


def test_a_missing_page_or_section_is_reported(tmp_path):
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "protocol-notes.md").write_text("# Notes\n\n## 1. Frames\n\n## 6. CoE\n")
    source = tmp_path / "x.py"
    ok = "# (docs/protocol-notes.md §6; ETG.1000.6 §5.6.2)\n# (protocol-notes §1, §6)\n"
    assert broken_citations(source, ok, docs) == []
    bad = "# docs/protocol-notes.md §7\n# (protocol-notes §1-§2)\n# docs/" + "nowhere.md\n"
    assert broken_citations(source, bad, docs) == [
        (1, "protocol-notes §7 does not exist"), (2, "protocol-notes §2 does not exist"),
        (3, "docs/" + "nowhere.md does not exist")]
    page = docs / "page.md"
    assert broken_citations(page, "[notes](protocol-notes.md), [x](gone.md)\n", docs) == [
        (1, "link to gone.md, which does not exist")]
