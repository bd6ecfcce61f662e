"""Film thickness over the image: the profiles of the scene spec, and the texture that
carries a map into the scene.

Thickness lives in image space (:mod:`thinfilm.generators.textures`): a per-pixel map
sampled at pixel centres, looked up bilinearly at the orthographic image position of a
surface point, so any shape can carry it and the ground truth read at a pixel centre is the
value the renderer used there.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.errors import UserError

from .frame import Frame

__all__ = ["MAX_BITMAP_PIXELS", "read_thickness_bitmap", "thickness_map", "thickness_texture", "film_bsdf"]


#: largest thickness bitmap read (pixels): 16384 x 16384
MAX_BITMAP_PIXELS = 16384 * 16384


def read_thickness_bitmap(path: str) -> np.ndarray:
    """A thickness bitmap (``.exr``: channel ``thickness``, ``Y``, ``R`` or its only channel;
    ``.npy``: a 2-D array of numbers) in nm, float64, checked: 2-D, finite, >= 0, at most
    :data:`MAX_BITMAP_PIXELS`. One-line :class:`UserError` naming the file otherwise."""
    from thinfilm.core.io import read_exr

    lower = path.lower()
    if lower.endswith(".npy"):
        try:
            img = np.load(path, mmap_mode="r", allow_pickle=False)
        except Exception as e:
            reason = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise UserError(f"{path}: cannot read thickness bitmap ({reason})") from None
        if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)) \
                or np.issubdtype(img.dtype, np.bool_):
            raise UserError(f"{path}: thickness bitmap must hold numbers (nm), found {img.dtype} values")
    elif lower.endswith(".exr"):
        ch = read_exr(path)
        for name in ("thickness", "Y", "R"):
            if name in ch:
                img = ch[name]
                break
        else:
            if len(ch) != 1:
                raise UserError(f"{path}: thickness bitmap needs a channel 'thickness', 'Y' or 'R', "
                                f"found {', '.join(sorted(ch))}")
            img = next(iter(ch.values()))
    else:
        raise UserError(f"{path}: thickness bitmap must be an .exr or .npy file of thickness in nm")
    if img.ndim != 2 or min(img.shape) < 1:
        raise UserError(f"{path}: thickness bitmap must be a 2-D image, got shape {img.shape}")
    if img.size > MAX_BITMAP_PIXELS:
        raise UserError(f"{path}: thickness bitmap has {img.shape[1]}x{img.shape[0]} pixels, "
                        f"at most {MAX_BITMAP_PIXELS} pixels are read")
    img = np.array(img, dtype=np.float64)
    if not np.all(np.isfinite(img)):
        raise UserError(f"{path}: thickness bitmap contains NaN or infinite values")
    if img.min() < 0:
        raise UserError(f"{path}: thickness bitmap has negative thickness {img.min():g} nm")
    if img.max() > 1e5:
        raise UserError(f"{path}: thickness bitmap has thickness {img.max():g} nm, expected at most "
                        f"1e+05 nm (values in nm)")
    return img


def _resample(img: np.ndarray, resolution: int) -> np.ndarray:
    """Bilinear resampling of an image covering the frame to ``resolution`` pixel centres."""
    if img.shape == (resolution, resolution):
        return img
    from scipy.ndimage import map_coordinates

    h, w = img.shape
    centres = (np.arange(resolution) + 0.5) / resolution
    rows, cols = np.meshgrid(centres * h - 0.5, centres * w - 0.5, indexing="ij")
    return map_coordinates(img, [rows, cols], order=1, mode="nearest")


def thickness_map(profile: dict, frame: Frame):
    """Film thickness (nm) at every pixel centre, (H, W) float32, or a float if uniform.

    ``linear`` runs from ``start`` to ``end`` across the object's projected extent (x: left
    to right, y: bottom to top), constant beyond it. ``radial`` falls linearly with the
    distance from the object's centre from ``center`` to ``edge`` at ``radius`` (0: the
    silhouette radius) and stays at ``edge`` beyond. ``bitmap`` stretches the image over the
    whole square frame (row 0 at the top).
    """
    kind = profile["profile"]
    if kind == "uniform":
        return float(profile["value"])
    x, y = frame.pixel_centres()
    if kind == "linear":
        xmin, xmax, ymin, ymax = frame.object_extent
        u = (x - xmin) / (xmax - xmin) if profile["axis"] == "x" else (y - ymin) / (ymax - ymin)
        t = profile["start"] + (profile["end"] - profile["start"]) * np.clip(u, 0.0, 1.0)
    elif kind == "radial":
        radius = profile["radius"] or frame.rim_radius
        r = np.hypot(x - frame.object_center[0], y - frame.object_center[1]) / radius
        t = profile["center"] + (profile["edge"] - profile["center"]) * np.clip(r, 0.0, 1.0)
    elif kind == "bitmap":
        t = _resample(read_thickness_bitmap(profile["path"]), frame.resolution)
    else:  # pragma: no cover - validated by load_spec
        raise UserError(f"unknown thickness profile {kind!r}")
    return np.asarray(t, dtype=np.float32)


def thickness_texture(thickness, frame: Frame):
    """The ``thickness`` parameter of the BSDF: a float, or an ``imagespace`` texture dict."""
    if np.isscalar(thickness):
        return float(thickness)
    import mitsuba as mi

    data = np.ascontiguousarray(np.asarray(thickness, dtype=np.float32)[..., None])
    return {
        "type": "imagespace",
        "x0": frame.cx - frame.half_width,
        "y1": frame.cy + frame.half_height,
        "width": 2.0 * frame.half_width,
        "height": 2.0 * frame.half_height,
        "nested": {"type": "bitmap", "data": mi.TensorXf(data), "raw": True,
                   "filter_type": "bilinear", "wrap_mode": "clamp"},
    }


def film_bsdf(film, thickness, frame: Frame, roughness: float = 0.0) -> dict:
    """The ``thinfilm`` BSDF dictionary of a :class:`thinfilm.core.film.Film` whose (top layer's)
    thickness is ``thickness`` (nm, a number or an (H, W) map over ``frame``). A stack gets
    its nominal layers and the ``thickness_scale`` that gives its top layer that thickness.
    ``roughness`` > 0: a rough film (the plugin's ``alpha``)."""
    if film.is_single:
        return film.plugin_dict(thickness=thickness_texture(thickness, frame), roughness=roughness)
    scale = film.thickness_scale(thickness)
    return film.plugin_dict(thickness_scale=thickness_texture(float(scale) if np.ndim(scale) == 0 else scale,
                                                              frame), roughness=roughness)
