"""Raw sensor data: what a colour polarization (division-of-focal-plane) camera delivers.

``rig.sensor`` of the scene spec:

``"ideal"`` (default)
    No raw data: the dataset holds the per-angle captures only, as always.
``"dofp-rgb"``
    The dataset also holds ``raw.tiff``: one 16-bit image in which each pixel saw one colour
    filter and one polarizer, in the layout of :data:`thinfilm.core.mosaic.DEFAULT_PATTERN`
    (Sony IMX250MYR; see :mod:`thinfilm.core.mosaic` for the diagram). The per-angle
    captures (``polarized_rgb.exr`` …) stay what they are: the direct path, against which
    ``thinfilm import polarization raw.tiff --layout dofp-rgb`` is measured.

How ``raw.tiff`` is made (:func:`dofp_raw`):

1. The exact, noise-free camera RGB of the rendered Stokes cube behind each of the pattern's
   polarizers (:func:`thinfilm.core.model.polarized_rgb_from_stokes`), sampled by the pattern
   (:func:`thinfilm.core.mosaic.mosaic_from_images`).
2. Undone white balance: a raw channel's response is its sensitivity times the illuminant
   summed over the bands (:func:`raw_channel_response`, relative to the strongest channel),
   so the raw values are not white-balanced, as a real sensor's are not.
3. One exposure for the whole mosaic and the camera noise of ``[noise]`` at the raw level
   (:func:`.noise.digitize`): shot and read noise, quantization to ``noise.bits`` and
   clipping at the full well. With noise ``none`` only the quantization is applied.
4. Digital numbers stored as they are (``0 … 2^bits − 1``, not shifted up), unsigned 16-bit.

``meta.json`` records, under ``sensor``, the pattern, the bit depth and the white-balance gains
that bring raw values (normalized by the bit depth) to reflectance units: the arguments of
``thinfilm import polarization raw.tiff --layout dofp-rgb --bit-depth BITS
--white-balance R,G,B``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["SENSORS", "RAW_FILE", "RAW_WRITER_EXTRA", "raw_channel_response", "dofp_raw", "write_raw_tiff"]

#: the extra that installs ``tifffile``, which writes ``raw.tiff`` (the file that ``thinfilm
#: import polarization`` reads back with the same extra)
RAW_WRITER_EXTRA = "import"

SENSORS = ("ideal", "dofp-rgb")
RAW_FILE = "raw.tiff"


def raw_channel_response(wavelengths_nm, camera: str, illuminant: str) -> np.ndarray:
    """Relative response (3,) of the raw R, G, B channels to a perfect white reflector: the
    sums of sensitivity × illuminant × band width, divided by the largest.

    White-balanced camera RGB (:func:`thinfilm.core.colorimetry.camera_weights`) times this
    response is what the raw channels collect.
    """
    from thinfilm.core.colorimetry import band_widths, camera_sensitivities, illuminant_spd

    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    total = (camera_sensitivities(camera, wl) * (illuminant_spd(illuminant, wl) * band_widths(wl))[:, None]).sum(0)
    return total / total.max()


def dofp_raw(stokes: dict, wavelengths_nm, camera: str, illuminant: str, mask, noise: dict,
             rng: np.random.Generator, pattern=None):
    """The raw image of a colour polarization sensor looking at a rendered Stokes cube.

    Parameters
    ----------
    stokes : dict
        ``S0``, ``S1``, ``S2`` → (H, W, B), reflectance units (exact, noise-free).
    wavelengths_nm, camera, illuminant
        The rig's bands and colour model.
    mask : (H, W) bool
        Object pixels (auto exposure looks only at them).
    noise : dict
        Resolved ``[noise]`` table; ``bits`` at most 16.
    rng : numpy.random.Generator
        The sensor's own stream (spawned from the seed).
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`, optional
        Default: :data:`thinfilm.core.mosaic.DEFAULT_PATTERN`.

    Returns
    -------
    raw : (H, W) uint16 digital numbers
    info : dict
        ``pattern``, ``bits``, ``gain_electrons`` (electrons per unit of white-balanced
        reflectance in the strongest channel), ``full_well``, ``channel_response`` and
        ``white_balance`` (gains R, G, B from normalized raw values to reflectance units).
    """
    from thinfilm.core.mosaic import DEFAULT_PATTERN, mosaic_from_images, parse_pattern

    from thinfilm.core.model import polarized_rgb_from_stokes
    from .noise import digitize

    pattern = pattern or parse_pattern(DEFAULT_PATTERN)
    bits = int(noise["bits"])
    if bits > 16:
        raise ValueError(f"a 16-bit raw file cannot hold {bits}-bit values")
    images = polarized_rgb_from_stokes(stokes, wavelengths_nm, pattern.angles, camera, illuminant)
    signal = mosaic_from_images(images, pattern)
    response = raw_channel_response(wavelengths_nm, camera, illuminant)
    colour, _ = pattern.maps(signal.shape)
    signal *= response[colour]
    if noise["model"] == "none":
        # exposure and quantization only: the raw file holds whole numbers
        quiet = dict(noise, read_noise=0.0)
        from .noise import exposure_gains

        gain = float(exposure_gains(signal[None], mask, quiet)[0])
        levels = float(2 ** bits - 1)
        dn = np.clip(np.rint(np.clip(signal, 0.0, None) * gain * levels / float(noise["full_well"])), 0.0, levels)
    else:
        dn, gains = digitize(signal[None], mask, noise, rng)
        dn, gain = dn[0], float(gains[0])
    full_well = float(noise["full_well"])
    info = {
        "kind": "dofp-rgb",
        "file": RAW_FILE,
        "pattern": pattern.text,
        "bits": bits,
        "gain_electrons": gain,
        "full_well": full_well,
        "channel_response": [float(v) for v in response],
        "white_balance": [float(full_well / (gain * r)) for r in response],
        "noise": "shot, read and quantization noise at the raw level, one exposure for the whole mosaic"
                 if noise["model"] != "none" else "quantization only",
    }
    return dn.astype(np.uint16), info


def write_raw_tiff(path, raw: np.ndarray, description: str = "") -> Path:
    """Write a raw image as an uncompressed 16-bit grayscale TIFF (deterministic bytes), with
    ``tifffile`` (the ``import`` extra, :data:`RAW_WRITER_EXTRA`)."""
    from thinfilm.core.extras import require_extra

    tifffile = require_extra("tifffile", RAW_WRITER_EXTRA, what='rig.sensor = "dofp-rgb" (raw.tiff)')

    path = Path(path)
    tifffile.imwrite(path, np.ascontiguousarray(raw, dtype=np.uint16), photometric="minisblack",
                     metadata=None, description=description or None, software=False)
    return path
