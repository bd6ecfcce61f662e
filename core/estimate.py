"""Estimate folders (``docs/design.md``, *Estimate folder*): ``estimate.exr``,
``estimate.json`` and an optional ``surface.ply``.

``estimate.exr`` holds :data:`ESTIMATE_CHANNELS`; when the estimate has a height field,
``height`` (scene units); and when the estimator reports its uncertainty, the
:data:`SIGMA_CHANNELS` ``normal_sigma_deg`` (the RMS angle between the estimated and the true
normal, ``sqrt(trace)`` of the normal's 2 x 2 covariance, in degrees) and
``thickness_sigma_nm`` (a standard deviation, nm). Every channel but ``valid`` is NaN off the
valid pixels.
``estimate.json`` holds ``format`` (:data:`ESTIMATE_FORMAT`), ``method``, ``film_ior``,
``substrate_ior``, ``pixel_size`` (scene units per pixel of ``height``), ``timings_s`` and the
method's other entries. An estimate read back (:func:`read_estimate`) is the one written, in
float32: normals, thickness, valid pixels, height, pixel size, indices and entries; written
and read again, it stays the same. An ``estimate.json`` without ``format`` (older estimates)
reads with a pixel size of 1.

:func:`read_estimate` stops with a :class:`~thinfilm.core.errors.UserError` that names the file
and the channel or field; :func:`write_estimate` writes into a folder that exists,
deterministically.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError
from .exr import read_exr, write_exr
from .files import read_json, write_json

__all__ = ["ESTIMATE_FORMAT", "ESTIMATE_CHANNELS", "SIGMA_CHANNELS", "Estimate", "write_estimate", "read_estimate", "height_to_mesh"]

#: the ``format`` of ``estimate.json``
ESTIMATE_FORMAT = "thinfilm-estimate/1"
#: the channels every ``estimate.exr`` holds (``height`` too when there is a height field)
ESTIMATE_CHANNELS = ("normal.X", "normal.Y", "normal.Z", "zenith", "azimuth", "thickness", "valid")
#: the uncertainty channels an ``estimate.exr`` may hold (all or none)
SIGMA_CHANNELS = ("normal_sigma_deg", "thickness_sigma_nm")


@dataclass
class Estimate:
    """What an estimator returns, and what an estimate folder holds.

    Attributes
    ----------
    normals : (H, W, 3) unit normals in the camera frame.
    thickness_nm : (H, W) film thickness of the (top) layer in nm.
    valid : (H, W) bool, pixels with an estimate.
    film_ior : the film index used or estimated: a number or a material name (``estimate.json``).
    substrate_ior : the substrate index used (a number), or None.
    height : (H, W) height field in scene units (``pixel_size`` per pixel), or None.
    pixel_size : scene units per pixel of ``height``.
    info : more entries for ``estimate.json`` (``method``, ``timings_s``, diagnostics).
    normal_sigma_deg : (H, W) the normal's uncertainty (RMS angle, degrees), or None.
    thickness_sigma_nm : (H, W) the thickness's standard deviation (nm), or None. An
        estimator that cannot resolve a pixel's thickness (an order of interference left
        open) says so with a large or infinite σ there.
    """

    normals: np.ndarray
    thickness_nm: np.ndarray
    valid: np.ndarray
    film_ior: object = None
    substrate_ior: float | None = None
    height: np.ndarray | None = None
    pixel_size: float = 1.0
    info: dict = field(default_factory=dict)
    normal_sigma_deg: np.ndarray | None = None
    thickness_sigma_nm: np.ndarray | None = None

    @property
    def zenith_azimuth_deg(self):
        from .conventions import normals_to_angles

        return normals_to_angles(self.normals)

    def json(self) -> dict:
        """The ``estimate.json`` content."""
        out = dict(self.info)
        out["format"] = ESTIMATE_FORMAT
        out["film_ior"] = self.film_ior
        out["substrate_ior"] = self.substrate_ior
        out["pixel_size"] = float(self.pixel_size)
        out.setdefault("method", None)
        out.setdefault("timings_s", {})
        return out


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


def write_estimate(folder, estimate: Estimate) -> Path:
    """Write the files of an estimate folder into ``folder`` (which exists):
    ``estimate.exr``, ``estimate.json`` and, with a height field, ``surface.ply`` (and the
    ``height`` channel)."""
    from .conventions import normals_to_angles

    folder = Path(folder)
    normals = np.asarray(estimate.normals, dtype=np.float64)
    valid = np.asarray(estimate.valid, dtype=bool)
    zenith, azimuth = normals_to_angles(normals)
    nan = np.float32(np.nan)
    channels = {
        "normal.X": np.where(valid, normals[..., 0], nan),
        "normal.Y": np.where(valid, normals[..., 1], nan),
        "normal.Z": np.where(valid, normals[..., 2], nan),
        "zenith": np.where(valid, zenith, nan),
        "azimuth": np.where(valid, azimuth, nan),
        "thickness": np.where(valid, estimate.thickness_nm, nan),
        "valid": valid.astype(np.float32),
    }
    if estimate.height is not None:
        channels["height"] = np.where(valid, estimate.height, nan)
    sigmas = (estimate.normal_sigma_deg, estimate.thickness_sigma_nm)
    if any(v is not None for v in sigmas):
        if any(v is None for v in sigmas):
            raise ValueError("an estimate reports both normal_sigma_deg and thickness_sigma_nm, or neither")
        for name, v in zip(SIGMA_CHANNELS, sigmas):
            channels[name] = np.where(valid, np.asarray(v, dtype=np.float64), nan)
    write_exr(folder / "estimate.exr", channels)
    write_json(folder / "estimate.json", estimate.json())
    if estimate.height is not None and valid.sum() >= 4:
        height = np.nan_to_num(np.asarray(estimate.height, dtype=np.float64))
        height_to_mesh(height, valid, estimate.pixel_size).export(folder / "surface.ply")
    return folder


def read_estimate(path) -> Estimate:
    """Read an estimate folder (see the module docstring). One-line errors name the file and
    the channel or field: a missing folder, file or channel, channels of other shapes, an
    ``estimate.json`` that is not an object, an unknown ``format``, a ``pixel_size`` that is
    not a positive number."""
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"{root}: estimate folder not found")
    exr = root / "estimate.exr"
    ch = read_exr(exr)
    shape = None
    sigmas = [name for name in SIGMA_CHANNELS if name in ch]
    if sigmas and len(sigmas) != len(SIGMA_CHANNELS):
        missing = next(name for name in SIGMA_CHANNELS if name not in ch)
        raise UserError(f"{exr}: channel '{sigmas[0]}' without '{missing}'")
    for name in (*ESTIMATE_CHANNELS, "height", *sigmas):
        if name not in ch:
            if name == "height":
                continue
            raise UserError(f"{exr}: missing channel '{name}'")
        if shape is None:
            shape = ch[name].shape
        elif ch[name].shape != shape:
            raise UserError(f"{exr}: channel '{name}' has shape {ch[name].shape}, expected {shape}")
    js = root / "estimate.json"
    info = read_json(js)
    if not isinstance(info, dict):
        raise UserError(f"{js}: expected a JSON object")
    info = dict(info)
    form = info.pop("format", ESTIMATE_FORMAT)
    if form != ESTIMATE_FORMAT:
        raise UserError(f"{js}: unknown format {form!r}, expected '{ESTIMATE_FORMAT}'")
    pixel_size = info.pop("pixel_size", 1.0)
    if (isinstance(pixel_size, bool) or not isinstance(pixel_size, (int, float))
            or not (np.isfinite(pixel_size) and pixel_size > 0)):
        raise UserError(f"{js}: field 'pixel_size' must be a positive number, got {pixel_size!r}")
    normals = np.stack([ch["normal.X"], ch["normal.Y"], ch["normal.Z"]], axis=-1)
    return Estimate(normals=normals, thickness_nm=ch["thickness"], valid=ch["valid"] > 0.5,
                    film_ior=info.pop("film_ior", None), substrate_ior=info.pop("substrate_ior", None),
                    height=ch.get("height"), pixel_size=float(pixel_size), info=info,
                    normal_sigma_deg=ch.get("normal_sigma_deg"), thickness_sigma_nm=ch.get("thickness_sigma_nm"))
