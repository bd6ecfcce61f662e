"""thinfilm.bsdf: thin-film optics core and the Mitsuba 3 ``thinfilm`` and ``thinfilm_sheet`` BSDFs.

The optics (:mod:`thinfilm.bsdf.optics`) and dispersion models
(:mod:`thinfilm.bsdf.materials`) import only NumPy; Mitsuba is imported when
:func:`register` is called, after the caller has chosen a variant.
"""

from .materials import (Cauchy, Constant, DatabaseMaterial, Layer, Tabulated, as_dispersion,
                        database_material, material_names, named_material, parse_index, parse_stack)
from .optics import (film_amplitudes, mueller_entries, reflectances, reflection_mueller,
                     sheet_amplitudes, sheet_mueller, stack_amplitudes, stack_powers,
                     transmission_factors, transmission_mueller_entries)

__all__ = [
    "register",
    "film_amplitudes",
    "stack_amplitudes",
    "sheet_amplitudes",
    "reflectances",
    "stack_powers",
    "transmission_factors",
    "mueller_entries",
    "transmission_mueller_entries",
    "reflection_mueller",
    "sheet_mueller",
    "Constant",
    "Cauchy",
    "Tabulated",
    "DatabaseMaterial",
    "Layer",
    "as_dispersion",
    "named_material",
    "database_material",
    "material_names",
    "parse_index",
    "parse_stack",
]


def register() -> None:
    """Register ``'type': 'thinfilm'`` and ``'type': 'thinfilm_sheet'`` with Mitsuba for the
    current variant.

    Call after ``mitsuba.set_variant(...)``; calling again is harmless.
    """
    from .plugin import register as _register_thinfilm
    from .sheet import register as _register_sheet

    _register_thinfilm()
    _register_sheet()
