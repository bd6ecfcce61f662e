"""Real measurements in: ``thinfilm import polarization`` and ``thinfilm import spectral``.

Captures of real cameras become dataset folders of the project's format
(``thinfilm-dataset/1``, no ground truth, ``meta.json`` ``source = "imported"``), which
``thinfilm reconstruct`` and ``thinfilm evaluate`` accept like generated ones.

Modules
-------
:mod:`~thinfilm.importers.polarization`
    Polarization-camera images: one RGB image per polarizer angle, or the raw mosaic of a colour
    division-of-focal-plane sensor; dark, flat, white balance, saturation.
:mod:`~thinfilm.importers.spectral`
    Hyperspectral cubes (ENVI, multi-page TIFF): dark and white references, s-polarized or
    Stokes cubes.
:mod:`~thinfilm.importers.demosaic`
    Float demosaicing of colour-polarization mosaics, and the pixels it cannot serve.
:mod:`~thinfilm.importers.images`
    8-, 12- and 16-bit PNG and TIFF images as the integers they hold.
"""

__all__ = ["import_polarization", "import_spectral"]


def import_polarization(*args, **kwargs):
    """See :func:`thinfilm.importers.polarization.import_polarization`."""
    from .polarization import import_polarization as f

    return f(*args, **kwargs)


def import_spectral(*args, **kwargs):
    """See :func:`thinfilm.importers.spectral.import_spectral`."""
    from .spectral import import_spectral as f

    return f(*args, **kwargs)
