"""The layers of the package (``docs/architecture.md``) and the house rules on imports, checked
on the source of every module of the project: the package folders, ``thinfilm/importers``,
the tests, benchmarks, scripts and examples.

* Each layer imports only the layers below it; ``generators`` and ``reconstruction`` never
  import each other; the importers use ``core`` and ``bsdf`` only.
* No module uses another module's underscore names (``from m import _x``, ``m._x``,
  ``getattr(m, "_x")`` and ``monkeypatch.setattr(m, "_x", ...)``).
* The project's modules import each other without cycles.

Every import counts: absolute and relative (``from . import x``, ``from ..core import y``,
resolved to module names), at module level and inside functions. An import names a module
(``import a.b``, ``from a import b`` where ``a.b`` is a module) or a name in one
(``from a import f``: module ``a``); the packages Python initializes on the way
(``a/__init__.py``) are not counted, or every package whose ``__init__`` imports its own
submodules would be a cycle. Imports by string (``importlib.import_module``) are not seen.

The checkers run on a small synthetic tree first (:func:`test_the_checkers_catch_what_they_are_for`),
so that they cannot pass by finding nothing.
"""

from __future__ import annotations

import ast
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: import name -> folder (relative to the root) of every package root of the project
PACKAGES = {
    "thinfilm": "thinfilm",
    "thinfilm.core": "core",
    "thinfilm.bsdf": "thinfilm_bsdf",
    "thinfilm.scenes": "scenes",
    "thinfilm.generators": "generators",
    "thinfilm.reconstruction": "reconstruction",
    "thinfilm_example_estimator": "examples/estimator_plugin/thinfilm_example_estimator",
}
#: folders of scripts and test files: their modules import each other by bare name
#: (pytest and ``python benchmarks/x.py`` put the folder on ``sys.path``)
SCRIPT_DIRS = ("tests", "benchmarks", "scripts", "examples")

#: module-name prefix -> layer; any other ``thinfilm.*`` module is a command (``thinfilm/``)
LAYERS = {
    "thinfilm.bsdf": "bsdf",
    "thinfilm.core": "core",
    "thinfilm.scenes": "scenes",
    "thinfilm.generators": "generators",
    "thinfilm.reconstruction": "reconstruction",
    "thinfilm.importers": "importers",
}
#: layer -> the other layers it may import. ``root`` is ``thinfilm/__init__.py`` (version,
#: start-up), which every layer may import; ``commands`` (``thinfilm/*.py``) may import all.
MAY_IMPORT = {
    "root": set(),
    "bsdf": set(),
    "scenes": set(),
    "core": {"root", "bsdf"},
    "generators": {"root", "bsdf", "core", "scenes"},
    "reconstruction": {"root", "bsdf", "core"},
    "importers": {"root", "bsdf", "core"},
    "commands": {"root", "bsdf", "core", "scenes", "generators", "reconstruction", "importers"},
}


def layer_of(name: str) -> str | None:
    """The layer of a module name; None outside the package (tests, benchmarks, examples)."""
    if name == "thinfilm":
        return "root"
    for prefix, layer in LAYERS.items():
        if name == prefix or name.startswith(prefix + "."):
            return layer
    return "commands" if name.startswith("thinfilm.") else None


# -- the scan ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Module:
    name: str  #: ``thinfilm.core.io``; ``tests:test_cli`` for a module of a script folder
    path: Path
    is_package: bool
    folder: str | None  #: the script folder, None for a package module


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    line: int


@dataclass
class Project:
    root: Path
    modules: dict = field(default_factory=dict)  #: name -> Module
    edges: list = field(default_factory=list)  #: Edge, every import of a project module
    private: list = field(default_factory=list)  #: "path:line: what", uses of underscore names
    unresolved: list = field(default_factory=list)  #: "path:line: what", imports of no module

    def where(self, name: str, line: int) -> str:
        return f"{self.modules[name].path.relative_to(self.root)}:{line}"


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def discover(root: Path, packages=PACKAGES, script_dirs=SCRIPT_DIRS) -> dict:
    """Every module of the project by name."""
    modules = {}
    for package, folder in packages.items():
        base = root / folder
        if not (base / "__init__.py").is_file():
            continue
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base)
            # only folders that are packages (an __init__.py all the way down)
            if not all((base.joinpath(*rel.parts[:i]) / "__init__.py").is_file() for i in range(1, len(rel.parts))):
                continue
            parts = list(rel.with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            name = ".".join([package, *(parts[:-1] if is_package else parts)])
            modules.setdefault(name, Module(name, path, is_package, None))
    for folder in script_dirs:
        for path in sorted((root / folder).glob("*.py")):
            name = f"{folder}:{path.stem}"
            modules[name] = Module(name, path, False, folder)
    return modules


class _Scanner:
    def __init__(self, project: Project, module: Module):
        self.p, self.m = project, module
        self.tops = {name.split(".")[0] for name in project.modules if ":" not in name}
        self.bound = {}  # local name -> module name it is bound to by an import

    def lookup(self, name: str | None) -> str | None:
        if not name:
            return None
        if self.m.folder is not None and "." not in name and f"{self.m.folder}:{name}" in self.p.modules:
            return f"{self.m.folder}:{name}"
        return name if name in self.p.modules else None

    def absolute(self, node: ast.ImportFrom) -> str | None:
        if node.level == 0:
            return node.module
        if self.m.folder is not None:
            return None  # a relative import outside a package
        parts = self.m.name.split(".")
        if not self.m.is_package:
            parts = parts[:-1]
        if node.level - 1 >= len(parts):
            return None
        parts = parts[:len(parts) - (node.level - 1)]
        return ".".join(parts + (node.module.split(".") if node.module else []))

    def edge(self, target: str, line: int):
        self.p.edges.append(Edge(self.m.name, target, line))

    def private(self, line: int, what: str):
        self.p.private.append(f"{self.p.where(self.m.name, line)}: {what}")

    def unresolved(self, line: int, name: str):
        if name.split(".")[0] in self.tops or name.startswith("."):
            self.p.unresolved.append(f"{self.p.where(self.m.name, line)}: imports {name}, no module of the project")

    def imports(self, tree):
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = self.lookup(alias.name)
                    if target is None:
                        self.unresolved(node.lineno, alias.name)
                        continue
                    self.edge(target, node.lineno)
                    if alias.asname:
                        self.bound[alias.asname] = target
                    else:
                        top = self.lookup(alias.name.split(".")[0])
                        if top:
                            self.bound[alias.name.split(".")[0]] = top
            elif isinstance(node, ast.ImportFrom):
                base = self.absolute(node)
                shown = "." * node.level + (node.module or "")
                if base is None:
                    self.unresolved(node.lineno, shown)
                    continue
                module = self.lookup(base)
                for alias in node.names:
                    sub = self.lookup(f"{base}.{alias.name}")
                    if sub is not None:
                        self.edge(sub, node.lineno)
                        self.bound[alias.asname or alias.name] = sub
                        if _private(alias.name) and self.p.modules[sub].path.parent != self.m.path.parent:
                            self.private(node.lineno, f"imports the private module {sub}")
                    elif module is not None:
                        self.edge(module, node.lineno)
                        if _private(alias.name) and module != self.m.name:
                            self.private(node.lineno, f"from {shown} import {alias.name} (a name of {module})")
                    else:
                        self.unresolved(node.lineno, f"{shown}.{alias.name}" if alias.name != "*" else shown)

    def member(self, module: str, dotted: list) -> tuple | None:
        """``(module, name)`` that ``module.a.b.name`` reaches through submodules."""
        i = 0
        while i < len(dotted) - 1 and f"{module}.{dotted[i]}" in self.p.modules:
            module = f"{module}.{dotted[i]}"
            i += 1
        return (module, dotted[i]) if i == len(dotted) - 1 else None

    def uses(self, tree):
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute):
                chain, cur = [], node
                while isinstance(cur, ast.Attribute):
                    chain.append(cur.attr)
                    cur = cur.value
                if isinstance(cur, ast.Name) and cur.id in self.bound:
                    hit = self.member(self.bound[cur.id], chain[::-1])
                    if hit and _private(hit[1]) and hit[0] != self.m.name:
                        self.private(node.lineno, f"{cur.id}.{'.'.join(chain[::-1])} (a name of {hit[0]})")
            elif isinstance(node, ast.Call) and len(node.args) >= 1:
                func = node.func
                fname = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
                if fname not in ("getattr", "setattr", "hasattr", "delattr"):
                    continue
                first, second = node.args[0], node.args[1] if len(node.args) > 1 else None
                if isinstance(first, ast.Name) and first.id in self.bound and isinstance(second, ast.Constant) \
                        and isinstance(second.value, str) and _private(second.value):
                    self.private(node.lineno, f"{fname}({first.id}, {second.value!r}) "
                                              f"(a name of {self.bound[first.id]})")
                elif isinstance(first, ast.Constant) and isinstance(first.value, str) and "." in first.value:
                    # monkeypatch.setattr("package.module.name", value)
                    head, *rest = first.value.split(".")
                    if head in self.tops and head in self.p.modules:
                        hit = self.member(head, rest)
                        if hit and _private(hit[1]):
                            self.private(node.lineno, f"{fname}({first.value!r}) (a name of {hit[0]})")


def scan(root: Path = ROOT, packages=PACKAGES, script_dirs=SCRIPT_DIRS) -> Project:
    project = Project(root, discover(root, packages, script_dirs))
    for module in project.modules.values():
        tree = ast.parse(module.path.read_text(encoding="utf-8"), filename=str(module.path))
        scanner = _Scanner(project, module)
        scanner.imports(tree)
        scanner.uses(tree)
    return project


# -- the checks -------------------------------------------------------------------------------


def layer_violations(project: Project) -> list:
    bad = []
    for e in project.edges:
        src, dst = layer_of(e.source), layer_of(e.target)
        if src is None or dst is None or src == dst:
            continue
        if dst not in MAY_IMPORT[src]:
            bad.append(f"{project.where(e.source, e.line)}: {e.source} ({src}) imports {e.target} ({dst})")
    return bad


def import_cycles(project: Project) -> list:
    """One cycle of each strongly connected group of modules, as text naming every import."""
    graph = {}
    for e in project.edges:
        if e.source != e.target:
            graph.setdefault(e.source, {}).setdefault(e.target, e.line)
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    cycles = []
    for group in groups:
        start = min(group)
        # shortest way back to start within the group (breadth first)
        came = {start: None}
        frontier, found = [start], None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph.get(v, {})):
                    if w == start:
                        found = v
                        break
                    if w in group and w not in came:
                        came[w] = v
                        nxt.append(w)
                if found is not None:
                    break
            frontier = nxt
        path = [found]
        while came[path[-1]] is not None:
            path.append(came[path[-1]])
        path = path[::-1] + [start]
        steps = [f"{a} -> {b} ({project.where(a, graph[a][b])})" for a, b in zip(path, path[1:])]
        cycles.append("cycle: " + "; ".join(steps))
    return cycles


# -- the checks, on the project ---------------------------------------------------------------


@pytest.fixture(scope="module")
def project():
    return scan()


def test_the_scan_sees_the_whole_project(project):
    """Enough modules from every folder, and the kinds of import the checks depend on."""
    names = project.modules
    assert len(names) >= 120, len(names)
    for package in PACKAGES:
        assert package in names, package
    for prefix in [*LAYERS, "thinfilm.cli", "tests:", "benchmarks:"]:
        count = sum(n.startswith(prefix) for n in names)
        assert count >= 1, prefix
    assert sum(layer_of(n) == "importers" for n in names) >= 5
    assert len(project.edges) >= 400, len(project.edges)
    edges = {(e.source, e.target) for e in project.edges}
    # relative, at module level
    assert ("thinfilm.reconstruction.rgb_coherent", "thinfilm.reconstruction.azimuth") in edges
    # relative, inside a function
    assert ("thinfilm.generators.render", "thinfilm.generators.scene") in edges
    # relative, from the command layer to another package
    assert ("thinfilm.cli", "thinfilm.core.signals") in edges
    # a test importing a helper module of its folder
    assert ("tests:test_plugin", "tests:_plugin_scenes") in edges
    # every package pyproject.toml ships is one the scan knows
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    for package in config["tool"]["setuptools"]["packages"]:
        assert package in names, package
    for package, folder in config["tool"]["setuptools"]["package-dir"].items():
        assert PACKAGES.get(package) == folder, package


def test_every_layer_has_modules(project):
    seen = {layer_of(name) for name in project.modules} - {None}
    assert seen == set(MAY_IMPORT)


def test_layers_import_only_what_they_may(project):
    bad = layer_violations(project)
    assert not bad, "\n".join(bad)


def test_generators_and_reconstruction_never_import_each_other(project):
    pairs = {("generators", "reconstruction"), ("reconstruction", "generators")}
    bad = [f"{project.where(e.source, e.line)}: {e.source} imports {e.target}" for e in project.edges
           if (layer_of(e.source), layer_of(e.target)) in pairs]
    assert not bad, "\n".join(bad)


def test_importers_use_only_core_and_bsdf(project):
    bad = [f"{project.where(e.source, e.line)}: {e.source} imports {e.target}" for e in project.edges
           if layer_of(e.source) == "importers" and layer_of(e.target) not in ("importers", "core", "bsdf", "root")]
    assert not bad, "\n".join(bad)


def test_no_module_uses_another_modules_underscore_names(project):
    assert not project.private, "\n".join(project.private)


def test_every_import_of_the_project_names_a_module(project):
    assert not project.unresolved, "\n".join(project.unresolved)


def test_no_import_cycles(project):
    cycles = import_cycles(project)
    assert not cycles, "\n".join(cycles)


# -- the checkers, on a synthetic tree ----------------------------------------------------------


def _write(root: Path, files: dict):
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def test_the_checkers_catch_what_they_are_for(tmp_path):
    _write(tmp_path, {
        "thinfilm/__init__.py": "",
        "thinfilm/cli.py": "from .core import a\nfrom .generators import shape\n",
        "core/__init__.py": "from .a import public\n",
        "core/a.py": "def public():\n    pass\n\n\ndef _hidden():\n    pass\n",
        # a cycle closed only by an import inside a function
        "core/b.py": "def f():\n    from .c import g\n    return g\n",
        "core/c.py": "from thinfilm.core.b import f\n\n\ndef g():\n    return f\n",
        "generators/__init__.py": "",
        # private names: imported, used as an attribute, patched by name
        "generators/shape.py": ("from thinfilm.core.a import _hidden\n"
                                "from thinfilm.core import a\n"
                                "import thinfilm.core.a\n\n\n"
                                "def use():\n    return a._hidden, thinfilm.core.a._hidden, a.public\n"),
        "reconstruction/__init__.py": "",
        # a relative import into the generators (and one into core, allowed)
        "reconstruction/fit.py": "from ..generators import shape\nfrom ..core.a import public\n",
        "tests/helper.py": "def _tool():\n    pass\n",
        "tests/_shared.py": "def tool():\n    pass\n",
        "tests/test_x.py": ("from helper import _tool\nfrom _shared import tool\nimport helper\n\n\n"
                            "def test_it(monkeypatch):\n"
                            "    monkeypatch.setattr(helper, '_tool', None)\n"
                            "    monkeypatch.setattr('thinfilm.core.a._hidden', None)\n"
                            "    from thinfilm.nothere import x\n"),
    })
    packages = {"thinfilm": "thinfilm", "thinfilm.core": "core", "thinfilm.generators": "generators",
                "thinfilm.reconstruction": "reconstruction"}
    project = scan(tmp_path, packages, ("tests",))
    assert set(project.modules) == {
        "thinfilm", "thinfilm.cli", "thinfilm.core", "thinfilm.core.a", "thinfilm.core.b", "thinfilm.core.c",
        "thinfilm.generators", "thinfilm.generators.shape", "thinfilm.reconstruction",
        "thinfilm.reconstruction.fit", "tests:helper", "tests:_shared", "tests:test_x"}

    assert sorted(project.private) == sorted([
        "generators/shape.py:1: from thinfilm.core.a import _hidden (a name of thinfilm.core.a)",
        "generators/shape.py:7: a._hidden (a name of thinfilm.core.a)",
        "generators/shape.py:7: thinfilm.core.a._hidden (a name of thinfilm.core.a)",
        "tests/test_x.py:1: from helper import _tool (a name of tests:helper)",
        "tests/test_x.py:7: setattr(helper, '_tool') (a name of tests:helper)",
        "tests/test_x.py:8: setattr('thinfilm.core.a._hidden') (a name of thinfilm.core.a)",
    ])
    assert project.unresolved == ["tests/test_x.py:9: imports thinfilm.nothere.x, no module of the project"]

    assert layer_violations(project) == [
        "reconstruction/fit.py:1: thinfilm.reconstruction.fit (reconstruction) imports "
        "thinfilm.generators.shape (generators)"]

    assert import_cycles(project) == [
        "cycle: thinfilm.core.b -> thinfilm.core.c (core/b.py:2); thinfilm.core.c -> thinfilm.core.b (core/c.py:1)"]

    # the same tree without its faults passes
    _write(tmp_path, {
        "core/b.py": "def f():\n    return 1\n",
        "generators/shape.py": "from thinfilm.core import a\n\n\ndef use():\n    return a.public\n",
        "reconstruction/fit.py": "from ..core.a import public\n",
        "tests/test_x.py": "from _shared import tool\n",
    })
    project = scan(tmp_path, packages, ("tests",))
    assert project.private == [] and project.unresolved == []
    assert layer_violations(project) == [] and import_cycles(project) == []
    assert ("thinfilm.reconstruction.fit", "thinfilm.core.a") in {(e.source, e.target) for e in project.edges}
