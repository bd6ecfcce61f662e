"""Scene specs: load a TOML spec or a preset, apply overrides, fill defaults, validate.

A scene spec (``DESIGN.md``, section *Scene spec*) describes one synthetic capture: the
shape, the film and its thickness profile, the substrate, the capture rig and the noise
model. :func:`load_spec` turns a preset name, a TOML file or a dictionary into a *resolved*
spec: every key present, every value of the right type, paths absolute. The resolved spec
is what a dataset's ``scene.toml`` holds (:func:`dump_toml`); loading that file again gives
the same resolved spec, so the same dataset.

Keys beyond ``DESIGN.md``
-------------------------
``shape.scale``, ``shape.rotate_deg`` (x, y, z Euler angles applied in that order),
``shape.smooth`` (mesh only: smooth shading normals, default true; false gives flat faces),
``film.thickness.axis`` (linear: ``"x"`` left→right or ``"y"`` bottom→top),
``film.thickness.radius`` (radial: distance in scene units at which ``edge`` is reached;
0 means the object's silhouette radius), ``rig.passband`` (``"gaussian"`` or ``"box"``),
``rig.fill`` (fraction of the square image the object's larger extent fills),
``rig.max_depth`` (path length limit, for inter-reflections of concave meshes).

Bad input raises :class:`~thinfilm.errors.UserError` with one sentence naming the source
(file, preset or ``--set``), the key and what was expected.

Examples
--------
>>> spec = load_spec("hemisphere", resolution=32, seed=3)
>>> spec["shape"]["kind"], spec["rig"]["resolution"], spec["seed"]
('hemisphere', 32, 3)
>>> load_spec("hemisphere", overrides=["film.thickness.value=450"])["film"]["thickness"]["value"]
450.0
"""

from __future__ import annotations

import copy
import json
import math
import sys
import tomllib
from importlib import resources
from pathlib import Path

from thinfilm.errors import UserError

__all__ = [
    "PRESETS",
    "preset_names",
    "preset_path",
    "load_spec",
    "dump_toml",
    "wavelength_grid",
]

#: Presets shipped in ``scenes/`` (package ``thinfilm.scenes``).
PRESETS = ("hemisphere", "cylinder", "pyramid")

# --- the schema ----------------------------------------------------------------------------
# Each key maps to (checker name, default). A default of _REQUIRED must be given by the user.
_REQUIRED = object()

_SHAPE_KEYS = {
    "hemisphere": {"radius": ("positive", 1.0)},
    "cylinder": {"radius": ("positive", 1.0), "length": ("positive", 2.0)},
    "pyramid": {"base": ("positive", 2.0), "height": ("positive", 0.6)},
    "mesh": {"path": ("file", _REQUIRED), "scale": ("positive", 1.0),
             "rotate_deg": ("vec3", [0.0, 0.0, 0.0]), "smooth": ("bool", True)},
}

_PROFILE_KEYS = {
    "uniform": {"value": ("thickness", 400.0)},
    "linear": {"start": ("thickness", 420.0), "end": ("thickness", 560.0), "axis": ("axis", "x")},
    "radial": {"center": ("thickness", 690.0), "edge": ("thickness", 400.0),
               "radius": ("nonnegative", 0.0)},
    "bitmap": {"path": ("file", _REQUIRED)},
}

_FILM_KEYS = {"ior": ("ior", 1.37)}
_SUBSTRATE_KEYS = {"ior": ("positive", 1.6), "k": ("nonnegative", 0.0)}
_RIG_KEYS = {
    "resolution": ("resolution", 256),
    "wavelengths_nm": ("wavelengths", {"start": 400.0, "stop": 720.0, "step": 4.0}),
    "band_fwhm_nm": ("nonnegative", 4.0),
    "passband": ("passband", "gaussian"),
    "polarizer_angles_deg": ("angles", [0, 45, 90, 135]),
    "camera": ("camera", "Nikon 5100 (NPL)"),
    "illuminant": ("illuminant", "D65"),
    "dome_hole_deg": ("hole", 0.0),
    "fill": ("fill", 0.9),
    "max_depth": ("depth", 6),
}
_NOISE_KEYS = {
    "model": ("noise_model", "camera"),
    "full_well": ("positive", 10000.0),
    "read_noise": ("nonnegative", 5.0),
    "bits": ("bits", 12),
    "exposure": ("exposure", "auto"),
}
_TOP_KEYS = ("seed", "shape", "film", "substrate", "rig", "noise")


# --- presets -------------------------------------------------------------------------------

def preset_names() -> list:
    """Names of the presets shipped in ``scenes/``."""
    return list(PRESETS)


def preset_path(name: str) -> Path:
    """Path of preset ``name``'s TOML file."""
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r}: expected one of {', '.join(PRESETS)}, "
                        f"or a path to a .toml scene spec")
    return Path(str(resources.files("thinfilm.scenes") / f"{name}.toml"))


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise UserError(f"{path}: scene spec not found")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{path}: not valid TOML ({e})") from None
    except UnicodeDecodeError:
        raise UserError(f"{path}: not a UTF-8 text file") from None


# --- overrides -----------------------------------------------------------------------------

def _parse_value(text: str):
    """A ``--set`` value: any TOML value (number, bool, list, quoted string) or a bare word."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def _apply_override(spec: dict, item: str) -> None:
    if not isinstance(item, str) or "=" not in item:
        raise UserError(f"--set {item!r}: expected KEY=VALUE, e.g. film.thickness.value=450")
    key, text = item.split("=", 1)
    parts = [p.strip() for p in key.strip().split(".")]
    if not all(parts):
        raise UserError(f"--set {item!r}: malformed key {key!r}")
    value = _parse_value(text)
    node = spec
    for i, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        elif not isinstance(child, dict):
            raise UserError(f"--set {item!r}: '{'.'.join(parts[:i + 1])}' is not a table")
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
        raise UserError(f"--set {item!r}: '{key}' is a table; set one of its keys instead")


# --- checkers ------------------------------------------------------------------------------

class _Checker:
    def __init__(self, source: str, base_dir: Path | None):
        self.source = source
        self.base_dir = base_dir

    def fail(self, where: str, expected: str, value) -> None:
        raise UserError(f"{self.source}: '{where}' must be {expected}, got {_show(value)}")

    def number(self, where, value):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(where, "a number", value)
        return float(value)

    def integer(self, where, value):
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            self.fail(where, "a whole number", value)
        return int(value)

    def check(self, kind: str, where: str, value):
        if kind == "positive":
            v = self.number(where, value)
            if v <= 0:
                self.fail(where, "a number > 0", value)
            return v
        if kind == "nonnegative":
            v = self.number(where, value)
            if v < 0:
                self.fail(where, "a number >= 0", value)
            return v
        if kind == "thickness":
            v = self.number(where, value)
            if v < 0:
                self.fail(where, "a film thickness in nm >= 0", value)
            return v
        if kind == "resolution":
            v = self.integer(where, value)
            if v <= 0:
                self.fail(where, "a whole number of pixels > 0", value)
            return v
        if kind == "depth":
            v = self.integer(where, value)
            if v < 2:
                self.fail(where, "a whole number >= 2", value)
            return v
        if kind == "bits":
            v = self.integer(where, value)
            if not 1 <= v <= 24:
                self.fail(where, "a whole number of bits from 1 to 24", value)
            return v
        if kind == "bool":
            if not isinstance(value, bool):
                self.fail(where, "true or false", value)
            return value
        if kind == "vec3":
            if not isinstance(value, list) or len(value) != 3:
                self.fail(where, "a list of 3 numbers", value)
            return [self.number(where, v) for v in value]
        if kind == "axis":
            if value not in ("x", "y"):
                self.fail(where, "\"x\" or \"y\"", value)
            return value
        if kind == "passband":
            if value not in ("gaussian", "box"):
                self.fail(where, "\"gaussian\" or \"box\"", value)
            return value
        if kind == "noise_model":
            if value not in ("none", "camera"):
                self.fail(where, "\"none\" or \"camera\"", value)
            return value
        if kind == "exposure":
            if value == "auto":
                return value
            if isinstance(value, str):
                self.fail(where, "\"auto\" or a number of electrons per unit reflectance > 0", value)
            v = self.number(where, value)
            if v <= 0:
                self.fail(where, "\"auto\" or a number of electrons per unit reflectance > 0", value)
            return v
        if kind == "hole":
            v = self.number(where, value)
            if not 0 <= v < 90:
                self.fail(where, "an angle in degrees from 0 to below 90", value)
            return v
        if kind == "fill":
            v = self.number(where, value)
            if not 0 < v <= 1:
                self.fail(where, "a fraction in (0, 1]", value)
            return v
        if kind == "file":
            if not isinstance(value, str) or not value:
                self.fail(where, "a file path", value)
            path = Path(value).expanduser()
            if not path.is_absolute() and self.base_dir is not None:
                path = self.base_dir / path
            path = path.resolve()
            if not path.is_file():
                raise UserError(f"{self.source}: '{where}' names a file that does not exist: {path}")
            return str(path)
        if kind == "ior":
            if isinstance(value, str):
                from thinfilm.bsdf import material_names

                if value not in material_names():
                    self.fail(where, f"a number or one of {', '.join(material_names())}", value)
                return value
            v = self.number(where, value)
            if v <= 0:
                self.fail(where, "a refractive index > 0 or a material name", value)
            return v
        if kind == "angles":
            if not isinstance(value, list) or not value:
                self.fail(where, "a list of polarizer angles in degrees", value)
            angles = [self.number(where, a) for a in value]
            layers = [int(round(a)) % 360 for a in angles]
            if any(abs(a - round(a)) > 1e-9 for a in angles) or len(set(layers)) != len(layers):
                self.fail(where, "distinct whole-degree polarizer angles", value)
            # The angles must determine S0, S1, S2 (rank 3 in cos 2a, sin 2a).
            import numpy as np

            a = np.radians(angles)
            design = np.stack([np.ones_like(a), np.cos(2 * a), np.sin(2 * a)], axis=-1)
            if np.linalg.matrix_rank(design, tol=1e-6) < 3:
                self.fail(where, "at least 3 angles that differ modulo 180 degrees", value)
            return [int(round(x)) for x in angles]
        if kind == "wavelengths":
            if not isinstance(value, dict) or set(value) != {"start", "stop", "step"}:
                self.fail(where, "a table { start = ..., stop = ..., step = ... } in nm", value)
            start = self.check("positive", f"{where}.start", value["start"])
            stop = self.check("positive", f"{where}.stop", value["stop"])
            step = self.check("positive", f"{where}.step", value["step"])
            if stop <= start or (stop - start) / step < 1 - 1e-9:
                raise UserError(f"{self.source}: '{where}' must hold at least 2 bands "
                                f"(start < stop, step <= stop - start), got {_show(value)}")
            if (stop - start) / step > 10000:
                raise UserError(f"{self.source}: '{where}' gives more than 10000 bands")
            return {"start": start, "stop": stop, "step": step}
        if kind == "camera":
            return self._colour_name(where, value, "camera")
        if kind == "illuminant":
            return self._colour_name(where, value, "illuminant")
        raise AssertionError(kind)

    def _colour_name(self, where, value, what):
        if not isinstance(value, str) or not value:
            self.fail(where, f"a {what} name or a CSV path", value)
        if value.lower().endswith(".csv"):
            return self.check("file", where, value)
        return value

    def table(self, where: str, value, schema: dict, fixed: dict) -> dict:
        """Check table ``value`` against ``schema`` (key → (checker, default)); ``fixed`` are
        keys already checked (like ``kind``) that are kept first."""
        if not isinstance(value, dict):
            self.fail(where, "a table", value)
        allowed = set(schema) | set(fixed)
        for key in value:
            if key not in allowed:
                raise UserError(f"{self.source}: unknown key '{where}.{key}' "
                                f"(expected one of {', '.join(sorted(allowed))})")
        out = dict(fixed)
        for key, (kind, default) in schema.items():
            if key in value:
                out[key] = self.check(kind, f"{where}.{key}", value[key])
            elif default is _REQUIRED:
                raise UserError(f"{self.source}: missing key '{where}.{key}'")
            else:
                out[key] = copy.deepcopy(default)
        return out


def _show(value) -> str:
    if isinstance(value, str):
        return repr(value)
    try:
        return json.dumps(value)
    except TypeError:
        return repr(value)


# --- loading -------------------------------------------------------------------------------

def load_spec(spec_or_preset, overrides=(), resolution=None, seed=None) -> dict:
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
    dict
        The resolved spec: every key present, paths absolute.

    Raises
    ------
    UserError
        Unknown preset or key, wrong type, negative thickness, missing mesh or bitmap file,
        resolution <= 0, and similar; one sentence naming the source and the key.

    Notes
    -----
    A film index >= the substrate index prints a one-line warning on stderr: the spectral
    method assumes n_film < n_substrate (constructive-interference peaks). An absorbing
    substrate (``substrate.k > 0``) prints one too: ``spectral_s`` (S0 + sqrt(S1² + S2²)) is
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
        _apply_override(raw, item)
    if overrides:
        source = f"{source} with --set {' '.join(overrides)}"
    if resolution is not None:
        raw.setdefault("rig", {})
        if not isinstance(raw["rig"], dict):
            raise UserError(f"{source}: 'rig' must be a table")
        raw["rig"]["resolution"] = resolution
    if seed is not None:
        raw["seed"] = seed
    spec = _resolve(raw, _Checker(source, base_dir))
    _warn_indices(spec)
    return spec


def _resolve(raw: dict, c: _Checker) -> dict:
    for key in raw:
        if key not in _TOP_KEYS:
            raise UserError(f"{c.source}: unknown key '{key}' (expected one of {', '.join(_TOP_KEYS)})")
    out = {}
    out["seed"] = c.integer("seed", raw.get("seed", 0))
    if out["seed"] < 0:
        c.fail("seed", "a whole number >= 0", out["seed"])

    shape = raw.get("shape", {"kind": "hemisphere"})
    if not isinstance(shape, dict):
        c.fail("shape", "a table", shape)
    kind = shape.get("kind", "hemisphere")
    if kind not in _SHAPE_KEYS:
        c.fail("shape.kind", f"one of {', '.join(_SHAPE_KEYS)}", kind)
    out["shape"] = c.table("shape", shape, _SHAPE_KEYS[kind], {"kind": kind})

    film = raw.get("film", {})
    if not isinstance(film, dict):
        c.fail("film", "a table", film)
    thickness = film.get("thickness", {"profile": "uniform"})
    if isinstance(thickness, (int, float)) and not isinstance(thickness, bool):
        thickness = {"profile": "uniform", "value": thickness}
    if not isinstance(thickness, dict):
        c.fail("film.thickness", "a table or a number of nm", thickness)
    profile = thickness.get("profile", "uniform")
    if profile not in _PROFILE_KEYS:
        c.fail("film.thickness.profile", f"one of {', '.join(_PROFILE_KEYS)}", profile)
    film_rest = {k: v for k, v in film.items() if k != "thickness"}
    out["film"] = c.table("film", film_rest, _FILM_KEYS, {})
    out["film"]["thickness"] = c.table("film.thickness", thickness, _PROFILE_KEYS[profile],
                                       {"profile": profile})

    out["substrate"] = c.table("substrate", raw.get("substrate", {}), _SUBSTRATE_KEYS, {})
    out["rig"] = c.table("rig", raw.get("rig", {}), _RIG_KEYS, {})
    out["noise"] = c.table("noise", raw.get("noise", {}), _NOISE_KEYS, {})
    _check_rig_colour(out["rig"], c)
    return out


def _check_rig_colour(rig: dict, c: _Checker) -> None:
    """Camera and illuminant must be known and give signal over the bands."""
    from thinfilm.colorimetry import camera_weights

    try:
        camera_weights(wavelength_grid(rig), rig["camera"], rig["illuminant"])
    except UserError as e:
        raise UserError(f"{c.source}: rig: {e}") from None


def _film_index_550(film_ior) -> float:
    if isinstance(film_ior, str):
        from thinfilm.bsdf import as_dispersion

        return float(as_dispersion(film_ior)(550.0))
    return float(film_ior)


def _warn_indices(spec: dict) -> None:
    n_film = _film_index_550(spec["film"]["ior"])
    n_sub = spec["substrate"]["ior"]
    if n_film >= n_sub:
        print(f"thinfilm: warning: film index {n_film:g} >= substrate index {n_sub:g}; the spectral "
              f"reconstruction assumes n_film < n_substrate", file=sys.stderr)
    k_sub = spec["substrate"]["k"]
    if k_sub > 0:
        print(f"thinfilm: warning: substrate k = {k_sub:g} > 0 (absorbing); spectral_s = S0 + sqrt(S1² + S2²) "
              f"then holds max(R_s, R_p), not R_s", file=sys.stderr)


def wavelength_grid(rig: dict):
    """Band centres (nm) of a resolved rig: ``start, start + step, …`` up to ``stop``."""
    import numpy as np

    w = rig["wavelengths_nm"]
    count = int(math.floor((w["stop"] - w["start"]) / w["step"] + 1e-9)) + 1
    return w["start"] + w["step"] * np.arange(count, dtype=np.float64)


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
    """A resolved spec as TOML text (deterministic; :func:`load_spec` reads it back)."""
    lines = [f"# thinfilm scene spec (resolved)", f"seed = {_toml_value(spec['seed'])}"]

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
