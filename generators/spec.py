"""Scene specs: load a TOML spec or a preset, apply overrides, validate once, type.

A scene spec (``docs/design.md``, *Scene spec*) describes one synthetic capture: the
shape, the film and its thickness profile, the substrate, the capture rig and the noise
model. :func:`load_spec` turns a preset name, a TOML file or a dictionary into a
:class:`SceneSpec`: validated once (:mod:`.spec_schema`), every key present, paths absolute,
the film as a :class:`thinfilm.core.film.Film`. Its :meth:`SceneSpec.to_toml` is what a
dataset's ``scene.toml`` holds; loading that file again gives the same spec, so the same
dataset.

More keys
---------
Keys beyond those of ``docs/design.md``, *Scene spec*:
``shape.scale``, ``shape.rotate_deg`` (x, y, z Euler angles applied in that order),
``shape.smooth`` (mesh only: smooth shading normals, default true; false gives flat faces),
``film.thickness.axis`` (linear: ``"x"`` left→right or ``"y"`` bottom→top),
``film.thickness.radius`` (radial: distance in scene units at which ``edge`` is reached;
0 means the object's silhouette radius), ``rig.passband`` (``"gaussian"`` or ``"box"``),
``rig.fill`` (fraction of the square image the object's larger extent fills),
``rig.max_depth`` (path length limit, for inter-reflections of concave meshes),
``rig.sensor`` (``"ideal"``: per-angle captures only; ``"dofp-rgb"``: also the raw image of a
colour polarization sensor, ``raw.tiff``, see :mod:`thinfilm.generators.sensor`).
``film.roughness`` (microfacet roughness of the film, the GGX alpha of the ``thinfilm``
plugin, 0 to 1; 0, the default, is a smooth film and is not written to ``scene.toml``),
``rig.spp`` (samples per pixel of a rough film: ``"auto"``, the default and not written, or
a whole number; see :func:`thinfilm.generators.generate.rough_spp`; smooth films are
rendered with one exact pixel-centre ray whatever it says).

Examples
--------
>>> spec = load_spec("hemisphere", resolution=32, seed=3)
>>> spec.shape.kind, spec.rig.resolution, spec.seed
('hemisphere', 32, 3)
>>> load_spec("hemisphere", overrides=["film.thickness.value=450"]).thickness["value"]
450.0
>>> load_spec(spec.to_dict()) == spec
True
"""

from __future__ import annotations

import copy
import json
import tomllib
import warnings
from dataclasses import dataclass
from pathlib import Path

from thinfilm.core.errors import ThinfilmWarning, UserError
from thinfilm.scenes import PRESETS, preset_file

from .spec_schema import Checker, resolve, wavelength_grid

__all__ = [
    "PRESETS",
    "apply_override",
    "SceneSpec",
    "Shape",
    "Rig",
    "Noise",
    "preset_path",
    "load_spec",
    "dump_toml",
    "wavelength_grid",
]


@dataclass(frozen=True)
class Shape:
    """``kind`` and its parameters (``radius``, ``length``, ``base``, ``height``, ``path``,
    ``scale``, ``rotate_deg``, ``smooth``, as the kind has them)."""

    kind: str
    params: dict


@dataclass(frozen=True)
class Rig:
    """The capture rig (``[rig]``)."""

    resolution: int
    wavelengths_nm: dict
    band_fwhm_nm: float
    passband: str
    polarizer_angles_deg: tuple
    camera: str
    illuminant: str
    dome_hole_deg: float
    fill: float
    max_depth: int
    sensor: str = "ideal"
    spp: object = "auto"

    @property
    def wavelengths(self):
        """Band centres (nm), a NumPy array."""
        return wavelength_grid({"wavelengths_nm": self.wavelengths_nm})


@dataclass(frozen=True)
class Noise:
    """The noise model (``[noise]``)."""

    model: str
    full_well: float
    read_noise: float
    bits: int
    exposure: object

    def as_dict(self) -> dict:
        return {"model": self.model, "full_well": self.full_well, "read_noise": self.read_noise,
                "bits": self.bits, "exposure": self.exposure}


@dataclass(frozen=True)
class SceneSpec:
    """A resolved, validated scene spec.

    Attributes
    ----------
    seed : int
    shape : :class:`Shape`
    film : :class:`thinfilm.core.film.Film` (a single film's thickness is ``None``: it
        follows ``thickness``; a stack's layers keep their nominal thicknesses, and
        ``thickness`` gives the top layer's, the others scaling with it)
    thickness : dict, the thickness profile table (``profile`` and its keys)
    rig : :class:`Rig`
    noise : :class:`Noise`
    source : where it came from (a file, a preset, with ``--set`` items), for messages
    roughness : float, ``film.roughness``: the film's microfacet roughness (GGX alpha, 0 =
        smooth); the ground truth stays the macro surface's
    """

    seed: int
    shape: Shape
    film: object
    thickness: dict
    rig: Rig
    noise: Noise
    source: str = "scene spec"
    roughness: float = 0.0

    def __eq__(self, other):
        return isinstance(other, SceneSpec) and self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash(self.to_toml())

    @classmethod
    def from_dict(cls, d: dict, source: str = "scene spec") -> "SceneSpec":
        """From a *resolved* spec dictionary (:func:`.spec_schema.resolve`)."""
        from thinfilm.core.film import Film, Layer, as_index

        film = Film.single(d["film"].get("ior", 1.0), None, d["substrate"]["ior"], d["substrate"]["k"],
                           where=source)
        if "layers" in d["film"]:
            film = Film(tuple(Layer(as_index(layer["ior"], f"{source}: 'film.layers[{i}].ior'"),
                                    layer["thickness_nm"]) for i, layer in enumerate(d["film"]["layers"])),
                        film.substrate, film.ext_ior)
        thickness = {k: v for k, v in d["film"]["thickness"].items()}
        rig = dict(d["rig"])
        rig["polarizer_angles_deg"] = tuple(rig["polarizer_angles_deg"])
        return cls(seed=d["seed"], shape=Shape(d["shape"]["kind"], {k: v for k, v in d["shape"].items() if k != "kind"}),
                   film=film, thickness=thickness, rig=Rig(**rig), noise=Noise(**d["noise"]), source=source,
                   roughness=float(d["film"].get("roughness", 0.0)))

    def to_dict(self) -> dict:
        """The resolved spec dictionary (loads back to an equal spec)."""
        from thinfilm.bsdf.materials import Constant
        from thinfilm.core.film import index_to_json

        sub = self.film.substrate
        rig = dict(self.rig.__dict__)
        rig["polarizer_angles_deg"] = list(rig["polarizer_angles_deg"])
        if rig["spp"] == "auto":  # the default, not written (specs read as before it existed)
            del rig["spp"]

        def ior(material):  # as the spec writes it: a number, "n+ki" or a material name
            value = index_to_json(material)
            return f"{value['n']!r}+{value['k']!r}i" if isinstance(value, dict) else value

        if self.film.is_single:
            film = {"ior": ior(self.film.layers[0].material)}
        else:
            film = {"layers": [{"ior": ior(layer.material), "thickness_nm": layer.thickness_nm}
                               for layer in self.film.layers]}
        if self.roughness:  # a smooth film's spec reads as it did before roughness existed
            film["roughness"] = self.roughness
        return {
            "seed": self.seed,
            "shape": {"kind": self.shape.kind, **copy.deepcopy(self.shape.params)},
            "film": {**film, "thickness": dict(self.thickness)},
            "substrate": ({"ior": float(sub.n), "k": float(sub.k)} if isinstance(sub, Constant)
                          else {"ior": ior(sub), "k": 0.0}),
            "rig": rig,
            "noise": self.noise.as_dict(),
        }

    def to_toml(self) -> str:
        """TOML text of the spec (``scene.toml``; deterministic)."""
        return dump_toml(self.to_dict())

    def replace(self, **changes) -> "SceneSpec":
        """A copy with top-level fields replaced (``seed``, ``rig`` …), e.g.
        ``spec.replace(seed=3)``."""
        from dataclasses import replace

        return replace(self, **changes)


def preset_path(name: str) -> Path:
    """Path of preset ``name``'s TOML file."""
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r}: expected one of {', '.join(PRESETS)}, "
                        f"or a path to a .toml scene spec")
    return preset_file(name)


def _read_toml(path: Path) -> dict:
    from thinfilm.core.io import read_toml

    return read_toml(path, "scene spec")


# --- overrides -----------------------------------------------------------------------------

def _parse_value(text: str):
    """A ``--set`` value: any TOML value (number, bool, list, quoted string) or a bare word."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()
    except RecursionError:
        raise UserError("the value is nested too deeply") from None


def apply_override(spec: dict, item: str) -> None:
    """Apply one ``--set KEY=VALUE`` item to a raw spec (or sweep) table in place.

    ``KEY`` is a dotted path (``film.thickness.value``), made of tables as needed; ``VALUE`` is
    read as TOML (a number, a list, an inline table), else kept as text. A relative ``path``
    (and a camera or illuminant ``.csv``) is made relative to the current folder. Setting
    ``shape.kind`` or ``film.thickness.profile`` to another value drops the old one's keys.
    A malformed item, or one that replaces a table by a value, is a one-line
    :class:`~thinfilm.core.errors.UserError` naming ``--set``.

    >>> spec = {"film": {"thickness": {"profile": "constant", "value": 300.0}}}
    >>> apply_override(spec, "film.thickness.value=450")
    >>> spec
    {'film': {'thickness': {'profile': 'constant', 'value': 450}}}
    """
    if not isinstance(item, str) or "=" not in item:
        raise UserError(f"expected KEY=VALUE, e.g. film.thickness.value=450", argument="set", value=repr(item))
    key, text = item.split("=", 1)
    parts = [p.strip() for p in key.strip().split(".")]
    if not all(parts):
        raise UserError(f"malformed key {key!r}", argument="set", value=repr(item))
    try:
        value = _parse_value(text)
    except UserError as e:
        raise UserError(e.message, argument="set", value=item if len(item) <= 60 else item[:60] + "…") from None
    node = spec
    for i, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        elif not isinstance(child, dict):
            raise UserError(f"'{'.'.join(parts[:i + 1])}' is not a table", argument="set", value=repr(item))
        node = child
    last = parts[-1]
    # A relative file named on the command line is relative to the current folder.
    if isinstance(value, str) and (last == "path" or (last in ("camera", "illuminant")
                                                      and value.lower().endswith(".csv"))):
        path = Path(value).expanduser()
        value = str(path if path.is_absolute() else Path.cwd() / path)
    # Switching the shape kind or the thickness profile drops the keys of the old one.
    if parts == ["shape", "kind"] and node.get("kind") != value:
        node.clear()
    if parts == ["film", "thickness", "profile"] and node.get("profile") != value:
        node.clear()
    if parts == ["rig", "wavelengths_nm"] or not isinstance(node.get(last), dict) or isinstance(value, dict):
        node[last] = value
    else:
        raise UserError(f"'{key}' is a table; set one of its keys instead", argument="set", value=repr(item))



# --- loading -------------------------------------------------------------------------------

def load_spec(spec_or_preset, overrides=(), resolution=None, seed=None) -> SceneSpec:
    """Load, complete and validate a scene spec.

    Parameters
    ----------
    spec_or_preset : str, Path or dict
        A preset name (``"hemisphere"``, ``"cylinder"``, ``"pyramid"``), a path to a TOML
        file, or a spec dictionary (relative paths in it are taken from the current folder).
    overrides : iterable of str
        ``"key=value"`` items (``--set``), e.g. ``"film.thickness.value=450"``; values are
        TOML values or bare words.
    resolution : int, optional
        Overrides ``rig.resolution``.
    seed : int, optional
        Overrides ``seed``.

    Returns
    -------
    SceneSpec

    Raises
    ------
    UserError
        Unknown preset or key, wrong type, negative thickness, missing mesh or bitmap file,
        resolution <= 0, and similar; one sentence naming the source and the key.

    Notes
    -----
    A film index >= the substrate index gives a :class:`~thinfilm.core.errors.ThinfilmWarning`: the paper's
    methods assume n_film < n_substrate (constructive-interference peaks; the default methods
    handle both); for a dispersive index, the indices at 550 nm. An absorbing substrate
    (``substrate.k > 0``, or a named material absorbing anywhere in 300-1000 nm, such as a
    metal) gives one too: ``spectral_s`` (S0 + sqrt(S1² + S2²)) is
    then max(R_s, R_p), which is R_s only on a dielectric substrate.
    """
    if isinstance(spec_or_preset, dict):
        raw, source, base_dir = copy.deepcopy(spec_or_preset), "scene spec", Path.cwd()
    else:
        text = str(spec_or_preset)
        path = Path(text).expanduser()
        if text in PRESETS and not path.is_file():
            path = preset_path(text)
            source = f"preset '{text}'"
        elif path.suffix.lower() == ".toml" or path.is_file() or "/" in text or "\\" in text:
            source = str(path)
        else:
            preset_path(text)  # raises "unknown preset"
        raw = _read_toml(path)
        base_dir = path.resolve().parent
    for item in overrides or ():
        apply_override(raw, item)
    if overrides:
        source = f"{source} with --set {' '.join(overrides)}"
    if resolution is not None:
        raw.setdefault("rig", {})
        if not isinstance(raw["rig"], dict):
            raise UserError(f"{source}: 'rig' must be a table")
        raw["rig"]["resolution"] = resolution
    if seed is not None:
        raw["seed"] = seed
    if isinstance(spec_or_preset, SceneSpec):
        raise TypeError("load_spec: already a SceneSpec")
    spec = SceneSpec.from_dict(resolve(raw, Checker(source, base_dir)), source)
    _warn_indices(spec)
    return spec


def _warn_indices(spec: SceneSpec) -> None:
    import numpy as np

    n_film = spec.film.effective_index()
    n_sub = spec.film.effective_substrate_index()
    if n_film >= n_sub:
        warnings.warn(f"film index {n_film:g} >= substrate index {n_sub:g}; the paper's methods assume "
                      f"n_film < n_substrate (the default methods handle both)", ThinfilmWarning, stacklevel=3)
    if spec.film.absorbing_substrate:
        sub = spec.film.substrate
        if hasattr(sub, "k"):  # a number or n+ki
            what = f"substrate k = {float(sub.k):g}"
        else:  # a material: its largest k where absorbing_substrate looks (300-1000 nm, within its table)
            lo, hi = getattr(sub, "range_nm", (300.0, 1000.0))
            lam = np.linspace(max(lo, 300.0), min(hi, 1000.0), 141)
            what = f"substrate k up to {float(np.max(spec.film.substrate_n_k(lam)[1])):g}"
        warnings.warn(f"{what} > 0 (absorbing); spectral_s = S0 + sqrt(S1² + S2²) "
                      f"then holds max(R_s, R_p), not R_s", ThinfilmWarning, stacklevel=3)


# --- writing -------------------------------------------------------------------------------

def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def dump_toml(spec: dict) -> str:
    """A resolved spec dictionary as TOML text (deterministic; :func:`load_spec` reads it back)."""
    lines = ["# thinfilm scene spec (resolved)", f"seed = {_toml_value(spec['seed'])}"]

    def table(name, body):
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in body.items():
            if not isinstance(v, dict) or k == "wavelengths_nm":
                lines.append(f"{k} = {_toml_value(v)}")

    table("shape", spec["shape"])
    table("film", spec["film"])
    table("film.thickness", spec["film"]["thickness"])
    for name in ("substrate", "rig", "noise"):
        table(name, spec[name])
    return "\n".join(lines) + "\n"
