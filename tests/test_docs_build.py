"""The documentation builds with warnings as errors, and its internal links resolve.

``python -m sphinx -W --keep-going -b html docs OUT``: a warning (a broken cross-reference,
a docstring that does not parse, a page in no table of contents), a failing cell of an
executed tutorial (myst-nb raises on errors) or a generated reference that cannot be built
fails the test. The same command the README gives, with ``-W --keep-going``, into a
temporary folder.

The links of the built pages are then checked: every relative ``href`` and ``src`` of every
HTML page names a file of the build and, with a ``#fragment``, an ``id`` in that file (no
network: Sphinx's ``linkcheck`` builder also fetches external links).
"""

from __future__ import annotations

import html.parser
import os
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[1]


class _Links(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name == "id" and value:
                self.ids.add(value)
            if name in ("href", "src") and value and tag in ("a", "img", "link", "script"):
                self.links.append(value)


def _parse(path: Path) -> _Links:
    parser = _Links()
    parser.feed(path.read_text(encoding="utf-8", errors="replace"))
    return parser


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs-html")
    env = dict(os.environ, MPLBACKEND="Agg", PYDEVD_DISABLE_FILE_VALIDATION="1")
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "docs", str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    seconds = time.perf_counter() - t0
    warnings = [line for line in done.stderr.splitlines()
                if ("WARNING" in line or "ERROR" in line) and "IPKernelApp" not in line]
    assert done.returncode == 0, ("the documentation does not build without warnings:\n"
                                  + "\n".join(warnings[-60:]) + "\n" + done.stderr[-3000:])
    print(f"docs built in {seconds:.0f} s")
    return out


@pytest.mark.slow
def test_the_documentation_builds_without_warnings(built):
    for page in ("index.html", "getting-started.html", "cli.html", "scene-spec.html", "plugins.html",
                 "design.html", "api.html", "estimators.html", "benchmarks.html",
                 "tutorials/soap-bubble.html", "tutorials/make-a-dataset.html",
                 "tutorials/estimator-plugin.html", "tutorials/fit-a-spectrum.html", "tutorials/dask-sweep.html"):
        assert (built / page).is_file(), page


@pytest.mark.slow
def test_the_generated_references_hold_the_code(built):
    """The CLI page lists every option of the parser, the scene-spec page every key."""
    from thinfilm.cli import arguments, commands
    from thinfilm.generators.spec_schema import schema

    cli = (built / "cli.html").read_text(encoding="utf-8")
    for name, parser in commands():
        for action in arguments(parser):
            for flag in action.option_strings:
                assert flag in cli, f"{name} {flag} missing from the CLI reference"
    spec = (built / "scene-spec.html").read_text(encoding="utf-8")
    for table, keys in schema().items():
        for key, value in keys.items():
            for sub in (value if isinstance(value, dict) else {key: value}):
                assert f">{sub}<" in spec, f"{table}.{sub} missing from the scene-spec reference"
    methods = (built / "estimators.html").read_text(encoding="utf-8")
    assert "median_window" in methods and "coherent" in methods


@pytest.mark.slow
def test_internal_links_resolve(built):
    pages = sorted(built.rglob("*.html"))
    parsed = {p: _parse(p) for p in pages}
    broken = []
    for page, links in parsed.items():
        if "_modules" in page.relative_to(built).parts:
            continue  # viewcode's highlighted sources
        for link in links.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith(("mailto:", "javascript:", "data:")):
                continue
            target = page if not parts.path else (page.parent / unquote(parts.path)).resolve()
            if target.is_dir():
                target = target / "index.html"
            if not target.exists():
                broken.append(f"{page.relative_to(built)}: {link}")
                continue
            if parts.fragment and target.suffix == ".html":
                if target not in parsed:
                    parsed[target] = _parse(target)
                if unquote(parts.fragment) not in parsed[target].ids:
                    broken.append(f"{page.relative_to(built)}: {link} (no such anchor)")
    assert not broken, "broken internal links: " + "; ".join(broken[:40])
