"""Documents cited by the repository's files are in the repository.

Every tracked text file (``git ls-files``) is scanned:

* no reference to a document outside the repository: the design and the paper summary are
  ``docs/design.md`` and ``docs/paper.md``, so a mention of either file name without that
  folder is a stale one, and so is a path into a shared folder beside the checkout or into
  the machine's work area;
* every ``docs/<file>`` path cited exists;
* every section citation, a Markdown file's path, a comma and a section title in italics
  (``docs/design.md``, *Conventions*; optionally "section" before the title), names a
  heading of that file.
"""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: text files scanned: by suffix, and every file under these folders
SUFFIXES = {".py", ".md", ".toml", ".txt", ".rst", ".cfg", ".sh", ".xml", ".json", ".yml", ".yaml", ".ini"}
FOLDERS = (".ci/",)

#: references to documents outside the repository (patterns written so that this file does
#: not match them itself)
OUTSIDE = {
    "the design or paper summary without docs/": re.compile(r"(?<!docs/)\b(?:design|paper)\.md\b", re.I),
    "a shared folder beside the checkout": re.compile(r"\.\./+shared\b"),
    "the machine's work area": re.compile(r"/wor[k]/"),
}
#: a path into docs/ (not the tail of a longer path or URL)
DOCS_PATH = re.compile(r"(?<![\w./-])docs/[\w./-]*\w")
#: a section citation: ``PATH.md`` (backquotes, a Markdown link around it allowed), a comma,
#: optionally "section", then *Title*
CITATION = re.compile(r"(?<![\w./-])((?:[\w-]+/)*[\w-]+\.md)`*(?:\]\([^)\s]*\))?,\s*(?:section\s+)?\*([^*\s][^*]*)\*")


def tracked_text_files():
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    names = [n for n in out.decode("utf-8").split("\0") if n]
    files = []
    for name in names:
        path = ROOT / name
        if not path.is_file() or not (Path(name).suffix in SUFFIXES or name.startswith(FOLDERS)):
            continue
        try:
            files.append((name, path.read_text(encoding="utf-8")))
        except UnicodeDecodeError:
            continue
    return files


FILES = tracked_text_files()


def _flat(text: str) -> str:
    """Line breaks (with the indentation and the ``#`` / ``#:`` of comments after them) as
    one space, so that a citation wrapped over two lines reads as one."""
    return re.sub(r"\s*\n[ \t]*(?:#+:?[ \t]*)?", " ", text)


def headings(path: Path) -> set:
    """The titles of a Markdown file's ATX headings (``#`` to ``######``), outside code blocks."""
    titles, fenced = set(), False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        m = None if fenced else re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            titles.add(" ".join(m.group(1).split()))
    return titles


def citations(text: str):
    for m in CITATION.finditer(_flat(text)):
        yield m.group(1), " ".join(m.group(2).split())


def test_the_scan_sees_the_files():
    names = {name for name, _ in FILES}
    assert {"README.md", "docs/design.md", "pyproject.toml", ".ci/run", "tests/test_docs_references.py"} <= names
    found = {c for _, text in FILES for c in citations(text)}
    assert ("docs/design.md", "Conventions") in found and ("docs/design.md", "Scene spec") in found


@pytest.mark.parametrize("what", sorted(OUTSIDE))
def test_no_reference_outside_the_repository(what):
    pattern = OUTSIDE[what]
    bad = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
           for name, text in FILES for m in pattern.finditer(text)]
    assert not bad, f"references to {what}: " + "; ".join(bad)


def test_cited_docs_files_exist():
    missing = sorted({f"{name}: {m.group(0)}" for name, text in FILES for m in DOCS_PATH.finditer(text)
                      if not (ROOT / m.group(0)).exists()})
    assert not missing, "cited files missing from docs/: " + "; ".join(missing)


def test_section_citations_name_existing_headings():
    cache, bad = {}, []
    for name, text in FILES:
        for doc, title in citations(text):
            path = ROOT / doc
            if not path.is_file():
                bad.append(f"{name}: {doc} (no such file)")
                continue
            if doc not in cache:
                cache[doc] = headings(path)
            if title not in cache[doc]:
                bad.append(f"{name}: {doc}, *{title}* (no such section)")
    assert not bad, "; ".join(bad)


def test_headings_of_this_scan():
    titles = headings(ROOT / "docs/design.md")
    assert {"Conventions", "Scene spec", "Dataset folder", "Estimate folder", "Evaluation output",
            "CLI contract", "Observation model", "Layers"} <= titles
    assert list(citations("see ``docs/design.md``,\n    *Dataset\n    folder* and")) == [
        ("docs/design.md", "Dataset folder")]
    assert list(citations("[`docs/design.md`](docs/design.md), section *Layers*")) == [("docs/design.md", "Layers")]
