"""Estimate folders (``DESIGN.md``): ``estimate.exr``, ``estimate.json``, optional ``surface.ply``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thinfilm.dataset import atomic_output_dir, read_exr, read_json, write_exr, write_json
from thinfilm.errors import UserError

__all__ = ["ESTIMATE_CHANNELS", "normals_to_angles", "write_estimate", "read_estimate", "height_to_mesh"]

ESTIMATE_CHANNELS = ("normal.X", "normal.Y", "normal.Z", "zenith", "azimuth", "thickness", "valid")


def normals_to_angles(normals):
    """Zenith θ = arccos(n_z) and azimuth φ = atan2(n_y, n_x) in [0, 360), both in degrees.

    The range holds in float32 too (files store float32): an azimuth a hair below 360 that
    would round up to 360.0 in float32 is returned as 0.
    """
    n = np.asarray(normals, dtype=np.float64)
    zenith = np.degrees(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))
    azimuth = np.mod(np.degrees(np.arctan2(n[..., 1], n[..., 0])), 360.0)
    azimuth = np.where(azimuth.astype(np.float32) >= np.float32(360.0), 0.0, azimuth)
    return zenith, azimuth


def height_to_mesh(height, mask, pixel_size=1.0):
    """A trimesh surface from a height map on a mask (x right, y up, z towards the camera).

    Vertices sit at pixel centres; two triangles per 2×2 block of masked pixels.
    """
    import trimesh

    h, w = mask.shape
    idx = -np.ones((h, w), dtype=np.int64)
    ys, xs = np.nonzero(mask)
    idx[ys, xs] = np.arange(ys.size)
    verts = np.stack([(xs - (w - 1) / 2) * pixel_size, ((h - 1) / 2 - ys) * pixel_size,
                      height[ys, xs]], axis=-1)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    faces = []
    for tri in ((a, c, b), (b, c, d)):  # counter-clockwise seen from +z (image y is down)
        t = np.stack([x.ravel() for x in tri], axis=-1)
        faces.append(t[np.all(t >= 0, axis=1)])
    return trimesh.Trimesh(vertices=verts, faces=np.concatenate(faces), process=False)


def write_estimate(out, normals, thickness, valid, info: dict, height=None, pixel_size=1.0):
    """Write an estimate folder atomically.

    Parameters
    ----------
    out : path-like
        Folder to create (replaced if it exists, only once complete).
    normals : (H, W, 3) unit normals in the camera frame.
    thickness : (H, W) film thickness in nm.
    valid : (H, W) bool, pixels with an estimate.
    info : dict for ``estimate.json``: ``method``, ``film_ior``, ``substrate_ior``, ``timings_s``
        (more keys welcome).
    height : optional (H, W) height map; written as ``surface.ply`` over ``valid``.
    """
    normals = np.asarray(normals, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    zenith, azimuth = normals_to_angles(normals)
    for key in ("method", "film_ior", "substrate_ior", "timings_s"):
        if key not in info:
            raise ValueError(f"estimate.json needs '{key}'")
    nan = np.float32(np.nan)
    channels = {
        "normal.X": np.where(valid, normals[..., 0], nan),
        "normal.Y": np.where(valid, normals[..., 1], nan),
        "normal.Z": np.where(valid, normals[..., 2], nan),
        "zenith": np.where(valid, zenith, nan),
        "azimuth": np.where(valid, azimuth, nan),
        "thickness": np.where(valid, thickness, nan),
        "valid": valid.astype(np.float32),
    }
    with atomic_output_dir(out) as tmp:
        write_exr(tmp / "estimate.exr", channels)
        write_json(tmp / "estimate.json", info)
        if height is not None and valid.sum() >= 4:
            height_to_mesh(np.asarray(height, dtype=np.float64), valid, pixel_size).export(tmp / "surface.ply")
    return Path(out)


def read_estimate(path):
    """Read an estimate folder: ``(channels, info)``; ``channels`` has ``normal`` (H, W, 3),
    ``zenith``, ``azimuth``, ``thickness`` and ``valid`` (bool). One-line errors name the file."""
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"{root}: estimate folder not found")
    exr = root / "estimate.exr"
    ch = read_exr(exr)
    shape = None
    for name in ESTIMATE_CHANNELS:
        if name not in ch:
            raise UserError(f"{exr}: missing channel '{name}'")
        if shape is None:
            shape = ch[name].shape
        elif ch[name].shape != shape:
            raise UserError(f"{exr}: channel '{name}' has shape {ch[name].shape}, expected {shape}")
    info = read_json(root / "estimate.json")
    valid = ch["valid"] > 0.5
    out = {
        "normal": np.stack([ch["normal.X"], ch["normal.Y"], ch["normal.Z"]], axis=-1),
        "zenith": ch["zenith"], "azimuth": ch["azimuth"], "thickness": ch["thickness"], "valid": valid,
    }
    return out, info
