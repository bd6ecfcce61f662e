"""The built-in reconstruction methods, as records of the estimator registry.

Each function here has the one estimator signature of :mod:`thinfilm.core.registry`,
``(dataset, options) -> Estimate``, and adapts a dataset to the method's own array-level
function. ``pyproject.toml`` points the entry point ``thinfilm.estimators: builtin`` at
:data:`METHODS`.

=========================  ========  =======  ======================================================
name (aliases)             kind      role     what it does
=========================  ========  =======  ======================================================
``kobayashi2023`` (paper)  rgb       paper    the paper's Sec. 4 as published (:mod:`.rgb_paper`)
``coherent`` (default)     rgb       default  joint coherent inversion + surface consistency
                                              (:mod:`.rgb_coherent`)
``kobayashi`` (paper,      spectral  paper    the paper's Sec. 6 as published (:mod:`.spectral_paper`)
published)
``eikonal`` (default)      spectral  default  object-level film index, per-pixel fits, eikonal
                                              surface (:mod:`.spectral_eikonal`)
=========================  ========  =======  ======================================================
"""

from __future__ import annotations

from thinfilm.core.registry import estimator

__all__ = ["METHODS", "kobayashi2023", "coherent", "kobayashi", "eikonal"]


@estimator("kobayashi2023", kind="rgb", role="paper", aliases=("paper",), needs=("polarized_rgb",),
           description="the paper's polarized-RGB method as published: incoherent DOP zenith, "
                       "boundary azimuth, RGB table thickness (known film index)")
def kobayashi2023(dataset, options):
    from .rgb_capture import capture_from_dataset
    from .rgb_paper import reconstruct_kobayashi2023

    return reconstruct_kobayashi2023(capture_from_dataset(dataset, options), progress=options.progress)


@estimator("coherent", kind="rgb", role="default", aliases=("default",), needs=("polarized_rgb",),
           description="joint per-pixel inversion of the coherent thin-film model, then one "
                       "consistent surface (known film index)")
def coherent(dataset, options):
    from .rgb_capture import capture_from_dataset
    from .rgb_coherent import reconstruct_coherent

    return reconstruct_coherent(capture_from_dataset(dataset, options), progress=options.progress)


def _s_cube(dataset):
    """The s-polarized cube: ``spectral_s`` when read, else read now (a method that reads the
    Stokes cube when there is one does not ask for it)."""
    from thinfilm.core.errors import UserError

    if dataset.spectral_s is not None:
        return dataset.spectral_s
    from thinfilm.core.io import read_dataset

    if not (dataset.path / "spectral_s.exr").is_file():
        raise UserError(f"{dataset.path}: the spectral methods need spectral_s.exr or stokes_spectral.exr, "
                        f"and the dataset holds neither")
    return read_dataset(dataset.path, need=("spectral_s",), optional=()).spectral_s


def _spectral(dataset, options, function, use_stokes=False):
    from thinfilm.core.errors import UserError

    from .spectral import reconstruct_spectral
    from .spectral_checks import check_dielectric_substrate

    meta_path = dataset.path / "meta.json"
    film = options.film
    if not film.is_single:
        raise UserError(f"{meta_path}: the film is a stack of {len(film.layers)} layers; the spectral "
                        f"methods model a single film")
    check_dielectric_substrate(film, meta_path)
    n3 = film.effective_substrate_index()
    if not n3 > 1.0:
        raise UserError(f"{meta_path}: substrate index must be above 1 for the spectral methods, got {n3:g} "
                        f"(give it with --substrate-ior)")
    pixel_size = dataset.pixel_size
    stokes = dataset.stokes if (use_stokes and dataset.stokes) else None
    cube = None if stokes is not None else _s_cube(dataset)
    mask = options.mask
    if dataset.valid is not None:  # valid.exr: e.g. saturated pixels of an imported capture
        import numpy as np

        from .spectral_checks import object_mask, object_mask_stokes

        if mask is None:
            mask = object_mask(cube) if stokes is None else object_mask_stokes(stokes)
        mask = np.asarray(mask, dtype=bool) & dataset.valid
    est = reconstruct_spectral(cube, dataset.wavelengths_nm, n3, mask=mask,
                               method=function, pixel_size=pixel_size or 1.0, stokes=stokes)
    est.info["coverage"] = float(est.valid.sum() / max(1, est.info["object_pixels"]))
    est.info["height_unit"] = "pixel" if pixel_size is None else "scene"
    return est


@estimator("kobayashi", kind="spectral", role="paper", aliases=("paper", "published"), needs=("spectral_s",),
           estimates_film_ior=True,
           description="the paper's hyperspectral method as published: peak angle, characteristic "
                       "strips, (n2, m) search")
def kobayashi(dataset, options):
    from .spectral_paper import reconstruct_kobayashi

    return _spectral(dataset, options, reconstruct_kobayashi)


@estimator("eikonal", kind="spectral", role="default", aliases=("default",), needs=(),
           uses=("stokes",), estimates_film_ior=True,
           description="one film index for the object (below or above the substrate's), per-pixel "
                       "fits of the s and p spectra (stokes_spectral.exr; else the s spectrum of "
                       "spectral_s.exr), one consistent surface")
def eikonal(dataset, options):
    from .spectral_eikonal import reconstruct_eikonal

    return _spectral(dataset, options, reconstruct_eikonal, use_stokes=True)


#: the built-in methods (the ``builtin`` entry point of the ``thinfilm.estimators`` group)
METHODS = [kobayashi2023, coherent, kobayashi, eikonal]
