"""``thinfilm render``: render a Mitsuba scene that uses the ``thinfilm`` plugin to EXR and PNG.

The scene is a Mitsuba XML file, or a TOML/JSON file holding a ``mi.load_dict``
dictionary. In TOML/JSON, a ``to_world`` entry may be written as a table of
transform steps applied in order, e.g. ``to_world = {look_at = {origin = [0, 0, 5],
target = [0, 0, 0], up = [0, 1, 0]}}`` or ``{translate = [0, 0, 1], scale = 2.0}``.

Outputs follow the rule of :mod:`thinfilm.core.outputs`: ``STEM.exr`` and ``STEM.png`` are
written to temporary files and renamed into place together; an existing file is replaced
only with ``--overwrite``, and a file the scene reads never.
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["load_scene", "scene_inputs", "output_files", "render_to_files", "write_bitmap", "cli_main"]


def _transform(mi, spec, where):
    if not isinstance(spec, dict):
        raise UserError(f"{where}: 'to_world' must be a table of transform steps")
    t = mi.ScalarTransform4f()
    for step, value in spec.items():
        try:
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
        except UserError:
            raise
        except Exception:
            expected = {"look_at": "a table with origin, target (and up), each 3 numbers",
                        "translate": "3 numbers", "scale": "a number or 3 numbers",
                        "rotate": "a table with axis (3 numbers) and angle (degrees)"}[step]
            raise UserError(f"{where}.{step}: expected {expected}, got {value!r}"[:300]) from None
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
    """The useful line of a Mitsuba loader error: a Python plugin's own message where Mitsuba
    wraps it with the Python traceback (nanobind's, which a Python plugin cannot leave out:
    the last line, ``ParameterError: thinfilm: ...``, without its exception name and, for the
    ``thinfilm`` plugin, its name), else Mitsuba's message without its source location, with
    the list that may follow it (unreferenced parameters) joined on, whole."""
    lines = [ln.strip() for ln in str(error).splitlines() if ln.strip()]
    if any(ln.endswith("Traceback (most recent call last):") for ln in lines[:-1]):
        last = re.sub(r"^(ParameterError|ValueError): ", "", lines[-1], count=1)
        return last[len("thinfilm: "):] if last.startswith("thinfilm: ") else last
    if not lines:
        return type(error).__name__
    first = re.sub(r"^\[[\w.]+:\d+\]\s*", "", lines[0])
    items = [ln[1:].strip() for ln in lines[1:] if ln.startswith("-")]
    if items and first.endswith(":"):
        first = f"{first} {'; '.join(items)}"
    return first


def _read_scene_data(path: Path) -> dict:
    """The dictionary of a .toml or .json scene, checked to be a ``type = "scene"`` table."""
    from thinfilm.core.files import parse_toml_text
    from thinfilm.core.io import parse_json_text, read_text_file

    text = read_text_file(path, "scene")
    if path.suffix.lower() == ".toml":
        data = parse_toml_text(text, path)
    else:
        data = parse_json_text(text, path)
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a table (a Mitsuba load_dict dictionary), got {type(data).__name__}")
    if data.get("type") != "scene":
        raise UserError(f"{path}: expected type = \"scene\" at the top of the dictionary, got {data.get('type')!r}")
    return data


def scene_inputs(path) -> list:
    """The files a scene reads: the scene file and every ``filename`` it names (XML
    ``<string name="filename" value="..."/>``, a dictionary's ``filename`` entries),
    relative to the scene's folder. An output never replaces them."""
    path = Path(path)
    names = []
    suffix = path.suffix.lower()
    if suffix in (".toml", ".json"):
        def walk(node):
            if isinstance(node, dict):
                for key, value in node.items():
                    if key == "filename" and isinstance(value, str):
                        names.append(value)
                    else:
                        walk(value)
            elif isinstance(node, list):
                for value in node:
                    walk(value)

        try:
            walk(_read_scene_data(path))
        except UserError:
            pass
    elif suffix == ".xml":
        import xml.etree.ElementTree as ET

        try:
            for el in ET.parse(path).iter():
                if el.get("name") == "filename" and el.get("value"):
                    names.append(el.get("value"))
        except (ET.ParseError, OSError, ValueError):
            pass
    return [path] + [path.parent / n for n in names if "$" not in n]


def _check_scene_file(path: Path) -> None:
    """A scene path that is a regular file, else one line naming it (a pipe or a device is
    never opened)."""
    import os

    from thinfilm.core.files import check_regular_file

    if os.path.isdir(path):
        raise UserError(f"{path}: scene file not found")
    check_regular_file(path, "scene file")


def load_scene(path):
    """Load a scene file (XML, TOML or JSON) in the current variant; registers the plugin."""
    import mitsuba as mi

    import thinfilm.bsdf

    thinfilm.bsdf.register()
    path = Path(path)
    _check_scene_file(path)
    suffix = path.suffix.lower()
    if suffix not in (".xml", ".toml", ".json"):
        raise UserError(f"{path}: expected a .xml, .toml or .json scene file")
    try:
        if suffix == ".xml":
            return mi.load_file(str(path))
        return mi.load_dict(_convert(mi, _read_scene_data(path), path.name))
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
    if not (gain > 0 and math.isfinite(gain)):
        raise UserError(f"--exposure: expected 'auto' or a positive number, got {exposure!r}")
    return gain


def _stem(out_stem) -> Path:
    stem = Path(out_stem)
    if stem.suffix.lower() in (".exr", ".png"):
        stem = stem.with_suffix("")
    if not stem.name or stem.name in (".", ".."):
        raise UserError(f"--out {out_stem}: expected a path stem for the images, e.g. out/image")
    return stem


def output_files(out_stem) -> tuple:
    """``(STEM.exr, STEM.png)`` of ``--out STEM`` (a trailing .exr or .png is dropped)."""
    stem = _stem(out_stem)
    return stem.with_name(stem.name + ".exr"), stem.with_name(stem.name + ".png")


def render_to_files(scene, out_stem, spp=None, seed=0, exposure="auto", overwrite=False, inputs=()):
    """Render ``scene`` and write ``out_stem.exr`` (every film channel, linear) and
    ``out_stem.png`` (sRGB, scaled by ``exposure``: ``"auto"`` or a gain).

    An existing file is replaced only with ``overwrite``, and never one of ``inputs`` (the
    scene's own files, :func:`scene_inputs`). Both files are written to temporary files and
    renamed into place together (:func:`thinfilm.core.outputs.atomic_output_files`). A scene
    without an integrator is rendered with Mitsuba's default one (``path``), as Mitsuba does
    for XML scenes.
    """
    import mitsuba as mi

    from thinfilm.core.outputs import atomic_output_files

    exr, png = output_files(out_stem)
    _gain(np.zeros(0), exposure)  # validate before the render
    if spp is not None and not 1 <= int(spp) <= 2**20:
        raise UserError(f"--spp: expected a whole number from 1 to {2**20}, got {spp}")
    if not 0 <= int(seed) < 2**32:
        raise UserError(f"--seed: expected a whole number from 0 to {2**32 - 1}, got {seed}")
    with atomic_output_files([exr, png], overwrite=overwrite, inputs=inputs) as tmp:
        tmp_exr, tmp_png = tmp.values()
        integrator = scene.integrator()
        if integrator is None:
            integrator = mi.load_dict({"type": "path"})
        try:
            mi.render(scene, integrator=integrator, spp=int(spp or 0), seed=int(seed))
        except Exception as e:
            raise UserError(f"cannot render the scene: {_one_line(e)}") from None
        bitmap = scene.sensors()[0].film().bitmap(raw=False)
        write_bitmap(mi, bitmap, tmp_exr, mi.Bitmap.FileFormat.OpenEXR)
        # The first group of channels is the image itself (RGB, luminance or Stokes S0).
        parts = bitmap.split()
        image = np.array(parts[0][1], dtype=np.float32)
        if image.ndim == 2:
            image = image[..., None]
        if image.shape[-1] == 1:
            image = np.repeat(image, 3, axis=-1)
        image = np.nan_to_num(np.clip(image[..., :3], 0.0, None), nan=0.0, posinf=0.0)
        image = image * _gain(image, exposure)
        srgb = mi.Bitmap(image.astype(np.float32), mi.Bitmap.PixelFormat.RGB).convert(
            mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
        write_bitmap(mi, srgb, tmp_png, mi.Bitmap.FileFormat.PNG)
    return exr, png


def write_bitmap(mi, bitmap, path: Path, file_format) -> None:
    """Encode in memory, then write with Python: a full disk raises ``OSError`` (Mitsuba's
    own file writer leaves an empty file and reports success)."""
    stream = mi.MemoryStream()
    bitmap.write(stream, file_format)
    Path(path).write_bytes(stream.raw_buffer()[:stream.size()])


def cli_main(args) -> int:
    """``thinfilm render SCENE --out STEM [--variant V] [--spp N] [--seed S] [--exposure E]
    [--overwrite]``: inputs and outputs are checked before Mitsuba starts."""
    from thinfilm.core.outputs import check_output_files
    from thinfilm.core.variants import use_variant

    scene = Path(args.scene)
    _check_scene_file(scene)
    if scene.suffix.lower() not in (".xml", ".toml", ".json"):
        raise UserError(f"{scene}: expected a .xml, .toml or .json scene file")
    if scene.suffix.lower() != ".xml":
        _read_scene_data(scene)
    _gain(np.zeros(0), args.exposure)
    overwrite = bool(getattr(args, "overwrite", False))
    inputs = scene_inputs(scene)
    check_output_files(output_files(args.out), overwrite=overwrite, inputs=inputs)
    use_variant(args.variant)
    loaded = load_scene(scene)
    start = time.perf_counter()
    exr, png = render_to_files(loaded, args.out, spp=args.spp, seed=args.seed, exposure=args.exposure,
                               overwrite=overwrite, inputs=inputs)
    print(f"wrote {exr} and {png} in {time.perf_counter() - start:.2f} s")
    return 0
