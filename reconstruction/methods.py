"""The built-in reconstruction methods, as records of the estimator registry.

Each method is a pipeline of public stages: a first stage that reads and checks what it
needs (:func:`thinfilm.reconstruction.rgb_capture.capture_from_dataset`,
:func:`spectral_inputs`), then the method's array-level function, whose steps are named in
its docstring. Each declares its tuning options (:class:`thinfilm.core.registry.Option`),
set with ``reconstruct … --option NAME=VALUE``.

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
``stokes``                 spectral  other    s and p spectra fitted per pixel, one surface
                                              (:mod:`.spectral_stokes`)
``eikonal-s``              spectral  other    the s spectrum alone, eikonal surface
                                              (:mod:`.spectral_eikonal`)
``auto`` (default,         spectral  default  ``stokes`` with a Stokes cube, else ``eikonal-s``
eikonal)
=========================  ========  =======  ======================================================
"""

from __future__ import annotations

from thinfilm.core.registry import Option, estimator

__all__ = ["METHODS", "COHERENT_OPTIONS", "STOKES_OPTIONS", "EIKONAL_S_OPTIONS", "kobayashi2023", "coherent",
           "kobayashi", "stokes", "eikonal_s", "auto", "spectral_inputs", "spectral_capture"]

#: the tuning options of ``coherent`` (:func:`.rgb_coherent.reconstruct_coherent`)
COHERENT_OPTIONS = (
    Option("rounds", int, 1, "integrate -> re-fit rounds", minimum=1, maximum=10),
    Option("normal_prior_sigma", float, 0.01, "sigma of the prior on each normal's image-plane part "
           "around the integrated surface's normal (unitless)", minimum=1e-6),
    Option("thickness_prior_sigma_nm", float, 8.0, "sigma of the prior on thickness around its local "
           "median, nm", minimum=1e-3),
    Option("smoothness", float, 2.0, "curvature penalty of the height integration", minimum=0.0),
    Option("thickness_smoothness_nm", float, 10.0, "scale of the neighbour penalty of the joint choice "
           "of thickness basins, nm", minimum=1e-3),
    Option("max_chi2", float, 50.0, "pixels whose final fit is worse (noise units per degree of freedom) "
           "are invalid", minimum=0.0),
    Option("robust_prior", bool, True, "loosen the surface prior where confident data disagree with it"),
    Option("median_window", int, 9, "side of the window of the local median thickness, pixels",
           minimum=3, maximum=101),
)
#: the tuning options of ``stokes`` (:func:`.spectral_stokes.reconstruct_stokes`)
STOKES_OPTIONS = (
    Option("smoothness", float, 2.0, "curvature penalty of the height integration", minimum=0.0),
    Option("surface_sigma", float, 0.01, "sigma of the integrated surface's normal when fused with each "
           "pixel's (unitless)", minimum=1e-6),
    Option("misfit", float, 4.0, "fits this many times above the noise's expected residual are restarted",
           minimum=1.0),
    Option("iterations", int, 8, "Levenberg-Marquardt iterations per fit", minimum=1, maximum=200),
    Option("thickness_sigma_nm", float, 15.0, "sigma of the prior on thickness around its local median, nm",
           minimum=1e-3),
    Option("seed_step", int, 3, "spacing of the seed pixels, pixels", minimum=1, maximum=64),
    Option("max_chi2", float, 10.0, "pixels whose fit is worse (noise units per value) are invalid",
           minimum=0.0),
)
#: the tuning options of ``eikonal-s`` (:func:`.spectral_eikonal.reconstruct_eikonal`)
EIKONAL_S_OPTIONS = (
    Option("smoothness", float, 10.0, "curvature penalty of the height refinement", minimum=0.0),
    Option("angle_floor_deg", float, 0.2, "smallest standard deviation of a pixel's angle, degrees",
           minimum=0.0),
    Option("condition_scale", float, 2.0, "weight of the peak reflectance's conditioning in each angle's "
           "precision", minimum=0.0),
    Option("noise_scale", float, 1.0, "scale of the modelled S1/S2 noise bias", minimum=0.0),
    Option("misfit", float, 3.0, "fits this many times above the noise's expected residual are restarted",
           minimum=1.0),
    Option("direction_weight", float, 0.1, "weight of the fast march's gradient directions on flat faces",
           minimum=0.0),
    Option("anchor_weight", float, 1.0, "weight of the silhouette's height on flat faces", minimum=0.0),
)


@estimator("kobayashi2023", kind="rgb", role="paper", aliases=("paper",), needs=("polarized_rgb",),
           description="the paper's polarized-RGB method as published: incoherent DOP zenith, "
                       "boundary azimuth, RGB table thickness (known film index)")
def kobayashi2023(dataset, options):
    """Stages: the capture (:func:`.rgb_capture.capture_from_dataset`), then
    :func:`.rgb_paper.reconstruct_kobayashi2023`."""
    from .rgb_capture import capture_from_dataset
    from .rgb_paper import reconstruct_kobayashi2023

    return reconstruct_kobayashi2023(capture_from_dataset(dataset, options), progress=options.progress)


@estimator("coherent", kind="rgb", role="default", aliases=("default",), needs=("polarized_rgb",),
           options=COHERENT_OPTIONS,
           description="joint per-pixel inversion of the coherent thin-film model, then one "
                       "consistent surface (known film index)")
def coherent(dataset, options):
    """Stages: the capture (:func:`.rgb_capture.capture_from_dataset`), then
    :func:`.rgb_coherent.reconstruct_coherent` (per-pixel inversion, azimuth, surface,
    thickness basins, final fit) with the method's options."""
    from .rgb_capture import capture_from_dataset
    from .rgb_coherent import reconstruct_coherent

    return reconstruct_coherent(capture_from_dataset(dataset, options), progress=options.progress,
                                **options.method_options)


def spectral_capture(dataset, part: str):
    """The dataset's ``spectral_s`` cube or ``stokes`` cube (``part``), read now when the
    registry did not read it (a method that reads the Stokes cube when there is one does not
    ask for the s cube)."""
    from thinfilm.core.errors import UserError
    from thinfilm.core.io import read_dataset

    have = dataset.spectral_s if part == "spectral_s" else dataset.stokes
    if have is not None and len(have):
        return have
    file = "spectral_s.exr" if part == "spectral_s" else "stokes_spectral.exr"
    if not (dataset.path / file).is_file():
        raise UserError(f"{dataset.path}: the method needs {file}, and the dataset does not hold it")
    got = read_dataset(dataset.path, need=(part,), optional=())
    if part == "spectral_s":
        dataset.spectral_s = got.spectral_s
        return got.spectral_s
    dataset.stokes = got.stokes
    return got.stokes


def spectral_inputs(dataset, options, part: str):
    """The first stage of every spectral method: the checked film (single, on a dielectric
    substrate of index above 1), the capture (``part``: ``spectral_s`` or ``stokes``), the
    object mask with the dataset's valid pixels, the band width and the thickness range.
    Returns a dict of :func:`.spectral.reconstruct_spectral`'s arguments."""
    import numpy as np

    from thinfilm.core.errors import UserError

    from .spectral_checks import check_dielectric_substrate, object_mask, object_mask_stokes

    meta_path = dataset.path / "meta.json"
    film = options.film
    if not film.is_single:
        raise UserError(f"{meta_path}: the film is a stack of {len(film.layers)} layers; the spectral "
                        f"methods model a single film")
    check_dielectric_substrate(film, meta_path)
    n3 = film.effective_substrate_index()
    if not n3 > 1.0:
        raise UserError(f"{meta_path}: substrate index must be above 1 for the spectral methods, got {n3:g}",
                        argument="substrate_ior")
    data = spectral_capture(dataset, part)
    mask = options.mask
    if dataset.valid is not None:  # valid.exr: e.g. saturated pixels of an imported capture
        if mask is None:
            mask = object_mask(data) if part == "spectral_s" else object_mask_stokes(data)
        mask = np.asarray(mask, dtype=bool) & dataset.valid
    fwhm = dataset.meta.get("band_fwhm_nm", 0.0)
    fwhm = float(fwhm) if isinstance(fwhm, (int, float)) and not isinstance(fwhm, bool) else 0.0
    return {"cube": data if part == "spectral_s" else None, "stokes": data if part == "stokes" else None,
            "wavelengths_nm": dataset.wavelengths_nm, "substrate_ior": n3, "mask": mask,
            "pixel_size": dataset.pixel_size or 1.0, "thickness_range_nm": options.thickness_range_nm,
            "band_fwhm_nm": fwhm}


def _spectral(dataset, options, function, part):
    from .spectral import reconstruct_spectral

    est = reconstruct_spectral(method=function, **spectral_inputs(dataset, options, part), **options.method_options)
    est.info["coverage"] = float(est.valid.sum() / max(1, est.info["object_pixels"]))
    est.info["height_unit"] = "pixel" if dataset.pixel_size is None else "scene"
    return est


@estimator("kobayashi", kind="spectral", role="paper", aliases=("paper", "published"), needs=("spectral_s",),
           estimates_film_ior=True,
           description="the paper's hyperspectral method as published: peak angle, characteristic "
                       "strips, (n2, m) search")
def kobayashi(dataset, options):
    """Stages: :func:`spectral_inputs`, then :func:`.spectral_paper.reconstruct_kobayashi`."""
    from .spectral_paper import reconstruct_kobayashi

    return _spectral(dataset, options, reconstruct_kobayashi, "spectral_s")


@estimator("stokes", kind="spectral", needs=("stokes",), estimates_film_ior=True, options=STOKES_OPTIONS,
           description="each pixel's zenith, azimuth axis and thickness fitted to its s and p spectra "
                       "(stokes_spectral.exr), one film index, the azimuth's sign for the object, "
                       "normals fused with one integrated surface")
def stokes(dataset, options):
    """Stages: :func:`spectral_inputs`, then :func:`.spectral_stokes.reconstruct_stokes`."""
    from .spectral_stokes import reconstruct_stokes

    return _spectral(dataset, options, reconstruct_stokes, "stokes")


@estimator("eikonal-s", kind="spectral", needs=("spectral_s",), estimates_film_ior=True,
           options=EIKONAL_S_OPTIONS,
           description="the s spectrum alone (spectral_s.exr): one film index, each pixel's angle and "
                       "thickness fitted, the surface by fast marching on |grad z| = tan(zenith)")
def eikonal_s(dataset, options):
    """Stages: :func:`spectral_inputs`, then :func:`.spectral_eikonal.reconstruct_eikonal`."""
    from .spectral_eikonal import reconstruct_eikonal

    return _spectral(dataset, options, reconstruct_eikonal, "spectral_s")


def _prefixed(prefix, options):
    from dataclasses import replace

    return tuple(replace(o, name=f"{prefix}_{o.name}", help=f"({prefix}) {o.help}") for o in options)


@estimator("auto", kind="spectral", role="default", aliases=("default", "eikonal"), needs=(),
           uses=("stokes",), estimates_film_ior=True,
           options=_prefixed("stokes", STOKES_OPTIONS) + _prefixed("s", EIKONAL_S_OPTIONS),
           description="the 'stokes' method where the dataset holds stokes_spectral.exr, else "
                       "'eikonal-s' on spectral_s.exr (options prefixed stokes_ and s_)")
def auto(dataset, options):
    """The default spectral method: :func:`stokes` where the dataset holds the Stokes cube, else
    :func:`eikonal_s`; ``info["capture"]`` says which ran. Its options are theirs, prefixed
    ``stokes_`` and ``s_``."""
    from dataclasses import replace

    has_stokes = bool(dataset.stokes) or (dataset.path / "stokes_spectral.exr").is_file()
    if not has_stokes and dataset.spectral_s is None and not (dataset.path / "spectral_s.exr").is_file():
        from thinfilm.core.errors import UserError

        raise UserError(f"{dataset.path}: the spectral methods need spectral_s.exr or stokes_spectral.exr, and "
                        f"the dataset holds neither")
    prefix, function = ("stokes_", stokes) if has_stokes else ("s_", eikonal_s)
    own = {k[len(prefix):]: v for k, v in options.method_options.items() if k.startswith(prefix)}
    return function(dataset, replace(options, method_options=function.method.option_values(own)))


#: the built-in methods (the ``builtin`` entry point of the ``thinfilm.estimators`` group)
METHODS = [kobayashi2023, coherent, kobayashi, stokes, eikonal_s, auto]
