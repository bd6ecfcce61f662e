"""thinfilm.bsdf: thin-film optics core and the Mitsuba 3 ``thinfilm`` BSDF.

The optics (:mod:`thinfilm.bsdf.optics`) and dispersion models
(:mod:`thinfilm.bsdf.materials`) import only NumPy; Mitsuba is imported when
:func:`register` is called, after the caller has chosen a variant.
"""

from .materials import Cauchy, Constant, Tabulated, as_dispersion, material_names, named_material
from .optics import film_amplitudes, mueller_entries, reflectances, reflection_mueller

__all__ = [
    "register",
    "film_amplitudes",
    "reflectances",
    "mueller_entries",
    "reflection_mueller",
    "Constant",
    "Cauchy",
    "Tabulated",
    "as_dispersion",
    "named_material",
    "material_names",
]


def register() -> None:
    """Register ``'type': 'thinfilm'`` with Mitsuba for the current variant.

    Call after ``mitsuba.set_variant(...)``; calling again is harmless.
    """
    from .plugin import register as _register

    _register()
