"""Every shell command of the README and of the documentation's pages runs as written.

The fenced ``sh``, ``bash``, ``shell`` and ``console`` blocks of ``README.md`` and
``docs/**/*.md`` are extracted (a ``console`` block's commands are its ``$ `` lines;
backslash-continued lines are joined; ``&&`` chains are split). Each page's commands run in
order, in a temporary folder that stands for a fresh clone after the set-up command:
``examples/``, ``scenes/``, ``scripts/`` and ``docs/`` of the repository and ``.venv`` (the
environment running the tests) are linked into it, and what the commands write (``data/``,
``est/``, ``eval/``, ``out/``) lands there.

At small sizes: a test may change sizes, never drop a command. ``generate`` gets
``--resolution 16`` and ``benchmark`` ``--resolution 24`` (replacing theirs; at 16 px the
spectral default fails on the roughest preset), ``benchmark`` also ``--no-figures``
(the PNG figures of each task, about 2 s each, of which the report then holds none), and
``render`` ``--spp 1``. The main job (``benchmark --quick --out out/benchmark``, minutes)
runs for the README only.

Three commands are the set-up itself and are checked instead of run: ``bash
scripts/setup.sh`` (what made this environment), ``bash scripts/test.sh`` (what runs this
test) and ``.venv/bin/pip install examples/estimator_plugin`` (which ``scripts/test.sh``
runs: the distribution must be installed). The documentation's build command is the one
``tests/test_docs_build.py`` runs (with warnings as errors), so it is checked to be that one.

Commands in ``text`` blocks are recipes that need files or machines of your own (a camera's
frames, a cluster) or long runs (the timing benchmarks), and say so where they stand.

The ``python`` blocks of the same pages run too, each in the page's folder; the one that
shows ``examples/my_estimators.py`` must be that file.
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
PAGES = [p for p in PAGES if "_build" not in p.parts]
SHELL = ("sh", "bash", "shell", "console")
SMALL = "16"
SMALL_BENCHMARK = "24"
#: set-up commands: checked, not run (see the module's docstring)
SETUP = {
    "bash scripts/setup.sh": "the set-up command",
    "bash scripts/test.sh": "the test suite",
    ".venv/bin/pip install examples/estimator_plugin": "installed by scripts/test.sh",
}
DOCS_BUILD = ".venv/bin/python -m sphinx -b html docs out/docs"
#: the main job: it needs nothing but the set-up and takes minutes, so it runs for the README
#: only; another page that shows it must show the same command
ONCE = ".venv/bin/thinfilm benchmark --quick --out out/benchmark"
LINKED = ("examples", "scenes", "scripts", "docs")


def fenced_blocks(text: str):
    """``(language, body)`` of every fenced block of a Markdown text."""
    for m in re.finditer(r"^```([\w{}-]*)[^\n]*\n(.*?)^```\s*$", text, re.S | re.M):
        yield m.group(1).strip().lower(), m.group(2)


def shell_commands(language: str, body: str) -> list[str]:
    """The commands of one shell block: comments and blank lines dropped, continued lines
    joined, ``&&`` chains split (a console block: its ``$`` lines)."""
    lines, out, current = body.splitlines(), [], ""
    for line in lines:
        if language == "console" and not current:
            if not line.startswith("$ "):
                continue  # the output shown
            line = line[2:]
        stripped = line.strip()
        if not current and (not stripped or stripped.startswith("#")):
            continue
        if stripped.endswith("\\"):
            current += stripped[:-1].rstrip() + " "
            continue
        current += stripped
        out.extend(part.strip() for part in current.split(" && "))
        current = ""
    return [c for c in out if c]


def page_commands(page: Path) -> list[str]:
    text = page.read_text(encoding="utf-8")
    return [c for lang, body in fenced_blocks(text) if lang in SHELL for c in shell_commands(lang, body)]


def page_python(page: Path) -> list[str]:
    return [body for lang, body in fenced_blocks(page.read_text(encoding="utf-8")) if lang == "python"]


def small(command: str) -> str:
    """The command at small sizes (the test's one change to it)."""
    words = shlex.split(command, comments=True)
    try:
        at = next(i for i, w in enumerate(words) if w.endswith("bin/thinfilm"))
    except StopIteration:
        return command
    sub = words[at + 1] if len(words) > at + 1 else ""
    changes = {"generate": [("--resolution", SMALL)], "benchmark": [("--resolution", SMALL_BENCHMARK), ("--no-figures", None)],
               "render": [("--spp", "1")]}.get(sub, [])
    if not changes:
        return command
    for flag, value in changes:
        if value is None:
            words += [] if flag in words else [flag]
        elif flag in words:
            words[words.index(flag) + 1] = value
        else:
            words += [flag, value]
    return shlex.join(words)


def test_the_extraction_sees_the_commands():
    readme = page_commands(ROOT / "README.md")
    assert "bash scripts/setup.sh" in readme and "bash scripts/test.sh" in readme
    assert ".venv/bin/thinfilm benchmark --quick --out out/benchmark" in readme
    assert any(c.startswith(".venv/bin/thinfilm reconstruct rgb data/cyl") for c in readme)
    assert shell_commands("console", "$ a \\\n  b\nout\n$ c && d\n") == ["a b", "c", "d"]
    assert shell_commands("sh", "# x\nthinfilm a \\\n    --b 1   # note\n\n") == ["thinfilm a --b 1   # note"]
    assert small(".venv/bin/thinfilm generate cylinder --out d --resolution 128") == \
        ".venv/bin/thinfilm generate cylinder --out d --resolution 16"
    assert small(".venv/bin/thinfilm render x.xml --out o") == ".venv/bin/thinfilm render x.xml --out o --spp 1"
    assert small("PYTHONPATH=examples .venv/bin/thinfilm benchmark --quick --out o  # c") == \
        "PYTHONPATH=examples .venv/bin/thinfilm benchmark --quick --out o --resolution 24 --no-figures"
    assert sum(len(page_commands(p)) for p in PAGES) >= 20


def test_commands_call_the_program_of_the_setup():
    """After the set-up, ``thinfilm`` is ``.venv/bin/thinfilm`` (not on PATH): no command calls
    it bare, nor Python or pip from outside the environment."""
    bad = []
    for page in PAGES:
        for command in page_commands(page):
            for word in shlex.split(command, comments=True):
                if word in ("thinfilm", "python", "python3", "pip", "dask"):
                    bad.append(f"{page.relative_to(ROOT)}: {command}")
    assert not bad, "commands that need the environment on PATH: " + "; ".join(bad)


def test_files_the_pages_name_exist():
    """Every ``examples/...`` and ``scenes/...`` path the README and the pages name (in code)
exists."""
    missing, seen = [], 0
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        code = [body for _, body in fenced_blocks(text)] + re.findall(r"`([^`\n]+)`", text)
        for m in re.finditer(r"(?<![\w./-])((?:examples|scenes)/[\w./*-]*[\w*])", "\n".join(code)):
            seen += 1
            if not any(ROOT.glob(m.group(1))):
                missing.append(f"{page.relative_to(ROOT)}: {m.group(1)}")
    assert seen >= 10 and not missing, "; ".join(missing)


def test_the_setup_commands_are_what_they_say():
    assert (ROOT / "scripts/setup.sh").is_file() and (ROOT / "scripts/test.sh").is_file()
    assert "examples/estimator_plugin" in (ROOT / "scripts/test.sh").read_text()
    importlib.metadata.distribution("thinfilm-example-estimator")  # scripts/test.sh installed it
    readme = page_commands(ROOT / "README.md")
    assert DOCS_BUILD in readme
    build_test = (ROOT / "tests/test_docs_build.py").read_text()
    assert '"-m", "sphinx"' in build_test and '"-W"' in build_test and '"html"' in build_test


def test_my_estimators_block_is_the_example_file():
    blocks = page_python(ROOT / "docs/estimators.md")
    text = (ROOT / "examples/my_estimators.py").read_text()
    assert any(block.strip() in text for block in blocks if "@estimator" in block)


def _clone(tmp_path: Path) -> Path:
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / ".venv").symlink_to(Path(sys.prefix))
    return tmp_path


def _run(command: str, cwd: Path, timeout: float = 600):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(["bash", "-euo", "pipefail", "-c", command], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
@pytest.mark.parametrize("page", [p for p in PAGES if page_commands(p) or page_python(p)],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_the_commands_of_a_page_run(page, tmp_path):
    cwd = _clone(tmp_path)
    ran = 0
    for command in page_commands(page):
        if command in SETUP or command == DOCS_BUILD:
            continue  # checked by test_the_setup_commands_are_what_they_say
        if command == ONCE and page.name != "README.md":
            assert ONCE in page_commands(ROOT / "README.md")
            continue
        done = _run(small(command), cwd)
        assert done.returncode == 0, (f"{page.relative_to(ROOT)}: `{command}` (run as `{small(command)}`) "
                                      f"exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}")
        ran += 1
    for i, block in enumerate(page_python(page)):
        script = cwd / f"block{i}.py"
        script.write_text(block)
        done = _run(shlex.join([str(Path(sys.prefix) / "bin" / "python"), script.name]), cwd)
        assert done.returncode == 0, f"{page.relative_to(ROOT)}: python block {i} failed:\n{done.stderr[-3000:]}"
        ran += 1
    assert ran > 0
