"""The scene-spec schema: every key, its checker and its default, and the validation.

:func:`resolve` turns a raw spec (a parsed TOML table with overrides applied) into the
*resolved* spec dictionary: every key present, every value of the right type, paths
absolute. :mod:`thinfilm.generators.spec` wraps the result in a typed
:class:`~thinfilm.generators.spec.SceneSpec`.

Bad input raises :class:`~thinfilm.core.errors.UserError` with one sentence naming the source
(file, preset or ``--set``), the key and what was expected.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

from thinfilm.core.errors import UserError

__all__ = ["SHAPE_KINDS", "PROFILES", "Checker", "resolve", "wavelength_grid"]

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

#: ``roughness``: the film's microfacet roughness, the GGX alpha of the ``thinfilm`` plugin
#: (0 = smooth); a spec writes it only when > 0, so smooth specs read as before
_FILM_KEYS = {"ior": ("ior", 1.37), "roughness": ("roughness", 0.0)}
#: a stack instead of one film: ``layers = [{ ior = ..., thickness_nm = ... }, ...]`` from the
#: exterior down (then ``film.thickness`` gives the top layer's thickness and the others scale
#: with it)
_STACK_KEYS = {"layers": ("layers", _REQUIRED), "roughness": ("roughness", 0.0)}
_LAYER_KEYS = {"ior": ("ior", _REQUIRED), "thickness_nm": ("positive", _REQUIRED)}
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
    "sensor": ("sensor", "ideal"),
    # samples per pixel of a rough film ("auto": generate.rough_spp); not written when "auto"
    "spp": ("spp", "auto"),
}
_NOISE_KEYS = {
    "model": ("noise_model", "camera"),
    "full_well": ("positive", 10000.0),
    "read_noise": ("nonnegative", 5.0),
    "bits": ("bits", 12),
    "exposure": ("exposure", "auto"),
}
_TOP_KEYS = ("seed", "shape", "film", "substrate", "rig", "noise")


# --- checkers ------------------------------------------------------------------------------

class Checker:
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
        if kind == "sensor":
            if value not in ("ideal", "dofp-rgb"):
                self.fail(where, "\"ideal\" or \"dofp-rgb\"", value)
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
        if kind == "spp":
            if value == "auto":
                return value
            if isinstance(value, str):
                self.fail(where, "\"auto\" or a whole number of samples per pixel from 1 to 4096", value)
            v = self.integer(where, value)
            if not 1 <= v <= 4096:
                self.fail(where, "\"auto\" or a whole number of samples per pixel from 1 to 4096", value)
            return v
        if kind == "roughness":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
                self.fail(where, "a microfacet roughness (GGX alpha) from 0 (smooth) to 1", value)
            return float(value)
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
        if kind == "layers":
            if not isinstance(value, list) or not value or len(value) > 200:
                self.fail(where, "a list of 1 to 200 layer tables { ior = ..., thickness_nm = ... }", value)
            return [self.table(f"{where}[{i}]", layer, _LAYER_KEYS, {}) for i, layer in enumerate(value)]
        if kind == "ior":
            if isinstance(value, str):
                from thinfilm.bsdf import material_names
                from thinfilm.bsdf.materials import parse_index

                try:
                    parsed = parse_index(value)
                except ValueError:
                    parsed = None
                if parsed is None or (hasattr(parsed, "name") and value not in material_names()):
                    self.fail(where, f"a number, 'n+ki' or one of {', '.join(material_names())}", value)
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


def resolve(raw: dict, c: "Checker") -> dict:
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
    if "layers" in film_rest:
        if "ior" in film_rest:
            raise UserError(f"{c.source}: 'film.ior' and 'film.layers' exclude each other "
                            f"(a stack gives each layer its 'ior')")
        out["film"] = c.table("film", film_rest, _STACK_KEYS, {})
        if "thickness" not in film:
            thickness = {"profile": "uniform", "value": out["film"]["layers"][0]["thickness_nm"]}
    else:
        out["film"] = c.table("film", film_rest, _FILM_KEYS, {})
    out["film"]["thickness"] = c.table("film.thickness", thickness, _PROFILE_KEYS[profile],
                                       {"profile": profile})

    out["substrate"] = c.table("substrate", raw.get("substrate", {}), _SUBSTRATE_KEYS, {})
    out["rig"] = c.table("rig", raw.get("rig", {}), _RIG_KEYS, {})
    out["noise"] = c.table("noise", raw.get("noise", {}), _NOISE_KEYS, {})
    _check_rig_colour(out["rig"], c)
    if out["rig"]["sensor"] == "dofp-rgb" and out["noise"]["bits"] > 16:
        raise UserError(f"{c.source}: 'noise.bits' must be at most 16 with rig.sensor = \"dofp-rgb\" "
                        f"(raw.tiff is a 16-bit file), got {out['noise']['bits']}")
    return out


def _check_rig_colour(rig: dict, c: "Checker") -> None:
    """Camera and illuminant must be known and give signal over the bands."""
    from thinfilm.core.colorimetry import camera_weights

    try:
        camera_weights(wavelength_grid(rig), rig["camera"], rig["illuminant"])
    except UserError as e:
        raise UserError(f"{c.source}: rig: {e}") from None


def wavelength_grid(rig: dict):
    """Band centres (nm) of a resolved rig table: ``start, start + step, …`` up to ``stop``."""
    import numpy as np

    w = rig["wavelengths_nm"]
    count = int(math.floor((w["stop"] - w["start"]) / w["step"] + 1e-9)) + 1
    return w["start"] + w["step"] * np.arange(count, dtype=np.float64)


SHAPE_KINDS = tuple(_SHAPE_KEYS)
PROFILES = tuple(_PROFILE_KEYS)
