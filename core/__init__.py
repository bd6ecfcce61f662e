"""thinfilm.core: what ``generators``, ``reconstruction`` and the commands share.

Modules
-------
:mod:`~thinfilm.core.errors`
    :class:`UserError`, the one-line error for bad input.
:mod:`~thinfilm.core.conventions`
    Camera frame, zenith/azimuth, Malus' law, the Stokes fit, the Stokes vector of a specular
    reflection.
:mod:`~thinfilm.core.film`
    Film descriptions (layers, substrate, exterior) and the one effective index.
:mod:`~thinfilm.core.colorimetry`
    Camera and illuminant spectra, camera RGB of reflectance spectra.
:mod:`~thinfilm.core.io`
    Dataset, estimate and evaluation folders: the public names of the five modules below.
:mod:`~thinfilm.core.exr`
    EXR files: channel names, reading and writing, OpenEXR's thread pool.
:mod:`~thinfilm.core.files`
    Text, TOML and JSON files and mask images, each failure one line.
:mod:`~thinfilm.core.dataset`
    Dataset folders (``thinfilm-dataset/1``): schema, reader, writer, preview.
:mod:`~thinfilm.core.estimate`
    Estimate folders: the :class:`~thinfilm.core.estimate.Estimate`, reader, writer, mesh.
:mod:`~thinfilm.core.evaluation_files`
    Evaluation folders: metrics and error maps.
:mod:`~thinfilm.core.masks`
    Otsu's threshold, shared by the importers and the reconstruction.
:mod:`~thinfilm.core.outputs`
    Safe output folders and files: the replacement rule, the marker, the lock, temporaries.
:mod:`~thinfilm.core.signals`
    SIGINT and SIGTERM as exceptions in the commands, so temporaries are cleaned up.
:mod:`~thinfilm.core.registry`
    The estimator registry.
:mod:`~thinfilm.core.variants`
    The rendering variant and choosing one.

This layer imports :mod:`thinfilm.bsdf` and nothing else of the project.
"""

from .errors import ThinfilmWarning, UserError

__all__ = ["ThinfilmWarning", "UserError"]
