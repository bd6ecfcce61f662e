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

from thinfilm.bsdf import limits as plugin_limits
from thinfilm.core.errors import UserError

__all__ = ["SHAPE_KINDS", "PROFILES", "LIMITS", "REQUIRED", "CHECKS", "Checker", "resolve", "schema", "describe_check",
           "wavelength_grid", "estimated_memory_bytes"]

#: Limits of the values a spec may hold: beyond them a capture would take more memory or
#: time than any machine has, lose its precision in Mitsuba's single-precision geometry,
#: or overflow the noise model. (name: (low, high), inclusive)
LIMITS = {
    "resolution": (2, 16384),            # pixels; 1 pixel has no image to speak of
    "length": (1e-6, 1e6),               # scene units: radius, length, base, height, mesh size
    "thickness_nm": plugin_limits.THICKNESS_NM,  # a film of 100 um is no longer thin
    "full_well": (1e-3, 1e9),            # electrons
    "read_noise": (0.0, 1e6),            # electrons
    "exposure": (1e-6, 1e12),            # electrons per unit reflectance
    "band_fwhm_nm": (0.0, 1000.0),
    "fill": (0.01, 1.0),
    "max_depth": (2, 100),
    "seed": (0, 2**32 - 1),
    "renders_per_image": (1, 20000),     # sub-wavelengths rendered for all bands together
    "wavelength_nm": plugin_limits.WAVELENGTH_NM,
    "index": plugin_limits.INDEX,        # refractive index n (real part)
    "extinction": plugin_limits.EXTINCTION,  # extinction coefficient k
}

# --- the schema ----------------------------------------------------------------------------
# Each key maps to (checker name, default). A default of _REQUIRED must be given by the user.
_REQUIRED = object()

_SHAPE_KEYS = {
    "hemisphere": {"radius": ("length", 1.0)},
    "cylinder": {"radius": ("length", 1.0), "length": ("length", 2.0)},
    "pyramid": {"base": ("length", 2.0), "height": ("length", 0.6)},
    "mesh": {"path": ("file", _REQUIRED), "scale": ("length", 1.0),
             "rotate_deg": ("vec3", [0.0, 0.0, 0.0]), "smooth": ("bool", True)},
    "torus": {"major_radius": ("length", 1.0), "minor_radius": ("length", 0.35),
              "rotate_deg": ("vec3", [0.0, 0.0, 0.0])},
    "capsule": {"radius": ("length", 0.5), "length": ("length", 1.5),
                "rotate_deg": ("vec3", [0.0, 0.0, 0.0])},
    "ellipsoid": {"semi_axes": ("lengths3", [1.0, 0.7, 0.5]), "rotate_deg": ("vec3", [0.0, 0.0, 0.0])},
    "cap": {"radius": ("length", 1.0), "height": ("length", 0.5), "rotate_deg": ("vec3", [0.0, 0.0, 0.0])},
    "sheet": {"size": ("length", 2.0), "amplitude": ("amplitude", 0.12), "wavelength": ("length", 1.0),
              "direction_deg": ("number", 0.0), "phase_deg": ("number", 90.0), "cross": ("bool", False),
              "rotate_deg": ("vec3", [0.0, 0.0, 0.0])},
    "group": {"parts": ("parts", _REQUIRED)},
}
#: the most parts a ``group`` shape may have (counted before any part is checked or built: each
#: is a mesh of up to about 130 000 triangles)
MAX_GROUP_PARTS = 64
#: the most layers a film ``layers`` stack may have (counted before any layer is checked): the
#: plugin's limit in the generator's variant (:data:`thinfilm.bsdf.limits.MAX_STACK_LAYERS`,
#: where the cost per layer is measured)
MAX_STACK_LAYERS = plugin_limits.MAX_STACK_LAYERS
#: shape kinds a ``group`` part may be
_PART_KINDS = tuple(k for k in _SHAPE_KEYS if k not in ("mesh", "group"))

_PROFILE_KEYS = {
    "uniform": {"value": ("thickness", 400.0)},
    "linear": {"start": ("thickness", 420.0), "end": ("thickness", 560.0), "axis": ("axis", "x")},
    "radial": {"center": ("thickness", 690.0), "edge": ("thickness", 400.0),
               "radius": ("radius", 0.0)},
    "bitmap": {"path": ("bitmap", _REQUIRED)},
}

#: ``roughness``: the film's microfacet roughness, the GGX alpha of the ``thinfilm`` plugin
#: (0 = smooth); a spec writes it only when > 0, so smooth specs read as before
_FILM_KEYS = {"ior": ("ior", 1.37), "roughness": ("roughness", 0.0)}
#: a stack instead of one film: ``layers = [{ ior = ..., thickness_nm = ... }, ...]`` from the
#: exterior down (then ``film.thickness`` gives the top layer's thickness and the others scale
#: with it)
_STACK_KEYS = {"layers": ("layers", _REQUIRED), "roughness": ("roughness", 0.0)}
_LAYER_KEYS = {"ior": ("ior", _REQUIRED), "thickness_nm": ("layer_thickness", _REQUIRED)}
#: ``ior`` takes what ``film.ior`` takes (a number, ``n+ki``, a material name); ``k`` adds an
#: extinction to a plain number only (a text index carries its own k)
_SUBSTRATE_KEYS = {"ior": ("ior", 1.6), "k": ("extinction", 0.0)}
_RIG_KEYS = {
    "resolution": ("resolution", 256),
    "wavelengths_nm": ("wavelengths", {"start": 400.0, "stop": 720.0, "step": 4.0}),
    "band_fwhm_nm": ("fwhm", 4.0),
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
    "full_well": ("full_well", 10000.0),
    "read_noise": ("read_noise", 5.0),
    "bits": ("bits", 12),
    "exposure": ("exposure", "auto"),
}
_TOP_KEYS = ("seed", "shape", "film", "substrate", "rig", "noise")

#: the default of a key that the user must give, in :func:`schema`
REQUIRED = _REQUIRED

#: what each checker of the schema accepts, in words (the scene-spec reference is generated
#: from :func:`schema` and these)
CHECKS = {
    "length": "a length in scene units, {length[0]:g} to {length[1]:g}",
    "radius": "0 (the silhouette's radius) or a length in scene units",
    "thickness": "a film thickness in nm, {thickness_nm[0]:g} to {thickness_nm[1]:g}",
    "layer_thickness": "a layer thickness in nm, > 0 and up to {thickness_nm[1]:g}",
    "fwhm": "a passband width (FWHM) in nm, {band_fwhm_nm[0]:g} to {band_fwhm_nm[1]:g} (0: one wavelength per band)",
    "full_well": "electrons, {full_well[0]:g} to {full_well[1]:g}",
    "read_noise": "electrons, {read_noise[0]:g} to {read_noise[1]:g}",
    "resolution": "a whole number of pixels, {resolution[0]} to {resolution[1]} (width and height)",
    "depth": "a whole number of bounces, {max_depth[0]} to {max_depth[1]}",
    "bits": "a whole number of bits, 1 to 24",
    "bool": "true or false",
    "vec3": "3 numbers: x, y, z Euler angles in degrees, applied in that order",
    "lengths3": "3 lengths in scene units",
    "offset": "3 numbers in scene units: the part's position",
    "amplitude": "0 or a length in scene units",
    "number": "a number",
    "parts": "a list of shape tables (any kind but mesh and group), each with an offset; at most "
             f"{MAX_GROUP_PARTS}",
    "axis": '"x" or "y"',
    "passband": '"gaussian" or "box"',
    "sensor": '"ideal" (no raw data) or "dofp-rgb" (a colour polarization sensor\'s raw.tiff too)',
    "noise_model": '"camera" (shot, read and quantization noise) or "none"',
    "exposure": '"auto" or electrons per unit reflectance, {exposure[0]:g} to {exposure[1]:g}',
    "spp": '"auto" or a whole number of samples per pixel, 1 to 4096 (rough films)',
    "roughness": "the microfacet roughness (GGX alpha), 0 (smooth) to 1",
    "hole": "an angle in degrees, 0 to below 90: the angular radius of the camera's hole in the lighting dome",
    "fill": "a fraction of the image, {fill[0]:g} to {fill[1]:g}",
    "file": "a file path (relative to the spec's folder)",
    "layers": "a list of 1 to " f"{MAX_STACK_LAYERS}" " layer tables, from the exterior down",
    "bitmap": ("an .exr (channel thickness, Y, R or its only one) or .npy file of thicknesses in nm, "
               "relative to the spec's folder"),
    "ior": ("a refractive index ({index[0]:g} to {index[1]:g}), 'n+ki' text, a shipped material (MgF2, PET, BK7, "
            "SiO2, H2O, Au) or a refractiveindex.info material (e.g. TiO2, main/TiO2/Sarkar)"),
    "index": "a refractive index, {index[0]:g} to {index[1]:g}",
    "extinction": "an extinction coefficient k, {extinction[0]:g} to {extinction[1]:g}",
    "angles": "whole-degree polarizer angles, 0 to 359, at least 3 that differ modulo 180",
    "wavelengths": "a table {{ start, stop, step }} in nm (band centres start, start + step, ... up to stop)",
    "camera": "a camera name (colour's camera sensitivities) or a CSV path",
    "illuminant": "an illuminant name (e.g. D65, D50, A) or a CSV path",
}


# --- checkers ------------------------------------------------------------------------------

class Checker:
    def __init__(self, source: str, base_dir: Path | None):
        self.source = source
        self.base_dir = base_dir

    def fail(self, where: str, expected: str, value) -> None:
        raise UserError(f"{self.source}: '{where}' must be {expected}, got {_show(value)}")

    def number(self, where, value):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, "a number", value)
        try:
            v = float(value)
        except OverflowError:
            v = math.inf
        if not math.isfinite(v):
            self.fail(where, "a finite number", value)
        return v

    def integer(self, where, value):
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            self.fail(where, "a whole number", value)
        return int(value)

    def bounded(self, where, value, limit: str, what: str = "a number"):
        """A number within :data:`LIMITS` ``limit``."""
        lo, hi = LIMITS[limit]
        v = self.number(where, value)
        if not lo <= v <= hi:
            self.fail(where, f"{what} from {lo:g} to {hi:g}", value)
        return v

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
        if kind == "length":
            return self.bounded(where, value, "length", "a length in scene units")
        if kind == "radius":
            if value == 0:
                return 0.0
            return self.bounded(where, value, "length", "0 (the silhouette radius) or a length in scene units")
        if kind == "thickness":
            return self.bounded(where, value, "thickness_nm", "a film thickness in nm")
        if kind == "layer_thickness":
            v = self.check("positive", where, value)
            if v > LIMITS["thickness_nm"][1]:
                self.fail(where, f"a layer thickness in nm up to {LIMITS['thickness_nm'][1]:g}", value)
            return v
        if kind == "fwhm":
            return self.bounded(where, value, "band_fwhm_nm", "a passband width in nm")
        if kind == "full_well":
            return self.bounded(where, value, "full_well", "a number of electrons")
        if kind == "read_noise":
            return self.bounded(where, value, "read_noise", "a number of electrons")
        if kind == "resolution":
            lo, hi = LIMITS["resolution"]
            v = self.integer(where, value)
            if not lo <= v <= hi:
                self.fail(where, f"a whole number of pixels from {lo} to {hi}", value)
            return v
        if kind == "depth":
            lo, hi = LIMITS["max_depth"]
            v = self.integer(where, value)
            if not lo <= v <= hi:
                self.fail(where, f"a whole number from {lo} to {hi}", value)
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
        if kind == "lengths3":
            lo, hi = LIMITS["length"]
            expected = f"a list of 3 lengths in scene units from {lo:g} to {hi:g}"
            if not isinstance(value, list) or len(value) != 3:
                self.fail(where, expected, value)
            out = [self.number(where, v) for v in value]
            if not all(lo <= v <= hi for v in out):
                self.fail(where, expected, value)
            return out
        if kind == "offset":
            lo, hi = LIMITS["length"]
            if not isinstance(value, list) or len(value) != 3:
                self.fail(where, f"a list of 3 numbers (scene units, at most {hi:g} across)", value)
            out = [self.number(where, v) for v in value]
            if max(abs(v) for v in out) > hi:
                self.fail(where, f"a list of 3 numbers (scene units, at most {hi:g} across)", value)
            return out
        if kind == "amplitude":
            if value == 0:
                return 0.0
            return self.bounded(where, value, "length", "0 or a length in scene units")
        if kind == "number":
            return self.number(where, value)
        if kind == "parts":
            return self._parts(where, value)
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
            lo, hi = LIMITS["exposure"]
            expected = f"\"auto\" or a number of electrons per unit reflectance from {lo:g} to {hi:g}"
            if isinstance(value, str):
                self.fail(where, expected, value)
            v = self.number(where, value)
            if not lo <= v <= hi:
                self.fail(where, expected, value)
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
            low, high = plugin_limits.ALPHA
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                self.fail(where, "a microfacet roughness (GGX alpha) from 0 (smooth) to 1", value)
            return float(value)
        if kind == "hole":
            v = self.number(where, value)
            if not 0 <= v < 90:
                self.fail(where, "an angle in degrees from 0 to below 90", value)
            return v
        if kind == "fill":
            return self.bounded(where, value, "fill", "a fraction of the image")
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
            if isinstance(value, list) and len(value) > MAX_STACK_LAYERS:
                raise UserError(f"{self.source}: '{where}' holds {len(value)} layers, at most {MAX_STACK_LAYERS}")
            if not isinstance(value, list) or not value:
                self.fail(where, f"a list of 1 to {MAX_STACK_LAYERS} layer tables {{ ior = ..., thickness_nm = ... }}",
                          value)
            return [self.table(f"{where}[{i}]", layer, _LAYER_KEYS, {}) for i, layer in enumerate(value)]
        if kind == "bitmap":
            path = self.check("file", where, value)
            from .thickness import read_thickness_bitmap

            read_thickness_bitmap(path)  # its contents, now, not after the renderer started
            return path
        if kind == "ior":
            if isinstance(value, str):
                from thinfilm.bsdf import material_names
                from thinfilm.bsdf.materials import DatabaseMaterial, parse_index

                if value.strip().lower() in {m.lower() for m in material_names()} and value not in material_names():
                    # a shipped table by its exact name, as the echo and meta.json write it
                    self.fail(where, f"a number, 'n+ki', one of {', '.join(material_names())} or a "
                                     f"refractiveindex.info material", value)
                try:
                    parsed = parse_index(value)
                except ValueError as e:
                    raise UserError(f"{self.source}: '{where}': {e}") from None
                if hasattr(parsed, "n"):
                    self.bounded(where, parsed.n, "index", "a refractive index")
                    self.bounded(where, parsed.k, "extinction", "an extinction coefficient k")
                # a database material as its full page (shelf/book/page): the echo records the page used
                return parsed.name if isinstance(parsed, DatabaseMaterial) else value
            v = self.number(where, value)
            lo, hi = LIMITS["index"]
            if not lo <= v <= hi:
                self.fail(where, f"a refractive index from {lo:g} to {hi:g}, or a material name", value)
            return v
        if kind == "index":
            return self.bounded(where, value, "index", "a refractive index")
        if kind == "extinction":
            return self.bounded(where, value, "extinction", "an extinction coefficient")
        if kind == "angles":
            if not isinstance(value, list) or not value:
                self.fail(where, "a list of polarizer angles in degrees", value)
            angles = [self.number(where, a) for a in value]
            if any(abs(a - round(a)) > 1e-9 or not 0 <= round(a) < 360 for a in angles):
                self.fail(where, "whole-degree polarizer angles from 0 to 359", value)
            layers = [int(round(a)) for a in angles]
            if len(set(layers)) != len(layers):
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
            start = self.bounded(f"{where}.start", value["start"], "wavelength_nm", "a wavelength in nm")
            stop = self.bounded(f"{where}.stop", value["stop"], "wavelength_nm", "a wavelength in nm")
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

    def _parts(self, where, value):
        if isinstance(value, list) and len(value) > MAX_GROUP_PARTS:
            raise UserError(f"{self.source}: '{where}' holds {len(value)} parts, at most {MAX_GROUP_PARTS} "
                            f"(each part is a mesh of its own; join them into one 'mesh' shape instead)")
        if not isinstance(value, list) or not value:
            self.fail(where, "a list of shape tables (each with a kind and an offset)", value)
        parts = []
        for i, part in enumerate(value):
            here = f"{where}[{i}]"
            if not isinstance(part, dict):
                self.fail(here, "a table", part)
            kind = part.get("kind")
            if kind not in _PART_KINDS:
                self.fail(f"{here}.kind", f"one of {', '.join(_PART_KINDS)}", kind)
            schema = dict(_SHAPE_KEYS[kind], offset=("offset", [0.0, 0.0, 0.0]))
            parts.append(self.table(here, part, schema, {"kind": kind}))
        return parts

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


def _show(value, limit: int = 120) -> str:
    if isinstance(value, str):
        text = repr(value)
    else:
        try:
            text = json.dumps(value)
        except (TypeError, ValueError):
            text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def resolve(raw: dict, c: "Checker") -> dict:
    for key in raw:
        if key not in _TOP_KEYS:
            raise UserError(f"{c.source}: unknown key '{key}' (expected one of {', '.join(_TOP_KEYS)})")
    out = {}
    out["seed"] = c.integer("seed", raw.get("seed", 0))
    lo, hi = LIMITS["seed"]
    if not lo <= out["seed"] <= hi:
        c.fail("seed", f"a whole number from {lo} to {hi}", out["seed"])

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
    if isinstance(out["substrate"]["ior"], str) and out["substrate"]["k"]:
        raise UserError(f"{c.source}: 'substrate.k' adds an extinction to a numeric 'substrate.ior' only; "
                        f"{out['substrate']['ior']!r} carries its own k (give the index as 'n+ki' instead)")
    out["rig"] = c.table("rig", raw.get("rig", {}), _RIG_KEYS, {})
    out["noise"] = c.table("noise", raw.get("noise", {}), _NOISE_KEYS, {})
    _check_rig_colour(out["rig"], c)
    if out["rig"]["sensor"] == "dofp-rgb" and out["noise"]["bits"] > 16:
        raise UserError(f"{c.source}: 'noise.bits' must be at most 16 with rig.sensor = \"dofp-rgb\" "
                        f"(raw.tiff is a 16-bit file), got {out['noise']['bits']}")
    _check_size(out["rig"], c)
    _check_material_ranges(out, c)
    return out


def _check_material_ranges(out: dict, c) -> None:
    """A database material must cover every wavelength the generator renders (the bands and
    their passbands): refused in one line naming its range, before anything is rendered."""
    film = out["film"]
    named = [("film.ior", film.get("ior"))] + [(f"film.layers[{i}].ior", layer["ior"])
                                               for i, layer in enumerate(film.get("layers", []))]
    named.append(("substrate.ior", out["substrate"]["ior"]))
    named = [(where, value) for where, value in named if isinstance(value, str)]
    if not named:
        return
    from thinfilm.bsdf.materials import DatabaseMaterial, parse_index
    from thinfilm.core.bands import passband_quadrature

    rig = out["rig"]
    sub_nm, _ = passband_quadrature(wavelength_grid(rig), rig["band_fwhm_nm"], rig["passband"])
    for where, value in named:
        material = parse_index(value)
        if isinstance(material, DatabaseMaterial):
            try:
                material.check_range(float(sub_nm[0]), float(sub_nm[-1]), "the rendered wavelengths")
            except ValueError as e:
                raise UserError(f"{c.source}: '{where}': {e}") from None


def _renders_per_image(rig: dict) -> int:
    """How many sub-wavelengths the passband quadrature renders for all bands together
    (:func:`thinfilm.core.bands.passband_quadrature`), counted without building it."""
    w = rig["wavelengths_nm"]
    bands = int(math.floor((w["stop"] - w["start"]) / w["step"] + 1e-9)) + 1
    fwhm = rig["band_fwhm_nm"]
    if fwhm == 0:
        return bands
    if rig["passband"] == "box":
        return bands * max(1, math.ceil(fwhm - 1e-9))
    h = w["step"] / math.ceil(w["step"] / (0.5 * fwhm) - 1e-9) if bands > 1 else 0.5 * fwhm
    reach = 4.0 * fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    return int((w["stop"] - w["start"] + 2 * reach) / h) + 1


def estimated_memory_bytes(rig: dict) -> int:
    """Peak memory of generating a dataset with a resolved rig (measured on the development
    machine: about 320 MB, plus 140 bytes per pixel and band)."""
    bands = len(wavelength_grid(rig))
    pixels = rig["resolution"] ** 2
    return int(320e6 + 140 * pixels * bands + 8 * bands * _renders_per_image(rig))


def _physical_memory() -> int | None:
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _check_size(rig: dict, c: "Checker") -> None:
    """Refuse a rig whose capture cannot be computed here: too many sub-wavelength renders,
    or more memory than the machine has."""
    renders = _renders_per_image(rig)
    hi = LIMITS["renders_per_image"][1]
    if renders > hi:
        raise UserError(f"{c.source}: 'rig.band_fwhm_nm' = {rig['band_fwhm_nm']:g} nm with these "
                        f"'rig.wavelengths_nm' needs {renders} renders per image, at most {hi} are allowed "
                        f"(a wider passband or fewer bands)")
    need, have = estimated_memory_bytes(rig), _physical_memory()
    if have and need > have:
        raise UserError(f"{c.source}: 'rig.resolution' = {rig['resolution']} with "
                        f"{len(wavelength_grid(rig))} bands needs about {need / 2**30:.0f} GiB of memory, "
                        f"this machine has {have / 2**30:.0f} GiB (lower the resolution or use fewer bands)")


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


def schema() -> dict:
    """Every table of a scene spec: ``{table: {key: (checker, default)}}``, the checkers named
    as in :data:`CHECKS` (:data:`REQUIRED` for a key without default). ``shape`` and
    ``film.thickness`` hold one such table per ``kind`` / ``profile``. A copy: changing it
    changes nothing."""
    keep = {id(_REQUIRED): _REQUIRED}
    tables = {"seed": {"seed": ("seed", 0)}, "shape": _SHAPE_KEYS, "film": _FILM_KEYS,
              "film (a stack)": _STACK_KEYS, "film.layers[i]": _LAYER_KEYS,
              "film.thickness": _PROFILE_KEYS, "substrate": _SUBSTRATE_KEYS, "rig": _RIG_KEYS,
              "noise": _NOISE_KEYS}
    return copy.deepcopy(tables, keep)


def describe_check(kind: str) -> str:
    """What checker ``kind`` of :func:`schema` accepts, in words (limits from :data:`LIMITS`)."""
    if kind == "seed":
        return "a whole number, {0} to {1}".format(*LIMITS["seed"])
    return CHECKS[kind].format(**LIMITS)


SHAPE_KINDS = tuple(_SHAPE_KEYS)
PROFILES = tuple(_PROFILE_KEYS)
