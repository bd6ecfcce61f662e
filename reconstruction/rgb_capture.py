"""Polarized RGB captures as the RGB methods see them: images, forward model, mask, range."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
from thinfilm.core.conventions import check_polarizer_angles, fit_stokes
from thinfilm.core.errors import ThinfilmWarning, UserError
from thinfilm.core.film import index_to_json

from .masks import mask_from_intensity
from .rgb_model import FilmCamera

__all__ = ["DEFAULT_THICKNESS_RANGE_NM", "RGBCapture", "capture_from_dataset"]

#: Thickness range searched when none is given (the span of the paper's Fig. 5).
DEFAULT_THICKNESS_RANGE_NM = (100.0, 1000.0)


@dataclass
class RGBCapture:
    """Polarized RGB captures and what is known about the rig.

    Attributes
    ----------
    images : dict angle (deg) → (H, W, 3) linear camera RGB.
    model : the forward model (film and substrate indices, camera, illuminant, bands).
    mask : (H, W) bool, the pixels to reconstruct.
    thickness_range_nm : (min, max).
    pixel_size : size of one pixel in scene units (scales ``surface.ply``).
    """

    images: dict
    model: FilmCamera
    mask: np.ndarray
    thickness_range_nm: tuple = DEFAULT_THICKNESS_RANGE_NM
    pixel_size: float = 1.0

    @property
    def angles_deg(self) -> list:
        return sorted(self.images)

    def stack(self) -> np.ndarray:
        """(H, W, K, 3) images in the order of :attr:`angles_deg`."""
        return np.stack([np.asarray(self.images[a], dtype=np.float64) for a in self.angles_deg], axis=2)
    info: dict = field(default_factory=dict)


def capture_from_dataset(dataset, options) -> RGBCapture:
    """An :class:`RGBCapture` of a :class:`thinfilm.core.io.Dataset` (no ground truth is
    used) and the estimator :class:`~thinfilm.core.registry.Options` (film, mask, range).

    Raises
    ------
    UserError
        Missing or too few polarizer layers, film indices not above 1, a mask of the wrong
        shape or an empty one.
    """
    meta_path = f"{dataset.path / 'meta.json'}"
    exr_path = f"{dataset.path / 'polarized_rgb.exr'}"
    if not dataset.polarized_rgb:
        raise UserError(f"{exr_path}: no polarizer layers (pol000, pol045, ...) found")
    check_polarizer_angles(dataset.polarizer_angles_deg, exr_path)
    lo, hi = options.thickness_range_nm or DEFAULT_THICKNESS_RANGE_NM

    wl = dataset.wavelengths_nm
    if wl.size < 2:
        wl = np.arange(400.0, 721.0, 4.0)
        warnings.warn(f"{meta_path}: no 'wavelengths_nm', modelling the camera over 400-720 nm in 4 nm steps",
                      ThinfilmWarning, stacklevel=2)
    film = options.film
    if not film.is_single:
        raise UserError(f"{meta_path}: the film is a stack of {len(film.layers)} layers; the RGB methods "
                        f"model a single film")
    for what, (n, _) in (("film index", film.layers[0].n_k(wl)), ("substrate index", film.substrate_n_k(wl))):
        if not np.all(np.isfinite(n)) or np.any(n <= 1.0):
            raise UserError(f"{meta_path}: {what}: refractive index must be > 1, got {float(np.min(n)):g} "
                            f"(give it with --film-ior / --substrate-ior)")
    meta = dataset.meta
    for key, default in (("camera", DEFAULT_CAMERA), ("illuminant", DEFAULT_ILLUMINANT)):
        if key not in meta:  # a real capture's meta.json may lack them: say what is assumed
            warnings.warn(f"{meta_path}: no '{key}', assuming {default!r}", ThinfilmWarning, stacklevel=2)
    model = FilmCamera(wl, film, meta.get("camera", DEFAULT_CAMERA), meta.get("illuminant", DEFAULT_ILLUMINANT))

    images = {a: np.asarray(img, dtype=np.float64) for a, img in dataset.polarized_rgb.items()}
    shape = next(iter(images.values())).shape[:2]
    if options.mask is not None:
        mask = np.asarray(options.mask, dtype=bool)
        if mask.shape != shape:
            raise UserError(f"shape {mask.shape} does not match the images {shape}", argument="mask")
    else:
        S0 = fit_stokes(np.stack([images[a] for a in sorted(images)]), sorted(images))[0]
        mask = mask_from_intensity(np.clip(S0.mean(axis=-1), 0.0, None))
    if dataset.valid is not None:  # valid.exr: e.g. saturated pixels of an imported capture
        mask = mask & dataset.valid
    if not mask.any():
        raise UserError(f"{'--mask' if options.mask is not None else exr_path}: the object mask is empty")
    info = {"film_ior": index_to_json(film.layers[0].material),
            "substrate_ior": film.effective_substrate_index(),
            "thickness_range_nm": [float(lo), float(hi)],
            "thickness_range_given": options.thickness_range_nm is not None}
    return RGBCapture(images, model, mask, (float(lo), float(hi)), dataset.pixel_size or 1.0, info)


#: share of the object's pixels whose thickness order stays open, or that sit at the top of the
#: default range, above which the RGB methods warn that the film may lie outside it
DOUBTFUL_SHARE = 0.2


def warn_if_outside_range(capture: RGBCapture, thickness_nm, valid, order_open: float | None = None) -> bool:
    """Warn, once, when a film looks thicker than the default range the RGB search covered.

    Colour alone cannot order thick films: past about a micron the fringes of neighbouring
    orders look alike, so a film outside the searched range is matched to a wrong thickness
    inside it. When the range was not given (``--thickness-range``) and either a share
    :data:`DOUBTFUL_SHARE` of the pixels leave their order open (``order_open``, the method's
    own measure) or sit in the top 5 % of the range, the warning names ``--thickness-range``
    and a spectral capture. Returns whether it warned.
    """
    if capture.info.get("thickness_range_given", True):
        return False
    lo, hi = capture.thickness_range_nm
    d = np.asarray(thickness_nm, dtype=np.float64)[np.asarray(valid, dtype=bool)]
    at_top = float(np.mean(d > hi - 0.05 * (hi - lo))) if d.size else 0.0
    if max(at_top, order_open or 0.0) < DOUBTFUL_SHARE:
        return False
    warnings.warn(f"rgb: the film may lie outside the default thickness range {lo:g}-{hi:g} nm "
                  f"({100 * max(at_top, order_open or 0.0):.0f} % of the pixels fit it poorly or sit at its "
                  f"top); colour alone cannot order thick films: give --thickness-range MIN MAX, or use a "
                  f"spectral capture", ThinfilmWarning, stacklevel=2)
    return True
