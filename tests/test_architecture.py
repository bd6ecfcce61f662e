"""The layers of the package (README, *Architecture*): who may import whom, checked on the
source of every module (imports at any depth, inside functions too)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: folder -> import names of the project it may use (besides itself)
ALLOWED = {
    "thinfilm_bsdf": set(),
    "core": {"thinfilm.bsdf", "thinfilm"},
    "generators": {"thinfilm.bsdf", "thinfilm.core", "thinfilm.scenes", "thinfilm"},
    "reconstruction": {"thinfilm.bsdf", "thinfilm.core", "thinfilm"},
}
SELF = {"thinfilm_bsdf": "thinfilm.bsdf", "core": "thinfilm.core", "generators": "thinfilm.generators",
        "reconstruction": "thinfilm.reconstruction"}


def _project_imports(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            if name == "thinfilm" or name.startswith("thinfilm."):
                yield node.lineno, name


def _layer(name: str) -> str:
    parts = name.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else name


@pytest.mark.parametrize("folder", sorted(ALLOWED))
def test_layers_import_only_what_they_may(folder):
    bad = []
    for path in sorted((ROOT / folder).glob("*.py")):
        for line, name in _project_imports(path):
            layer = _layer(name)
            if layer != SELF[folder] and layer not in ALLOWED[folder]:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not bad, "\n".join(bad)


def test_generators_and_reconstruction_never_import_each_other():
    for folder, other in (("generators", "thinfilm.reconstruction"), ("reconstruction", "thinfilm.generators")):
        for path in (ROOT / folder).glob("*.py"):
            assert not [n for _, n in _project_imports(path) if n.startswith(other)], path
