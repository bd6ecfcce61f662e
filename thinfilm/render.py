"""``thinfilm render``: render a Mitsuba scene that uses the ``thinfilm`` plugin to EXR and PNG.

The scene is a Mitsuba XML file, or a TOML/JSON file holding a ``mi.load_dict``
dictionary. In TOML/JSON, a ``to_world`` entry may be written as a table of
transform steps applied in order, e.g. ``to_world = {look_at = {origin = [0, 0, 5],
target = [0, 0, 0], up = [0, 1, 0]}}`` or ``{translate = [0, 0, 1], scale = 2.0}``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["load_scene", "render_to_files", "cli_main"]


def _transform(mi, spec, where):
    if not isinstance(spec, dict):
        raise UserError(f"{where}: 'to_world' must be a table of transform steps")
    t = mi.ScalarTransform4f()
    for step, value in spec.items():
        if step == "look_at":
            t = t @ mi.ScalarTransform4f().look_at(origin=value["origin"], target=value["target"],
                                                   up=value.get("up", [0, 1, 0]))
        elif step == "translate":
            t = t @ mi.ScalarTransform4f().translate(value)
        elif step == "scale":
            t = t @ mi.ScalarTransform4f().scale(value)
        elif step == "rotate":
            t = t @ mi.ScalarTransform4f().rotate(axis=value["axis"], angle=value["angle"])
        else:
            raise UserError(f"{where}: unknown transform step '{step}' "
                            "(expected look_at, translate, scale or rotate)")
    return t


def _convert(mi, node, where):
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if key == "to_world":
                out[key] = _transform(mi, value, f"{where}.{key}")
            else:
                out[key] = _convert(mi, value, f"{where}.{key}")
        return out
    return node


def _one_line(error) -> str:
    """The useful line of a Mitsuba loader error: our plugin's own message where it is wrapped
    (with a Python traceback) inside Mitsuba's, else Mitsuba's first line."""
    lines = [ln.strip() for ln in str(error).splitlines() if ln.strip()]
    for line in reversed(lines):
        if "thinfilm: " in line:
            return line[line.index("thinfilm: ") + len("thinfilm: "):]
    return lines[0] if lines else type(error).__name__


def load_scene(path):
    """Load a scene file (XML, TOML or JSON) in the current variant; registers the plugin."""
    import mitsuba as mi

    import thinfilm.bsdf

    thinfilm.bsdf.register()
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: scene file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".xml":
            return mi.load_file(str(path))
        if suffix == ".toml":
            import tomllib

            data = tomllib.loads(path.read_text())
        elif suffix == ".json":
            data = json.loads(path.read_text())
        else:
            raise UserError(f"{path}: expected a .xml, .toml or .json scene file")
        return mi.load_dict(_convert(mi, data, path.name))
    except UserError:
        raise
    except Exception as e:  # Mitsuba's loader errors: one line that names the file
        raise UserError(f"{path}: {_one_line(e)}") from None


def _gain(image, exposure):
    if exposure in (None, "auto"):
        level = float(np.percentile(image, 99.5)) if image.size else 0.0
        return 0.9 / level if level > 0 else 1.0
    try:
        gain = float(exposure)
    except (TypeError, ValueError):
        raise UserError(f"--exposure: expected 'auto' or a positive number, got {exposure!r}") from None
    if not gain > 0:
        raise UserError(f"--exposure: expected 'auto' or a positive number, got {exposure!r}")
    return gain


def render_to_files(scene, out_stem, spp=None, seed=0, exposure="auto"):
    """Render ``scene`` and write ``out_stem.exr`` (every film channel, linear) and
    ``out_stem.png`` (sRGB, scaled by ``exposure``: ``"auto"`` or a gain)."""
    import mitsuba as mi

    out_stem = Path(out_stem)
    if out_stem.suffix.lower() in (".exr", ".png"):
        out_stem = out_stem.with_suffix("")
    out_stem.parent.mkdir(parents=True, exist_ok=True)
    _gain(np.zeros(0), exposure)  # validate before the render
    mi.render(scene, spp=spp or 0, seed=seed)
    bitmap = scene.sensors()[0].film().bitmap(raw=False)
    tmp_exr = out_stem.with_name(out_stem.name + ".tmp.exr")
    bitmap.write(str(tmp_exr))
    # The first group of channels is the image itself (RGB, luminance or Stokes S0).
    parts = bitmap.split()
    image = np.array(parts[0][1], dtype=np.float32)
    if image.ndim == 2:
        image = image[..., None]
    if image.shape[-1] == 1:
        image = np.repeat(image, 3, axis=-1)
    image = np.clip(image[..., :3], 0.0, None)
    image = image * _gain(image, exposure)
    srgb = mi.Bitmap(image.astype(np.float32), mi.Bitmap.PixelFormat.RGB).convert(
        mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    tmp_png = out_stem.with_name(out_stem.name + ".tmp.png")
    srgb.write(str(tmp_png))
    tmp_exr.replace(out_stem.with_suffix(".exr"))
    tmp_png.replace(out_stem.with_suffix(".png"))
    return out_stem.with_suffix(".exr"), out_stem.with_suffix(".png")


def cli_main(args) -> int:
    from thinfilm.core.variants import use_variant

    use_variant(args.variant)
    scene = load_scene(args.scene)
    start = time.perf_counter()
    exr, png = render_to_files(scene, args.out, spp=args.spp, seed=args.seed, exposure=args.exposure)
    print(f"wrote {exr} and {png} in {time.perf_counter() - start:.2f} s")
    return 0
