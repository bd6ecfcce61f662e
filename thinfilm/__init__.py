"""thinfilm: spectral, polarized thin-film rendering and reconstruction.

Subpackages: :mod:`thinfilm.bsdf` (optics core and Mitsuba plugin),
:mod:`thinfilm.scenes`, :mod:`thinfilm.generators`, :mod:`thinfilm.reconstruction`.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
