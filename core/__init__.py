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
    Dataset and estimate folders: readers, writers, channel names, format version.
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
