"""Analytic test objects for the RGB reconstruction, without rendering.

Normal fields and thickness maps of a hemisphere, a cylinder and a pyramid are written down
in closed form; captures are the optics core's reflectances through the camera weights
(``FilmCamera``), with an optional camera-noise model (shot noise, read noise, 12-bit
quantization, each image exposed so that its brightest pixel reaches 90 % of full well).
Used by the fast tests; the end-to-end test uses the real generator.
"""

from __future__ import annotations


import numpy as np

from thinfilm.core.film import Film
from thinfilm.core.io import dataset_meta, write_dataset
from thinfilm.reconstruction.rgb_model import FilmCamera

__all__ = ["shape_field", "capture", "write_synthetic_dataset"]


def shape_field(kind: str, resolution: int, thickness=(400.0, 400.0)):
    """Normals (H, W, 3), mask, thickness (nm) of an analytic object filling the view.

    ``kind``: ``"hemisphere"`` (radius 1 in a 2.2-wide view), ``"cylinder"`` (axis along y),
    ``"pyramid"`` (base 2, height 0.6). ``thickness``: (centre, edge) values of a radial
    (hemisphere, pyramid) or left-to-right linear (cylinder) profile.
    """
    n = resolution
    c = (np.arange(n) + 0.5) / n * 2.2 - 1.1
    x, y = np.meshgrid(c, -c)  # row 0 = top = +y
    if kind == "hemisphere":
        r2 = x ** 2 + y ** 2
        mask = r2 < 1.0
        z = np.sqrt(np.clip(1.0 - r2, 1e-12, None))
        normals = np.stack([x, y, z], axis=-1)
        t = np.sqrt(np.clip(r2, 0, 1))
    elif kind == "cylinder":
        mask = (np.abs(x) < 1.0) & (np.abs(y) < 1.0)
        z = np.sqrt(np.clip(1.0 - x ** 2, 1e-12, None))
        normals = np.stack([x, 0 * x, z], axis=-1)
        t = (x + 1.0) / 2.0
    elif kind == "pyramid":
        mask = (np.abs(x) < 1.0) & (np.abs(y) < 1.0)
        h = 0.6
        normals = np.zeros(x.shape + (3,))
        xs = np.abs(x) >= np.abs(y)
        normals[..., 0] = np.where(xs, np.sign(x) * h, 0.0)
        normals[..., 1] = np.where(xs, 0.0, np.sign(y) * h)
        normals[..., 2] = 1.0
        t = np.clip(np.hypot(x, y) / np.sqrt(2.0), 0, 1)
    else:
        raise ValueError(kind)
    normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
    normals[~mask] = (0.0, 0.0, 1.0)
    thick = thickness[0] + (thickness[1] - thickness[0]) * t
    return normals, mask, np.where(mask, thick, 0.0)


def capture(model: FilmCamera, normals, mask, thickness, angles_deg, noise: bool = True, seed: int = 0,
            full_well: float = 10000.0, read_noise: float = 5.0, bits: int = 12):
    """Camera RGB behind each polarizer ``{angle: (H, W, 3)}``; background 0."""
    zen = np.degrees(np.arccos(np.clip(normals[..., 2], -1, 1)))
    az = np.degrees(np.arctan2(normals[..., 1], normals[..., 0]))
    imgs = model.polarized_rgb(zen[mask], az[mask], thickness[mask], angles_deg)
    rng = np.random.default_rng(seed)
    out = {}
    for a in angles_deg:
        img = np.zeros(mask.shape + (3,))
        img[mask] = imgs[a]
        if noise:
            gain = 0.9 * full_well / img.max()
            e = rng.poisson(img * gain).astype(np.float64) + rng.normal(0.0, read_noise, img.shape)
            step = full_well / 2 ** bits
            dn = np.clip(np.round(e / step), 0, 2 ** bits - 1)
            img = dn * step / gain
        out[a] = img.astype(np.float32)
    return out


def write_synthetic_dataset(path, kind, resolution, film_ior=1.37, substrate_ior=1.6,
                            thickness=(400.0, 400.0), angles_deg=(0, 45, 90, 135), noise=True, seed=0,
                            wavelengths_nm=None):
    """A dataset folder (``meta.json``, ``polarized_rgb.exr``, ``ground_truth.exr``) of an
    analytic object; returns (normals, mask, thickness)."""
    from pathlib import Path

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    wl = np.arange(400.0, 721.0, 4.0) if wavelengths_nm is None else np.asarray(wavelengths_nm)
    film = Film.single(film_ior, None, substrate_ior)
    model = FilmCamera(wl, film)
    normals, mask, thick = shape_field(kind, resolution, thickness)
    imgs = capture(model, normals, mask, thick, angles_deg, noise, seed)
    zen = np.degrees(np.arccos(normals[..., 2]))
    az = np.mod(np.degrees(np.arctan2(normals[..., 1], normals[..., 0])), 360)
    gt = {"normal": normals, "zenith": zen, "azimuth": az, "thickness": thick, "depth": np.zeros(mask.shape),
          "mask": mask}
    meta = dataset_meta(wavelengths_nm=wl.tolist(), band_fwhm_nm=4.0, polarizer_angles_deg=list(angles_deg),
                        camera="Nikon 5100 (NPL)", illuminant="D65", **film.to_meta(),
                        seed=seed, noise={"model": "camera" if noise else "none"})
    write_dataset(path, meta, ground_truth=gt, polarized_rgb=imgs, preview=False)
    return normals, mask, thick
