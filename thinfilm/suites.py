"""Benchmark suites: which scenes ``thinfilm benchmark`` renders, and with which methods.

A suite is a TOML file::

    name = "standard"
    description = "..."
    methods = ["coherent", "eikonal"]     # optional: default every registered method of the kinds that apply
    quick_resolution = 96                 # optional: the --quick resolution cap (default 128)

    [[scenes]]
    name = "torus-mgf2"                   # unique, used in folder names and reports
    spec = "../standard/torus_mgf2.toml"  # path relative to this suite file, or a preset name
    resolution = 96                       # optional (default: the spec's)
    quick_resolution = 64                 # optional: this scene's --quick cap (default the suite's)
    seeds = [0]                           # optional (default: [the spec's seed])
    overrides = ["noise.bits=10"]         # optional --set items
    kinds = ["rgb", "spectral"]           # optional: reconstruction kinds that apply (default both)

The shipped suites live in ``scenes/suites/`` (``thinfilm.scenes``): ``presets`` (the three
preset objects, the default of ``thinfilm benchmark``) and ``standard`` when installed.
``--suite NAME`` names one of them, ``--suite FILE.toml`` any file.

A suite expands into *cases*: one per scene and seed, each a resolved
:class:`~thinfilm.generators.spec.SceneSpec`. A case is named after its scene, with
``-s<seed>`` appended when the scene lists several seeds.

Examples
--------
>>> suite = load_suite("presets")
>>> [s.name for s in suite.scenes][:4]
['hemisphere', 'cylinder', 'pyramid', 'hemisphere-rough-0.02']
>>> [(c.id, c.spec.rig.resolution, c.kinds) for c in suite.cases(quick=True)][2]
('pyramid', 128, ('rgb',))
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from thinfilm.core.errors import UserError

__all__ = ["DEFAULT_SUITE", "QUICK_RESOLUTION", "KINDS", "SuiteScene", "Case", "Suite", "suites_dir",
           "known_suites", "suite_path", "load_suite", "parse_suite"]

DEFAULT_SUITE = "presets"
#: the largest image size of a ``--quick`` run, unless the suite sets ``quick_resolution``
QUICK_RESOLUTION = 128
KINDS = ("rgb", "spectral")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_TOP_KEYS = ("name", "description", "methods", "quick_resolution", "scenes")
_SCENE_KEYS = ("name", "spec", "resolution", "quick_resolution", "seeds", "overrides", "kinds")


@dataclass(frozen=True)
class SuiteScene:
    """One ``[[scenes]]`` entry: ``spec`` is a preset name or an absolute path."""

    name: str
    spec: str
    resolution: int | None = None
    seeds: tuple | None = None
    overrides: tuple = ()
    kinds: tuple = KINDS
    quick_resolution: int | None = None


@dataclass(frozen=True)
class Case:
    """One scene of a suite at one seed: what one dataset is generated from."""

    id: str
    scene: str
    seed: int
    spec: object  # thinfilm.generators.spec.SceneSpec
    kinds: tuple


@dataclass(frozen=True)
class Suite:
    """A loaded suite (see the module docstring)."""

    name: str
    description: str
    methods: tuple | None
    quick_resolution: int | None
    scenes: tuple
    path: Path | None = None

    def cases(self, quick: bool = False, resolution: int | None = None) -> list:
        """Every (scene, seed) as a :class:`Case` with its resolved spec.

        ``resolution`` overrides every scene's; else a scene's own ``resolution`` or its
        spec's, capped when ``quick`` by the scene's ``quick_resolution``, else the suite's
        (default :data:`QUICK_RESOLUTION`)."""
        from thinfilm.generators.spec import load_spec

        out = []
        for scene in self.scenes:
            base = load_spec(scene.spec, overrides=list(scene.overrides), resolution=scene.resolution)
            res = base.rig.resolution
            if resolution is not None:
                res = int(resolution)
            elif quick:
                res = min(res, scene.quick_resolution or self.quick_resolution or QUICK_RESOLUTION)
            seeds = scene.seeds if scene.seeds is not None else (base.seed,)
            for seed in seeds:
                spec = load_spec(scene.spec, overrides=list(scene.overrides), resolution=res, seed=seed)
                cid = scene.name if len(seeds) == 1 else f"{scene.name}-s{seed}"
                out.append(Case(cid, scene.name, int(seed), spec, scene.kinds))
        ids = [c.id for c in out]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise UserError(f"{self.path or self.name}: scene names collide with seed suffixes: {', '.join(dup)}")
        return out

    def as_dict(self) -> dict:
        """JSON-ready description (``results.json``)."""
        return {"name": self.name, "description": self.description, "path": str(self.path) if self.path else None,
                "methods": list(self.methods) if self.methods is not None else None,
                "quick_resolution": self.quick_resolution,
                "scenes": [{"name": s.name, "spec": s.spec, "resolution": s.resolution,
                            "quick_resolution": s.quick_resolution,
                            "seeds": list(s.seeds) if s.seeds is not None else None,
                            "overrides": list(s.overrides), "kinds": list(s.kinds)} for s in self.scenes]}


def suites_dir() -> Path:
    """The folder of the shipped suites (``scenes/suites`` of :mod:`thinfilm.scenes`)."""
    from importlib import resources

    return Path(str(resources.files("thinfilm.scenes") / "suites"))


def known_suites() -> list:
    """Names of the shipped suites."""
    d = suites_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d.is_dir() else []


def suite_path(name_or_file) -> Path:
    """The file of a shipped suite name, or the given path. One-line error when neither."""
    text = str(name_or_file)
    path = Path(text).expanduser()
    if path.is_file():
        return path.resolve()
    if text in known_suites():
        return suites_dir() / f"{text}.toml"
    if path.suffix.lower() == ".toml" or "/" in text or "\\" in text:
        raise UserError(f"--suite {text}: suite file not found")
    raise UserError(f"--suite {text}: unknown suite, expected one of {', '.join(known_suites())} "
                    f"or a path to a suite .toml file")


def load_suite(name_or_file) -> Suite:
    """Read and check a suite by shipped name or path (:func:`parse_suite`)."""
    from thinfilm.core.io import read_toml

    path = suite_path(name_or_file)
    return parse_suite(read_toml(path, "suite"), path)


def _fail(where, key, expected, value):
    raise UserError(f"{where}: '{key}' must be {expected}, got {value!r}")


def _int(where, key, value, minimum):
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        _fail(where, key, f"a whole number >= {minimum}", value)
    return int(value)


def _str_list(where, key, value):
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        _fail(where, key, "a list of non-empty strings", value)
    return tuple(value)


def parse_suite(data: dict, path: Path | None = None) -> Suite:
    """A :class:`Suite` from a parsed TOML table; ``path`` is the file (relative ``spec``
    paths are taken from its folder; the current folder without one)."""
    from thinfilm.scenes import PRESETS

    where = str(path) if path is not None else "suite"
    base = path.parent if path is not None else Path.cwd()
    unknown = [k for k in data if k not in _TOP_KEYS]
    if unknown:
        raise UserError(f"{where}: unknown key {unknown[0]!r}, expected some of {', '.join(_TOP_KEYS)}")
    name = data.get("name", path.stem if path is not None else "suite")
    if not isinstance(name, str) or not name:
        _fail(where, "name", "a non-empty string", name)
    description = data.get("description", "")
    if not isinstance(description, str):
        _fail(where, "description", "a string", description)
    methods = data.get("methods")
    if methods is not None:
        methods = _str_list(where, "methods", methods)
    quick = data.get("quick_resolution")
    if quick is not None:
        quick = _int(where, "quick_resolution", quick, 1)
    scenes_raw = data.get("scenes")
    if not isinstance(scenes_raw, list) or not scenes_raw or not all(isinstance(s, dict) for s in scenes_raw):
        raise UserError(f"{where}: expected at least one [[scenes]] table")
    scenes, names = [], set()
    for i, s in enumerate(scenes_raw):
        w = f"{where}: scenes[{i}]"
        unknown = [k for k in s if k not in _SCENE_KEYS]
        if unknown:
            raise UserError(f"{w}: unknown key {unknown[0]!r}, expected some of {', '.join(_SCENE_KEYS)}")
        sname = s.get("name")
        if not isinstance(sname, str) or not _NAME.match(sname):
            _fail(w, "name", "a name of letters, digits, '.', '_' or '-'", sname)
        if sname in names:
            raise UserError(f"{w}: scene name {sname!r} is used twice")
        names.add(sname)
        spec = s.get("spec")
        if not isinstance(spec, str) or not spec:
            _fail(w, "spec", "a preset name or a path to a scene spec", spec)
        p = Path(spec).expanduser()
        p = p if p.is_absolute() else base / p
        if p.is_file():
            spec = str(p.resolve())
        elif spec not in PRESETS:
            raise UserError(f"{w}: 'spec' {spec!r} is neither a file (looked for {p}) nor a preset "
                            f"({', '.join(PRESETS)})")
        res = s.get("resolution")
        if res is not None:
            res = _int(w, "resolution", res, 1)
        quick_res = s.get("quick_resolution")
        if quick_res is not None:
            quick_res = _int(w, "quick_resolution", quick_res, 1)
        seeds = s.get("seeds")
        if seeds is not None:
            if (not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds)
                    or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in seeds)):
                _fail(w, "seeds", "a list of distinct whole numbers >= 0", seeds)
            seeds = tuple(int(v) for v in seeds)
        overrides = _str_list(w, "overrides", s.get("overrides", []))
        kinds = _str_list(w, "kinds", s.get("kinds", list(KINDS)))
        bad = [k for k in kinds if k not in KINDS]
        if bad or not kinds:
            _fail(w, "kinds", f"a list of {' and '.join(KINDS)}", list(kinds))
        scenes.append(SuiteScene(sname, spec, res, seeds, overrides, tuple(k for k in KINDS if k in kinds),
                                 quick_res))
    return Suite(name, description, methods, quick, tuple(scenes), path)
